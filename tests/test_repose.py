"""Reposing moves (planner.repose) and plans that move the object (planner.pose_search):
the object path's spacing, contacts that stay fixed on the object (re-checked by forward
kinematics here, not by the planner's own follower), plans between grasps at different
object poses and their schema-4 file form."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from planner.errors import MotionError, SpecError
from planner.grasp import load_grasp
from planner.options import PlanOptions
from planner.plan import plan_from_data, read_plan
from planner.plan_data import OBJECT, pose_matrix, pose_vector, write_plan
from planner.realization import realize
from planner.regrasp import plan_regrasp
from planner.resources import bundled_grasp
from planner.repose import FOLLOW_TOL_M, STEP_M, STEP_RAD, object_path, pose_distance, repose

OPTS = PlanOptions.for_execution(motion=False, verify=False)


def _no_finger_path(hand, obj, q_a, q_b, finger):
    """A stand-in for the planner's finger paths (`planner.pose_search.leg`'s ``gait_fn``): none."""
    from planner.errors import MotionError

    raise MotionError(f"no path for {finger} (stand-in)")


@pytest.fixture(scope="module")
def box():
    return realize(load_grasp(bundled_grasp("allegro/box_four_finger.yaml")))


def _moved(T, d=(0.0, 0.0, 0.0), axis=(0.0, 0.0, 1.0), deg=0.0):
    T = np.array(T, dtype=float)
    T[:3, 3] += np.asarray(d, float)
    T[:3, :3] = Rotation.from_rotvec(math.radians(deg) * np.asarray(axis, float)).as_matrix() @ T[:3, :3]
    return T


def test_object_path_spacing_and_ends():
    rng = np.random.default_rng(3)
    for _ in range(20):
        Ta = _moved(np.eye(4), rng.normal(size=3) * 0.01, rng.normal(size=3) / 1.0, rng.uniform(0, 60))
        Tb = _moved(Ta, rng.normal(size=3) * 0.01, rng.normal(size=3), rng.uniform(0, 60))
        P = object_path(Ta, Tb)
        assert len(P) >= 2
        assert np.allclose(P[0], Ta) and np.allclose(P[-1], Tb)
        for a, b in zip(P[:-1], P[1:]):
            mm, deg = pose_distance(a, b)
            assert mm <= STEP_M * 1e3 + 1e-6 and math.radians(deg) <= STEP_RAD + 1e-9
        # a pure translation moves the centre along the segment, uniformly
        Tc = _moved(Ta, (0.0, 0.0, 0.0))
        Tc[:3, 3] += np.array([0.004, 0.0, 0.0])
        Q = object_path(Ta, Tc)
        steps = np.diff(Q[:, :3, 3], axis=0)
        assert np.allclose(steps, steps[0]) and np.allclose(Q[:, :3, :3], Ta[:3, :3])


def test_pose_vector_round_trip():
    rng = np.random.default_rng(4)
    for _ in range(10):
        T = _moved(np.eye(4), rng.normal(size=3), rng.normal(size=3), rng.uniform(0, 180))
        v = pose_vector(T)
        assert v[6] >= 0 and np.allclose(pose_matrix(v), T, atol=1e-12)


def test_contacts_stay_on_the_object_along_the_move(box):
    """Forward kinematics of every holding finger's outermost contact point, transported by
    the object's path, stays where the object point is (within twice the follow tolerance),
    joints stay within limits, and the same fingers hold at the end."""
    hand = box.hand
    T0 = np.asarray(box.obj.T_palm_obj, float)
    r = repose(box, _moved(T0, (0.002, 0.0, 0.001), (0.0, 1.0, 0.0), 4.0), OPTS)
    assert len(r.q_path) == len(r.poses) >= 3
    lo, hi = np.asarray(hand.lower), np.asarray(hand.upper)
    assert np.all(r.q_path >= lo - 1e-9) and np.all(r.q_path <= hi + 1e-9)
    state0 = hand.state(box.q)
    for c in box.contacts:
        if c.finger is None:
            continue
        order = hand.fingers[c.finger].contact_links
        outer = max((x for x in box.contacts if x.finger == c.finger), key=lambda x: order.index(x.link))
        if c is not outer:
            continue
        p_palm = T0[:3, :3] @ c.point + T0[:3, 3]
        T_link = state0.link_pose(c.link)
        p_link = T_link[:3, :3].T @ (p_palm - T_link[:3, 3])
        for q, T in zip(r.q_path, r.poses):
            T_l = hand.state(q).link_pose(c.link)
            here = T_l[:3, :3] @ p_link + T_l[:3, 3]
            there = T[:3, :3] @ c.point + T[:3, 3]
            assert np.linalg.norm(here - there) <= 2 * FOLLOW_TOL_M
    assert set(r.end.patches) == set(box.patches)
    assert r.end.closure_under("link").is_force_closure
    back = r.reversed()
    assert np.allclose(back.poses[0], r.poses[-1]) and np.allclose(back.q_path[-1], box.q)


def test_a_move_out_of_reach_is_refused_naming_where(box):
    T0 = np.asarray(box.obj.T_palm_obj, float)
    with pytest.raises(MotionError, match=r"reposing, .* mm / .* deg along the object's path \(waypoint \d+/\d+\)"):
        repose(box, _moved(T0, (0.0, 0.0, 0.04)), OPTS)


def _moved_final(dz=0.001):
    spec = load_grasp(bundled_grasp("allegro/box_tripod.yaml"))
    T = _moved(spec.object.T_palm_obj, (0.001, 0.0, dz))
    return realize(replace(spec, object=spec.object.with_pose(T))).require_placed()


def test_grasps_at_different_poses_plan_with_a_repose_step(box, tmp_path):
    final = _moved_final()
    result = plan_regrasp(box, final, OPTS)
    plan = result.plan
    reposes = [s for s in plan.steps if s.action == "repose"]
    assert len(reposes) == 1 and reposes[0].finger == OBJECT
    st = reposes[0]
    # the object path starts and ends at the poses of its states; the last state is the final grasp's pose
    assert np.allclose(pose_matrix(st.object_path[0]), plan.object_at(st.from_state).T_palm_obj, atol=1e-9)
    assert np.allclose(pose_matrix(st.object_path[-1]), plan.object_at(st.to_state).T_palm_obj, atol=1e-9)
    assert np.allclose(plan.object_at(len(plan.states) - 1).T_palm_obj, final.obj.T_palm_obj, atol=1e-9)
    assert np.allclose(plan.object_at(0).T_palm_obj, box.obj.T_palm_obj)
    mm = plan.summary["reposing"]["object_path_mm"]
    assert mm == pytest.approx(pose_distance(box.obj.T_palm_obj, final.obj.T_palm_obj)[0], abs=1e-3)
    # schema 4 on file, read back equal
    path = write_plan(plan, tmp_path / "p.yaml")
    data = read_plan(path)
    assert data["schema_version"] == 4
    back = plan_from_data(data.to_dict())
    assert [s.action for s in back.steps] == [s.action for s in plan.steps]
    assert back.states[-1].object_pose is not None


def test_without_reposing_the_poses_must_match(box):
    with pytest.raises(SpecError, match="both grasps must share hand, object, object pose and friction"):
        plan_regrasp(box, _moved_final(), replace(OPTS, repose=False))


def test_plan_files_refuse_a_finger_move_that_moves_the_object(box):
    data = plan_regrasp(box, _moved_final(), OPTS).plan.to_dict()
    k = next(i for i, s in enumerate(data["steps"]) if s["action"] == "lift")
    data["states"][k + 1]["object_pose"] = {"position": [0.2, 0.0, 0.0], "quat_xyzw": [0.0, 0.0, 0.0, 1.0]}
    with pytest.raises(SpecError, match="only a repose step moves it"):
        plan_from_data(data)
    data = plan_regrasp(box, _moved_final(), OPTS).plan.to_dict()
    k = next(i for i, s in enumerate(data["steps"]) if s["action"] == "repose")
    data["steps"][k]["finger"] = "index"
    with pytest.raises(SpecError, match="expected finger 'object'"):
        plan_from_data(data)


def test_turns_need_levers_against_torsional_friction(box):
    """drive_refusal: a translation is always driven; the box turned about an axis through
    its centre is driven (four contacts ~20 mm off it); the same turn with only contacts on
    the axis (a pinch turning about its own line) is refused; no torsion (gamma 0), no refusal."""
    from planner import repose as rp
    from planner.model import Friction
    from planner.sim import controller

    assert rp.POSTURE_SHARE == controller.POSTURE_SHARE
    T0 = np.asarray(box.obj.T_palm_obj, float)
    assert rp.drive_refusal(box, _moved(T0, (0.01, 0.0, 0.0))) is None
    assert rp.drive_refusal(box, _moved(T0, axis=(0.0, 0.0, 1.0), deg=10.0)) is None
    pinch = realize(load_grasp(bundled_grasp("icub/pen_palmar_pinch.yaml")))
    Tp = np.asarray(pinch.obj.T_palm_obj, float)
    pts = [Tp[:3, :3] @ c.point + Tp[:3, 3] for c in pinch.contacts]
    axis = (pts[1] - pts[0]) / np.linalg.norm(pts[1] - pts[0])
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(math.radians(10) * axis).as_matrix()
    T[:3, 3] = pts[0] - T[:3, :3] @ pts[0]  # about the line through the pads
    assert "torsional friction" in rp.drive_refusal(pinch, T @ Tp)
    assert rp.drive_refusal(replace(pinch, friction=Friction(0.9, 0.0)), T @ Tp) is None


def _release_plan(box):
    """The box grasp with one finger released: the object carried 2 mm away from it by the
    others (it keeps still), then it opens; as one plan (repose, move)."""
    from planner.audit import audit_plan
    from planner.pose_search import Leg, _away_from, _open_path, compose
    from planner.repose import at_pose, state_reason

    hand = box.hand
    for f in ("ring", "index", "middle"):
        without = replace(box, patches={k: v for k, v in box.patches.items() if k != f})
        if state_reason(without, OPTS) is not None:
            continue
        u = _away_from(box, f, 0.002)
        if u is None:
            continue
        P = np.array(box.obj.T_palm_obj, dtype=float)
        P[:3, 3] += 0.002 * u
        try:
            r = repose(box, P, OPTS, still=(f,))
        except MotionError:
            continue
        path = _open_path(r.end, f, OPTS)
        if path is None:
            continue
        q = np.array(r.end.q, dtype=float)
        q[list(hand.fingers[f].q_index)] = path[-1]
        end = at_pose(r.end, P, q)
        plan = compose(box, box, OPTS, Leg(box, [], r, end, [(f, path)]), None, Leg(end, [], None, end), P)
        return f, r, plan, audit_plan
    pytest.fail("no finger of the box grasp can be released")


def test_a_finger_released_by_carrying_the_object_away_keeps_still(box, tmp_path):
    f, r, plan, audit_plan = _release_plan(box)
    idx = list(box.hand.fingers[f].q_index)
    assert np.allclose(r.q_path[:, idx], box.q[idx])  # it keeps still while the others carry
    assert f not in r.end.patches and f not in r.fingers
    assert [s.action for s in plan.steps] == ["repose", "move"]
    assert f in plan.states[0].patches and f not in plan.states[1].patches
    path = write_plan(plan, tmp_path / "release.yaml")
    read_plan(path)  # schema 4: a finger touching at one end of a repose step only
    report = audit_plan(read_plan(path))
    assert report.ok, report.problems
    # the audit refuses a released finger whose joints move during the step
    data = read_plan(path).to_dict()
    step = data["steps"][0]
    j = box.hand.fingers[f].joints[1]
    data["steps"][0] = {**step, "joints": step["joints"] + [j],
                        "path": [row + [data["states"][0]["q"][j]] for row in step["path"]]}
    data["states"][1]["q"][j] = data["states"][1]["q"][j] + 0.05
    data["steps"][0]["path"][-1][-1] = data["states"][1]["q"][j]
    data["steps"][1]["path"][0][box.hand.fingers[f].joints.index(j)] = data["states"][1]["q"][j]
    bad = audit_plan(plan_from_data(data))
    assert any("touches at state 0 only, yet its joints move" in p for p in bad.problems), bad.problems


def test_a_released_finger_plan_holds_in_the_simulator(box, tmp_path):
    """The release plan replays (default engine, palm down): the released finger's load is
    handed over before the others carry the object away from it."""
    from planner.sim.replay import replay_plan

    _, _, plan, _ = _release_plan(box)
    report = replay_plan(write_plan(plan, tmp_path / "release.yaml"))
    assert report.passed, report.verdict
    assert report.max_drift_mm < 2.0 and report.max_drift_deg < 3.0


def test_plan_files_keep_the_object_where_the_plan_says(box):
    """read_plan's pose rules: the first state is at the object block's pose; a repose step's
    path ends at its states' poses (the object block's where a state has none); reposing is
    schema 4; a wrong finger is quoted."""
    plan = plan_regrasp(box, _moved_final(), OPTS).plan
    data = plan.to_dict()
    k = next(i for i, s in enumerate(data["steps"]) if s["action"] == "repose")
    bad = {**data, "states": [dict(s) for s in data["states"]]}
    bad["states"][0]["object_pose"] = {"position": [0.2, 0.0, 0.0], "quat_xyzw": [0.0, 0.0, 0.0, 1.0]}
    with pytest.raises(SpecError, match="the first state's object_pose differs from the object block"):
        plan_from_data(bad)
    bad = {**data, "schema_version": 3}
    with pytest.raises(SpecError, match="schema 4 key; this plan says schema 3|repose steps are schema 4"):
        plan_from_data(bad)
    bad = {**data, "steps": [dict(s) for s in data["steps"]]}
    bad["steps"][k]["finger"] = "thumb"
    with pytest.raises(SpecError, match="expected finger 'object', got 'thumb'"):
        plan_from_data(bad)
    if data["states"][k].get("object_pose") is None:  # the move starts at the object block's pose
        bad = {**data, "steps": [dict(s) for s in data["steps"]]}
        bad["steps"][k]["object_path"] = [[p[0] + 0.09, *p[1:]] for p in data["steps"][k]["object_path"]]
        with pytest.raises(SpecError, match="does not start at state"):
            plan_from_data(bad)


def _pen_turned_10deg():
    """The pen pinch and a tripod of the pen turned 10 deg about the axis across the pinch, its
    thumb and index written where the pinch's turn leaves them (realized)."""
    a = realize(load_grasp(bundled_grasp("icub/pen_palmar_pinch.yaml")))
    spec = load_grasp(bundled_grasp("icub/pen_writing_tripod.yaml"))
    T = np.array(spec.object.T_palm_obj, dtype=float)
    T[:3, :3] = (Rotation.from_matrix(T[:3, :3]) * Rotation.from_euler("y", -10, degrees=True)).as_matrix()
    points = {"thumb": (-0.004876, -0.001043, 0.001342), "index": (0.005, -1.8e-05, -0.001254)}
    fingers = tuple(replace(f, point_obj=points[f.name]) if f.name in points else f for f in spec.fingers)
    return a, realize(replace(spec, object=replace(spec.object, T_palm_obj=T), fingers=fingers))


