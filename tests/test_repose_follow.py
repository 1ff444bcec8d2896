"""The reposing follower's step within joint limits (planner.repose._bounded_step): a free
coordinate a limit cuts is held and the step solved again over the others, so a finger with
a joint at its limit still makes the motion its other joints can make."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from planner.hand import Finger
from planner.repose import DAMPING, FOLLOW_TOL_M, _bounded_step, _follow, _holds, object_path

PAIRS = Path(__file__).resolve().parents[1] / "experiments" / "results" / "exp10_pairs"


def _finger(coupled=()):
    followers = {k for k, *_ in coupled}
    return Finger(name="f", joints=("a", "b", "c"), q_index=(0, 1, 2), contact_links=(), tip_frame="",
                  q_open=(0.0, 0.0, 0.0), free=tuple(k for k in range(3) if k not in followers), coupled=tuple(coupled))


LO, HI = -np.ones(3), np.ones(3)


def test_a_joint_at_its_limit_is_held_and_the_others_make_the_motion():
    # task: x = a + b, y = c; a is at its upper limit and the error asks x to grow by 0.5
    f = _finger()
    J = np.array([[1.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    qf = np.array([1.0, 0.0, 0.0])
    e = np.array([0.5, 0.0])
    qn = _bounded_step(f, qf, J, e, LO, HI)
    assert qn[0] == pytest.approx(1.0)  # held at its limit
    assert J @ (qn - qf) == pytest.approx(e / (1.0 + DAMPING**2), abs=1e-12)  # b gives all of it
    # the clipped unconstrained step (the follower before) gives half: a's share is lost
    dz = J.T @ np.linalg.solve(J @ J.T + DAMPING**2 * np.eye(2), e)
    clipped = f.step(qf, dz, LO, HI)
    assert (J @ (clipped - qf))[0] == pytest.approx(0.25, abs=1e-6)


def test_a_step_away_from_the_limit_is_not_held():
    f = _finger()
    J = np.array([[1.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    qf = np.array([1.0, 0.0, 0.0])
    e = np.array([-0.5, 0.2])
    dz = J.T @ np.linalg.solve(J @ J.T + DAMPING**2 * np.eye(2), e)
    assert _bounded_step(f, qf, J, e, LO, HI) == pytest.approx(qf + dz, abs=1e-12)  # the plain step


def test_a_coupled_driver_at_its_limit_is_held_and_its_follower_with_it():
    # c follows b (c = b); task: x = a + b + c over the joints, a + 2 b over the free coordinates
    f = _finger(coupled=((2, 1, 1.0, 0.0),))
    Jq = np.array([[1.0, 1.0, 1.0]])
    J = f.reduce(Jq)
    assert J == pytest.approx(np.array([[1.0, 2.0]]))
    qf = np.array([0.0, 1.0, 1.0])
    qn = _bounded_step(f, qf, J, np.array([0.6]), LO, HI)
    assert qn[1:] == pytest.approx([1.0, 1.0])
    assert Jq @ (qn - qf) == pytest.approx([0.6], rel=1e-5)


def test_every_coordinate_held_leaves_the_finger_where_it_is():
    f = _finger()
    J = np.array([[1.0, 1.0, 0.0]])
    qf = np.array([1.0, 1.0, 0.0])
    assert _bounded_step(f, qf, J, np.array([0.3]), LO, HI) == pytest.approx(qf)


def test_the_allegro_thumb_near_its_limit_keeps_its_contact_on_the_moving_box():
    """exp10's Allegro box (medium offset), initial grasp: the thumb's joint_15.0 is 0.008 rad
    below its upper limit. Along the whole straight path to the final grasp's pose (11
    waypoints, 10.8 mm / 20.4 deg) the thumb keeps its outermost contact point on its object
    point (re-measured here by forward kinematics), the joints within their limits; the clipped
    step (the follower before) drove joint_15.0 into its limit and lost the contact by 3.6 mm
    at the second waypoint."""
    from planner.grasp import load_grasp
    from planner.realization import realize

    g = realize(load_grasp(PAIRS / "allegro_right_box_medium_initial.yaml"))
    gb = realize(load_grasp(PAIRS / "allegro_right_box_medium_final.yaml"))
    hand = g.hand
    lo, hi = np.asarray(hand.lower, float), np.asarray(hand.upper, float)
    holds = _holds(g)["thumb"]
    thumb = hand.fingers["thumb"]
    j15 = thumb.q_index[thumb.joints.index("joint_15.0")]
    assert 0.0 < hi[j15] - np.asarray(g.q)[j15] < 0.01
    q = np.array(g.q, dtype=float)
    link, p_link, p_obj = holds[0][:3]
    path = object_path(g.obj.T_palm_obj, gb.obj.T_palm_obj)
    assert len(path) == 12
    for T in path[1:]:
        q, worst, _ = _follow(hand, "thumb", q, holds, T, lo, hi, True)
        T_link = hand.state(q).link_pose(link)
        off = (T_link[:3, :3] @ p_link + T_link[:3, 3]) - (T[:3, :3] @ p_obj + T[:3, 3])
        assert np.linalg.norm(off) <= 2 * FOLLOW_TOL_M
        assert np.all(q >= lo - 1e-12) and np.all(q <= hi + 1e-12)
