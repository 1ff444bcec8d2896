"""Reposing along the motion the fingers can follow (experiments.repose_drive, exp10's reach
measurement): the grasp-Jacobian step's maths, the drive's waypoints re-measured
independently, the meeting pose of two grasps."""

import numpy as np
import pytest

from experiments.repose_drive import LAMBDA, _skew, _solve, drive_toward, meeting



def _w():
    from planner.repose import STEP_M, STEP_RAD

    return np.r_[np.ones(3), np.full(3, STEP_M / STEP_RAD)]


def _block(J, c, at_lo=None, at_hi=None):
    n = J.shape[1]
    return (np.asarray(J, float), np.asarray(c, float), np.zeros(n, bool) if at_lo is None else at_lo,
            np.zeros(n, bool) if at_hi is None else at_hi)


def test_no_finger_moves_the_object_as_asked():
    nu_goal = np.array([1e-3, -2e-4, 0.0, 0.01, 0.0, -0.02])
    nu, rates = _solve([], [], nu_goal)
    assert np.allclose(nu, nu_goal, atol=1e-12) and rates == []


def test_a_finger_that_moves_its_contact_freely_follows_any_motion():
    """J = I: the contact point's velocity is the joints' rates; the twist is the goal's but for
    the tie-breaker LAMBDA |dq|^2 (relative shrink of order LAMBDA)."""
    nu_goal = np.array([1e-3, 0.0, 0.0, 0.0, 0.02, 0.0])
    c = np.array([0.02, 0.01, -0.01])
    nu, (dq,) = _solve([_block(np.eye(3), c)], [np.zeros(3, bool)], nu_goal)
    assert np.allclose(dq, nu[:3] + np.cross(nu[3:], c), atol=1e-12)  # the contact follows exactly
    assert np.linalg.norm(_w() * (nu - nu_goal)) <= 10 * LAMBDA * np.linalg.norm(_w() * nu_goal) + 1e-12


def test_a_finger_that_cannot_move_pins_its_contact_point():
    """J = 0: the contact point stays where it is (v + w x c = 0); among those twists the one
    nearest the goal (weighted), found here by least squares over w directly."""
    c = np.array([0.03, -0.01, 0.02])
    nu_goal = np.array([1e-3, 5e-4, 0.0, 0.0, 0.0, 0.01])
    nu, _ = _solve([_block(np.zeros((3, 2)), c)], [np.zeros(2, bool)], nu_goal)
    assert np.allclose(nu[:3] + np.cross(nu[3:], c), 0.0, atol=1e-12)
    # v = -w x c = [c]x w: minimize |W ([ [c]x ; I ] w - nu_goal)|
    M = np.vstack([_skew(c), np.eye(3)])
    w = np.linalg.lstsq(_w()[:, None] * M, _w() * nu_goal, rcond=None)[0]
    assert np.allclose(nu, M @ w, atol=1e-9)


def test_a_held_coordinate_does_not_move():
    c = np.array([0.0, 0.02, 0.0])
    nu_goal = np.array([1e-3, 0.0, 0.0, 0.0, 0.0, 0.0])
    free, _ = _solve([_block(np.eye(3), c)], [np.zeros(3, bool)], nu_goal)
    nu, (dq,) = _solve([_block(np.eye(3), c)], [np.array([True, False, False])], nu_goal)
    assert abs(dq[0]) < 1e-12  # x of the contact cannot move: the object turns about a point on the x line
    assert np.allclose(dq, nu[:3] + np.cross(nu[3:], c), atol=1e-12)
    assert np.linalg.norm(_w() * (nu - nu_goal)) > np.linalg.norm(_w() * (free - nu_goal))


@pytest.fixture(scope="module")
def sphere_pair():
    from experiments.exp10_reposing import DEFAULT_PAIRS
    from planner.grasp import load_grasp
    from planner.realization import realize

    return tuple(realize(load_grasp(DEFAULT_PAIRS / f"allegro_right_sphere_medium_{k}.yaml")) for k in ("initial", "final"))


def _check_move(move, grasp, P):
    """Independent re-check of a drive: it starts at the grasp, ends at P, steps at most one
    waypoint apart, and every holding finger's outermost contact point (fixed in its link)
    stays on its object point at every waypoint (forward kinematics, object pose)."""
    from planner.repose import FOLLOW_TOL_M, STEP_M, STEP_RAD, _holds, pose_distance

    assert np.allclose(move.poses[0], grasp.obj.T_palm_obj, atol=1e-12)
    assert np.allclose(move.poses[-1], P, atol=1e-12)
    assert np.allclose(move.q_path[0], grasp.q, atol=1e-12)
    for k in range(1, len(move.poses)):
        mm, deg = pose_distance(move.poses[k - 1], move.poses[k])
        assert mm <= STEP_M * 1e3 + 1e-6 and deg <= np.degrees(STEP_RAD) + 1e-6
    holds = _holds(grasp)
    assert set(move.fingers) == set(holds)
    for q, T in zip(move.q_path, move.poses):
        st = grasp.hand.state(q)
        for f in move.fingers:
            link, p_link, p_obj = holds[f][0][:3]
            TL = st.link_pose(link)
            off = np.linalg.norm(TL[:3, :3] @ p_link + TL[:3, 3] - (T[:3, :3] @ p_obj + T[:3, 3]))
            assert off <= 2 * FOLLOW_TOL_M + 1e-9, (f, off)


def test_meeting_pose_both_grasps_reach(sphere_pair):
    """The Allegro sphere pair (18.4 mm / 16.0 deg apart): neither grasp carries the object to
    the other's pose, but driven toward each other they meet between the two poses."""
    from planner.options import PlanOptions
    from planner.repose import pose_distance

    ga, gb = sphere_pair
    met = meeting(ga, gb, PlanOptions.for_execution())
    assert met is not None
    P, ma, mb = met
    da, db = pose_distance(ga.obj.T_palm_obj, P)[0], pose_distance(gb.obj.T_palm_obj, P)[0]
    assert da > 1.0 and db > 1.0  # strictly between: both moved
    _check_move(ma, ga, P)
    _check_move(mb, gb, P)
    for m in (ma, mb):  # every waypoint was judged a valid state: the end grasp holds with the same fingers
        assert set(m.fingers) <= set(m.end.patches)


def test_drive_toward_stops_at_its_last_valid_waypoint(sphere_pair):
    from planner.options import PlanOptions

    ga, gb = sphere_pair
    move, err = drive_toward(ga, gb.obj.T_palm_obj, PlanOptions.for_execution())
    assert err is not None and "of 18.4 mm / 16.0 deg" in str(err)
    _check_move(move, ga, move.poses[-1])
    assert not np.allclose(move.poses[-1], gb.obj.T_palm_obj)