def test_legs_ending_within_the_slot_tolerance_are_joined_exactly():
    """A pen pinch turned 10 deg about the axis across its pinch into a tripod, the final
    grasp's thumb and index written where the pinch's turn leaves them: at the initial pose
    the final grasp's leg ends with a finger within the slot tolerance (0.001 rad) of the
    initial grasp's posture but not on it. The plan joins the legs with a last waypoint (no
    gait), and every plan returned reads back (each step starts and ends at its states within
    1e-6 rad; before, such a plan was refused by its own verification as written)."""
    a, b = _pen_turned_10deg()
    plan = plan_regrasp(a, b, PlanOptions.for_execution(verify=False)).plan
    back = plan_from_data(plan.to_dict())
    assert len(back.states) == len(plan.states) and any(s.action == "repose" for s in back.steps)
    assert np.allclose(back.states[-1].q, plan.states[-1].q, atol=1e-6)


def test_reposture_keeps_each_contact_on_its_point_and_ends_in_the_other_posture():
    """Two grasps of the pen touching the same points with other postures (the bundled
    writing pose's tripod carried back to the pinch's pose, against the pinch with the
    middle finger landed): `_reposture` joins them with the object still; independently
    re-measured, every waypoint keeps each moved finger's outermost link within the
    follower's tolerance of its object point, and the last one is the other grasp's."""
    from planner.pose_search import _reposture, leg
    from planner.repose import FOLLOW_TOL_M, _holds, at_pose, state_reason

    def outer(g, f):  # the finger's outermost contact point (object frame)
        return _holds(g)[f][0][2]

    pinch = realize(load_grasp(bundled_grasp("icub/pen_palmar_pinch.yaml")))
    pose = realize(load_grasp(bundled_grasp("icub/pen_writing_pose.yaml")))
    T = np.asarray(pinch.obj.T_palm_obj, float)
    back = leg(pose, T, OPTS, None).end
    fingers = [f for f in ("thumb", "index")
               if np.linalg.norm(outer(back, f) - outer(pinch, f)) < 2 * FOLLOW_TOL_M]
    assert fingers and any(np.max(np.abs(np.asarray(back.finger_q[f]) - pinch.finger_q[f])) > 0.05 for f in fingers)
    path = _reposture(back, pinch, fingers, OPTS)
    assert path is not None and len(path) > 1
    for f in fingers:
        idx = list(back.hand.fingers[f].q_index)
        assert np.allclose(path[-1][idx], pinch.finger_q[f])
        others = [i for i in range(len(back.q)) if i not in {k for x in fingers for k in back.hand.fingers[x].q_index}]
        assert np.allclose(path[:, others], np.asarray(back.q)[others])
        link = [c.link for c in back.contacts if c.finger == f]
        for q in path[:-1]:
            g = at_pose(back, T, q)
            assert f in g.patches and state_reason(g, OPTS) is None
            d = g.hand.state(q).link_object(g.obj, [link[-1]])
            assert abs(min(x.distance_m for x in d.values())) < 2 * FOLLOW_TOL_M
            assert np.linalg.norm(outer(g, f) - outer(back, f)) < 2 * FOLLOW_TOL_M


def test_candidate_poses_share_one_verification_budget():
    """The reposing candidates share ``--verify-attempts``: each gait search gets what the
    ones before left, and once it is spent the candidates left are not tried, so a refusal
    replays a bounded number of sequences however many poses there are. The refusal opens
    with the stop on the budget (not with "no reposing move joins them": the poses left were
    never tried) and names the first pose not tried. The stand-in gait search replays, as
    `planner.regrasp.plan_gaits` does, at most the attempts it is given (four, or its share)."""
    from planner.errors import NoSequenceError
    from planner.pose_search import candidate_poses, plan_with_reposing

    pinch = realize(load_grasp(bundled_grasp("icub/pen_palmar_pinch.yaml")))
    pose = realize(load_grasp(bundled_grasp("icub/pen_writing_pose.yaml")))
    opts = PlanOptions.for_execution(motion=False, verify_attempts=6)
    names = [name for name, _ in candidate_poses(pinch, pose)]
    assert len(names) > 2
    calls = []

    def gaits(a, b, o, on_replay, **_):
        calls.append(o.verify_attempts)
        for _ in range(min(4, o.verify_attempts)):  # sequences replayed and rejected, within its share
            on_replay()
        raise NoSequenceError("no sequence held in the simulator")

    with pytest.raises(NoSequenceError) as err:
        plan_with_reposing(pinch, pose, opts, {}, False, gaits, _no_finger_path)
    text = str(err.value)
    assert calls == [6, 2]  # 4 + 2 replayed: the budget of 6 spent by the first two candidates
    assert text.startswith("the grasps' object poses differ by ")
    assert text.split(": ")[0].endswith("search for a reposing move stopped on the --verify-attempts budget "
                                        "(6 sequences replayed) before trying every candidate pose")
    assert "no reposing move joins them" not in text
    assert f"not tried at {names[2]} and after: 6 sequences were replayed" in text


def test_the_gait_search_counts_each_replayed_sequence_within_the_attempts_it_is_given(monkeypatch):
    """What the shared budget's stand-in above assumes of `planner.regrasp.plan_gaits`: it
    calls ``on_replay`` once per sequence its verification replays (every direction rejecting
    each: a stand-in simulator), and replays no more sequences than its ``verify_attempts``."""
    import planner.sim.verify as verify
    from planner.errors import NoSequenceError
    from planner.regrasp import plan_gaits

    a, b = (realize(load_grasp(bundled_grasp(n))) for n in ("icub/box_parallel_extension.yaml", "icub/box_ir2m.yaml"))
    replayed, counted = [], []

    def never(plan, hand, directions, workers=None, meanwhile=None):
        if meanwhile is not None:
            meanwhile()
        replayed.append(plan.summary["order"])
        return verify.Verification(False, tuple((n, False, "FAIL: made up", 1, False, 9.0, 9.0)
                                                for n, _ in directions), 0.0)

    monkeypatch.setattr(verify, "verify_plan", never)
    with pytest.raises(NoSequenceError, match=r"in 3 attempt\(s\) \(--verify-attempts"):
        plan_gaits(a, b, PlanOptions.for_execution(motion=False, verify_attempts=3, repose=False),
                   on_replay=lambda: counted.append(1))
    # 3 sequences, then (every one failed) the final grasp alone, which is no sequence: not counted
    assert replayed[-1] == [] and len(replayed[:-1]) == len(counted) == 3 and len({tuple(o) for o in replayed}) == 4


def test_fingers_within_snap_rad_still_join_when_the_re_posturing_fails(monkeypatch):
    """The final grasp's leg of the 10 deg pen turn (`test_legs_ending_within_the_slot_tolerance_are_joined_exactly`)
    ends with thumb and index within `SNAP_RAD` of the pinch's postures. When the re-posturing
    path cannot be made (a farther finger that cannot keep its contact: `_reposture` None),
    those fingers still take the other grasp's joints in one waypoint with the object still,
    as before there were re-posturing paths."""
    from planner import pose_search
    from planner.regrasp import _straight_gait

    a, b = _pen_turned_10deg()
    opts = PlanOptions.for_execution(verify=False)
    P = np.asarray(a.obj.T_palm_obj, float)
    first, back = pose_search.leg(a, P, opts, _straight_gait), pose_search.leg(b, P, opts, _straight_gait)
    near = [f for f in ("thumb", "index")
            if 0 < np.max(np.abs(np.asarray(back.end.finger_q[f]) - a.finger_q[f])) <= pose_search.SNAP_RAD]
    assert first.move is None and back.move is not None and near
    monkeypatch.setattr(pose_search, "_reposture", lambda *args: None)
    _, snapped = pose_search._snap(first, back, opts)
    assert snapped is not back and len(snapped.move.q_path) == len(back.move.q_path) + 1
    assert np.array_equal(snapped.move.poses[-1], snapped.move.poses[-2])  # the object still
    for f in near:
        assert np.allclose(snapped.end.finger_q[f], a.finger_q[f])
        assert np.allclose(snapped.move.q_path[-1][list(a.hand.fingers[f].q_index)], a.finger_q[f])


def test_a_candidate_whose_plan_fails_the_physics_check_is_refused(monkeypatch):
    """plan_with_reposing runs the physics check `replay` runs (`planner.audit.audit_plan`) on
    every composed plan before it is verified or returned: a plan failing it is not returned,
    its candidate is refused naming the check's first problem, and the next one is tried."""
    from planner import audit
    from planner.errors import NoSequenceError
    from planner.pose_search import plan_with_reposing

    pinch = realize(load_grasp(bundled_grasp("icub/pen_palmar_pinch.yaml")))
    pose = realize(load_grasp(bundled_grasp("icub/pen_writing_pose.yaml")))
    opts = PlanOptions.for_execution(motion=False, verify=False)
    audited = []

    def failing(plan, hand=None, paths=True, verified=True):
        audited.append(plan)
        rep = audit.AuditReport("<plan>")
        rep.add("steps[1] (repose object): a made-up problem")
        return rep

    class NoGaits:  # the gaits' result at the candidate pose: none needed
        plan = whole = None

    monkeypatch.setattr(audit, "audit_plan", failing)
    with pytest.raises(NoSequenceError) as err:
        plan_with_reposing(pinch, pose, opts, {}, False, lambda a, b, o, r=None, **_: NoGaits(), _no_finger_path)
    words = str(err.value)
    assert len(audited) >= 2 and words.count("the plan fails a physics check (steps[1] (repose object): a made-up problem)") \
        == len(audited)


def test_a_plan_with_reposing_records_the_verify_attempts_it_was_given():
    """The gait search at a candidate pose gets what is left of the shared --verify-attempts
    (`plan_with_reposing`); the composed plan's parameters still record the option given
    (6), not the gait search's share (2)."""
    from planner import pose_search
    from planner.regrasp import _straight_gait, plan_gaits

    pinch = realize(load_grasp(bundled_grasp("icub/pen_palmar_pinch.yaml")))
    pose = realize(load_grasp(bundled_grasp("icub/pen_writing_pose.yaml")))
    opts = PlanOptions.for_execution(motion=False, verify=False, verify_attempts=6)
    P = np.asarray(pinch.obj.T_palm_obj, float)
    first, back = pose_search._snap(pose_search.leg(pinch, P, opts, _straight_gait),
                                    pose_search.leg(pose, P, opts, _straight_gait), opts)
    gait = plan_gaits(first.end, back.end, replace(opts, verify_attempts=2)).plan
    plan = pose_search.compose(pinch, pose, opts, first, gait, back, P)
    assert gait.parameters["verify_attempts"] == 2 and plan.parameters["verify_attempts"] == 6


def _pen_pair():
    return tuple(realize(load_grasp(bundled_grasp(f"icub/{n}.yaml"))) for n in ("pen_palmar_pinch", "pen_writing_pose"))


def _stand_in_simulator(monkeypatch, verdict):
    """``planner.sim.verify.verify_plan`` replaced: every plan it is asked to replay is kept,
    and ``verdict(plan, k)`` (k: how many were asked before) gives None (every direction
    passes) or the plan step the first direction fails at."""
    import planner.sim.verify as verify

    replayed = []

    def stand_in(plan, hand, directions, workers=None, meanwhile=None, **_):
        if meanwhile is not None:
            meanwhile()
        step = verdict(plan, len(replayed))
        replayed.append(plan)
        if step is None:
            return verify.Verification(True, tuple((n, True, "PASS", None, False, 0.1, 0.1) for n, _ in directions), 0.0)
        n = directions[0][0]
        return verify.Verification(False, ((n, False, "FAIL: made up", step, False, 9.0, 9.0),), 0.0)

    monkeypatch.setattr(verify, "verify_plan", stand_in)
    return replayed


def _repose_steps(plan) -> list[int]:
    return [k for k, s in enumerate(plan.steps) if s.action == "repose"]


def test_gaits_at_a_candidate_pose_are_verified_inside_the_whole_plan(monkeypatch):
    """With reposing, each gait sequence the search finds is replayed once, inside the whole
    plan (the reposing move included), not alone and then again whole: the pen's pinch to its
    writing pose (gaits at the pinch's pose, then the turn) is replayed once when the simulator
    passes it, and the plan returned is the one replayed, its verification recorded."""
    replayed = _stand_in_simulator(monkeypatch, lambda plan, k: None)
    pinch, pose = _pen_pair()
    plan = plan_regrasp(pinch, pose, PlanOptions.for_execution(motion=False)).plan
    assert len(replayed) == 1
    assert _repose_steps(replayed[0]) and [s.action for s in replayed[0].steps] == [s.action for s in plan.steps]
    ver = plan.summary["verification"]
    assert ver["passed"] and ver["attempts"] == 1 and ver["rejected"] == []


def test_a_gait_step_failing_in_the_whole_plan_rejects_that_sequence_only(monkeypatch):
    """A failure at a gait step of the whole plan rejects that sequence, as a failure of the
    gaits alone did: the next sequence is replayed, again whole, and the rejection is recorded
    at the whole plan's step (the plan file's). The pen's first candidate is the pinch turned
    to the writing pose (step 0), then its gaits (from step 1): its first gait step fails once."""
    failed = []

    def verdict(plan, k):
        if _repose_steps(plan)[:1] == [0] and not failed:
            failed.append(plan)
            return 1
        return None

    replayed = _stand_in_simulator(monkeypatch, verdict)
    pinch, pose = _pen_pair()
    plan = plan_regrasp(pinch, pose, PlanOptions.for_execution(motion=False)).plan
    assert len(replayed) == 2 and replayed[0] is failed[0] and _repose_steps(replayed[1])[:1] == [0]
    assert [s.action for s in replayed[1].steps] == [s.action for s in plan.steps] and plan.steps[0].action == "repose"
    ver = plan.summary["verification"]
    assert ver["attempts"] == 2 and len(ver["rejected"]) == 1 and ver["rejected"][0]["step"] == 1
    s = failed[0].steps[1]
    assert ver["rejected"][0]["order"][0] == f"{s.finger}:{s.action}>" + ver["rejected"][0]["order"][0].split(">")[1]


def test_a_reposing_move_failing_in_the_whole_plan_ends_its_candidate(monkeypatch):
    """A failure outside the gaits (here the reposing move) ends the candidate: no other gait
    sequence mends the move. The pen's first candidate (the pinch turned first) is replayed
    once; the next candidate (the middle finger lands, then the turn) is replayed next."""
    replayed = _stand_in_simulator(monkeypatch, lambda plan, k: 0 if _repose_steps(plan)[:1] == [0] else None)
    pinch, pose = _pen_pair()
    plan = plan_regrasp(pinch, pose, PlanOptions.for_execution(motion=False)).plan
    assert [_repose_steps(p)[:1] == [0] for p in replayed] == [True, False]
    assert plan.steps[0].action != "repose" and plan.summary["verification"]["attempts"] == 1


def test_the_reposing_candidates_share_one_max_rounds():
    """The candidates' gait searches share ``--max-rounds`` (rounds of intermediate contacts,
    those after rejected sequences included), as they share ``--verify-attempts``: each
    search gets what the ones before left (a stand-in search here takes three rounds when it
    can, and counts as stopped by the budget when it wants one and none is left, as
    `planner.regrasp.anytime_search` does), so a refusal's searches add at most that many
    rounds of contacts together; the refusal says which searches the spent budget stopped
    (the first in full), and says nothing of it with --max-rounds 0 (no rounds wanted)."""
    from planner.errors import NoSequenceError
    from planner.pose_search import plan_with_reposing

    pinch, pose = _pen_pair()
    full = "no rounds of intermediate contacts were left: the searches before it spent the --max-rounds"
    for max_rounds in (4, 3, 0):
        left = []

        def gaits(a, b, o, on_replay, budget=None, **_):
            left.append(budget.left)
            if o.max_rounds > 0 and budget.spent:
                budget.stopped += 1
            budget.take(min(3, budget.left))
            raise NoSequenceError("no finger-gaiting sequence")

        with pytest.raises(NoSequenceError) as err:
            plan_with_reposing(pinch, pose, PlanOptions.for_execution(motion=False, max_rounds=max_rounds), {}, False,
                               gaits, _no_finger_path)
        assert len(left) >= 2 and left == [max(0, max_rounds - 3 * k) for k in range(len(left))]
        text = str(err.value)
        starved = sum(x == 0 for x in left) if max_rounds else 0
        assert text.count(full) == min(1, starved) and text.count("(no rounds left)") == max(0, starved - 1)


def test_a_whole_plan_that_fails_the_physics_check_with_its_inputs_is_not_returned(monkeypatch):
    """The whole plan the gait search verified passes the physics check again with the
    inputs (the check `verify` runs on the written file) before it is returned: one that
    fails it is refused, naming the check's problem."""
    from planner import audit
    from planner.errors import NoSequenceError

    replayed = _stand_in_simulator(monkeypatch, lambda plan, k: None)

    def failing(plan, hand=None, paths=True, verified=True):
        rep = audit.AuditReport("<plan>")
        rep.add("inputs: a made-up problem")
        return rep

    monkeypatch.setattr(audit, "audit_plan", failing)
    pinch, pose = _pen_pair()
    with pytest.raises(NoSequenceError) as err:
        plan_regrasp(pinch, pose, PlanOptions.for_execution(motion=False))
    assert replayed and "the plan fails a physics check (inputs: a made-up problem)" in str(err.value)


def test_a_gait_search_makes_no_round_beyond_the_budget_it_shares(tmp_path):
    """`planner.regrasp.plan_gaits` with a shared `RoundBudget`: rounds of intermediate contacts
    come out of it (the search's own --max-rounds still bounds it), none once it is spent; the
    Allegro sphere pair whose middle finger takes the ring finger's place needs intermediate
    contacts, so with none left it is refused, saying the searches before it spent them."""
    import importlib.util
    from pathlib import Path

    from planner.errors import NoSequenceError
    from planner.regrasp import RoundBudget, plan_gaits

    root = Path(__file__).resolve().parents[1]
    spec = importlib.util.spec_from_file_location("bench_plan", root / "benchmarks" / "bench_plan.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    a, b = (realize(load_grasp(p)) for p in bench.middle_for_ring_pair(tmp_path))
    opts = PlanOptions(motion=False, repose=False)
    free = plan_gaits(a, b, opts).plan.summary["search"]["rounds"]
    assert free >= 1  # (the pair needs intermediate contacts)
    budget = RoundBudget(free + 3)
    plan = plan_gaits(a, b, opts, budget=budget).plan
    assert plan.summary["search"]["rounds"] == free and budget.used == free and budget.left == 3
    spent = RoundBudget(0)
    with pytest.raises(NoSequenceError, match="the rounds shared with the other searches were spent"):
        plan_gaits(a, b, opts, budget=spent)
    assert spent.stopped == 1  # (it would have made a round)
    none_wanted = RoundBudget(0)
    with pytest.raises(NoSequenceError) as err:
        plan_gaits(a, b, replace(opts, max_rounds=0), budget=none_wanted)
    assert none_wanted.stopped == 0 and "the rounds shared" not in str(err.value)


def test_the_final_grasp_is_replayed_alone_only_when_no_plan_is_found(monkeypatch):
    """Every gait sequence at the grasps' own pose failing in the simulator, the final grasp was
    replayed alone for the refusal's words ("the final grasp 'X' alone does not hold ...")
    before the reposing moves were tried: a plan they found threw those words, and the replay,
    away. It is replayed once no plan is found, its words where they were (a stand-in simulator
    failing every plan without a reposing move; then every plan)."""
    from planner.errors import NoSequenceError

    def gaits_fail(plan, k):
        return None if _repose_steps(plan) else (0 if plan.steps else -1)

    replayed = _stand_in_simulator(monkeypatch, gaits_fail)
    a, b = (realize(load_grasp(bundled_grasp(n))) for n in ("icub/box_parallel_extension.yaml", "icub/box_ir2m.yaml"))
    opts = PlanOptions.for_execution(motion=False, verify_attempts=2)
    plan = plan_regrasp(a, b, opts).plan
    assert _repose_steps(plan) and plan.summary["verification"]["passed"]
    assert replayed and all(p.steps for p in replayed), [len(p.states) for p in replayed]  # (no one-state plan)

    replayed = _stand_in_simulator(monkeypatch, lambda plan, k: 0 if plan.steps else -1)
    with pytest.raises(NoSequenceError) as err:
        plan_regrasp(a, b, opts)
    text = str(err.value)
    assert sum(not p.steps for p in replayed) == 1  # the final grasp alone, once
    assert "; the final grasp 'box_ir2m' alone does not hold in the simulator either (" in text
    assert text.index("the final grasp 'box_ir2m' alone") < text.index("; --no-verify returns the best sequence") \
        < text.index("; with the object moved: ")
