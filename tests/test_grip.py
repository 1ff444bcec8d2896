"""The grip model (planner.grip): analytic cases, witnesses re-checked, the hand's statics, the
planner's verification loop and the replay's honest verdict."""

from __future__ import annotations

import math

import numpy as np
import pytest

from planner.model import Friction
from planner.grip import (FACTOR_MAX, FingerStatics, balance_forces, finger_statics, hold_capacity, torque_demand,
                          torque_rows)

R_M, LEVER_M, TAU_MAX, MU, W_N = 0.02, 0.05, 0.3, 0.5, 2.0


def _pinch(c_nm: float = 0.0, effort: float = TAU_MAX):
    """Two opposed contacts at +-r on the x axis, each pushed by a one-joint finger of lever L
    (torque L f_n for a normal force f_n); gravity -z adds ``c_nm`` to each joint."""
    patches = {"a": (np.array([[R_M, 0, 0]]), np.array([[-1.0, 0, 0]])),
               "b": (np.array([[-R_M, 0, 0]]), np.array([[1.0, 0, 0]]))}
    statics = {}
    for f, n in (("a", -1.0), ("b", 1.0)):
        J = np.zeros((1, 6, 1))
        J[0, 0, 0] = n * LEVER_M  # the point moves along its inward normal: tau = J^T f = L f_n
        G = np.array([[0.0, 0.0, -c_nm / 9.81]])  # tau_g = G @ (0, 0, -9.81) = c
        statics[f] = FingerStatics(f, (f"{f}_j",), J, G, np.array([effort]))
    load = np.array([0.0, 0.0, -W_N, 0.0, 0.0, 0.0])
    return patches, statics, load, np.array([0.0, 0.0, -9.81])


def test_pinch_capacity_is_friction_times_what_the_joints_push():
    """Two opposed one-joint fingers hold a tangential weight W up to 2 mu tau_max / (L W) times
    (the 16-gon has the tangent as a vertex: exact), limited by a joint at its limit."""
    patches, statics, load, g = _pinch()
    cap = hold_capacity(patches, statics, Friction(MU, 0.0), load, g, margin=1.0)
    assert cap.factor == pytest.approx(2 * MU * TAU_MAX / (LEVER_M * W_N), rel=1e-6)
    assert cap.limit is not None and cap.limit.joint in ("a_j", "b_j") and cap.limit.value == pytest.approx(TAU_MAX)
    # the friction margin scales the answer; a per-finger cap below tau_max / L binds instead
    assert hold_capacity(patches, statics, Friction(MU, 0.0), load, g, margin=0.75).factor == pytest.approx(
        0.75 * cap.factor, rel=1e-6)
    capped = hold_capacity(patches, statics, Friction(MU, 0.0), load, g, margin=1.0, force_cap_n=2.0)
    assert capped.factor == pytest.approx(2 * MU * 2.0 / W_N, rel=1e-6) and capped.limit.joint is None


def test_pinch_own_weight_takes_its_share_of_the_torque():
    """Gravity torque c on each joint leaves tau_max - c to push with; over tau_max the
    fingers cannot hold even themselves (factor 0, the joint named)."""
    patches, statics, load, g = _pinch(c_nm=0.1)
    cap = hold_capacity(patches, statics, Friction(MU, 0.0), load, g, margin=1.0)
    assert cap.factor == pytest.approx(2 * MU * (TAU_MAX - 0.1) / (LEVER_M * W_N), rel=1e-6)
    patches, statics, load, g = _pinch(c_nm=0.4)
    cap = hold_capacity(patches, statics, Friction(MU, 0.0), load, g, margin=1.0)
    assert cap.factor == 0.0 and cap.limit is not None and cap.limit.value == pytest.approx(0.4)


def test_pinch_torque_demand_and_its_agreement_with_capacity():
    """To hold h W the pinch needs L h W / (2 mu) N m at each joint: the fraction u of the
    limit is that over tau_max; u <= 1 exactly when the capacity is at least h."""
    patches, statics, load, g = _pinch()
    fr = Friction(MU, 0.0)
    cap = hold_capacity(patches, statics, fr, load, g, margin=1.0).factor
    for h in (0.5 * cap, 0.99 * cap, 1.01 * cap, 3.0 * cap):
        d = torque_demand(patches, statics, fr, load, g, factor=h, margin=1.0)
        assert d.ratio == pytest.approx(LEVER_M * h * W_N / (2 * MU * TAU_MAX), rel=1e-6)
        assert (d.ratio <= 1.0) == (h <= cap)
        assert d.limit.value == pytest.approx(LEVER_M * h * W_N / (2 * MU), rel=1e-6)
        assert f"needs {d.limit.value:.3g} N m (limit {TAU_MAX:.3g} N m)" in d.words()


def _random_grasp(rng, n_fingers: int = 3):
    """Contacts on a sphere roughly around it, each finger a random 3-joint Jacobian."""
    patches, statics = {}, {}
    for i in range(n_fingers):
        a = 2 * np.pi * i / n_fingers + rng.uniform(-0.4, 0.4)
        p = R_M * np.array([np.cos(a), np.sin(a), rng.uniform(-0.3, 0.3)])
        p = R_M * p / np.linalg.norm(p)
        patches[f"f{i}"] = (p[None, :], -(p / np.linalg.norm(p))[None, :])
        J = rng.normal(scale=0.03, size=(1, 6, 3))
        J[0, 3:] *= 10.0  # rad/s per rad/s: angular rows of order 1
        statics[f"f{i}"] = FingerStatics(f"f{i}", tuple(f"f{i}_{k}" for k in range(3)), J,
                                         rng.normal(scale=0.002, size=(3, 3)), rng.uniform(0.2, 0.6, size=3))
    load = np.r_[rng.normal(size=3), 0.0, 0.0, 0.0]
    return patches, statics, load, 9.81 * load[:3] / np.linalg.norm(load[:3])


def test_capacity_witness_rechecks_on_random_grasps():
    """On seeded random grasps the capacity's witness forces balance factor x load (force and
    torque), lie in the cones (margin) with torsion within gamma, and keep every joint within
    its limit: |g + J^T [f ; m]| <= tau_max, recomputed here; the torque demand agrees."""
    rng = np.random.default_rng(7)
    fr, margin = Friction(0.8, 0.004), 0.75
    checked = 0
    for _ in range(30):
        patches, statics, load, g = _random_grasp(rng)
        cap = hold_capacity(patches, statics, fr, load, g, margin=margin)
        if not 0 < cap.factor < FACTOR_MAX:
            continue
        checked += 1
        force = sum(cap.forces[f].sum(axis=0) for f in patches)
        torque = sum(np.cross(patches[f][0], cap.forces[f]).sum(axis=0) + cap.moments[f].sum(axis=0) for f in patches)
        np.testing.assert_allclose(force, -cap.factor * load[:3], atol=1e-6)
        np.testing.assert_allclose(torque, -cap.factor * load[3:], atol=1e-7)
        for f, (_, n) in patches.items():
            fn = float(cap.forces[f][0] @ n[0])
            tangential = np.linalg.norm(cap.forces[f][0] - fn * n[0])
            assert fn >= -1e-9 and tangential <= margin * fr.mu * fn + 1e-7
            assert abs(float(cap.moments[f][0] @ n[0])) <= margin * fr.gamma * fn + 1e-9
            st = statics[f]
            tau = st.gravity @ g + st.jacobians[0, :3].T @ cap.forces[f][0] + st.jacobians[0, 3:].T @ cap.moments[f][0]
            assert np.all(np.abs(tau) <= st.effort + 1e-6)
        for h in (0.9 * cap.factor, 1.1 * cap.factor):
            d = torque_demand(patches, statics, fr, load, g, factor=h, margin=margin)
            assert (d.ratio <= 1.0 + 1e-6) == (h <= cap.factor)
    assert checked >= 10


def test_capacity_scales_with_the_joints_when_the_hand_weighs_nothing():
    """Without gravity torques the program is homogeneous: k times every limit holds k times
    the load (an invariance of the model, not of a solver run)."""
    rng = np.random.default_rng(3)
    fr = Friction(0.8, 0.004)
    for _ in range(10):
        patches, statics, load, g = _random_grasp(rng)
        light = {f: FingerStatics(s.finger, s.joints, s.jacobians, np.zeros_like(s.gravity), s.effort)
                 for f, s in statics.items()}
        strong = {f: FingerStatics(s.finger, s.joints, s.jacobians, s.gravity, 3.0 * s.effort) for f, s in light.items()}
        a = hold_capacity(patches, light, fr, load, g).factor
        if 0 < a < FACTOR_MAX / 3:
            assert hold_capacity(patches, strong, fr, load, g).factor == pytest.approx(3.0 * a, rel=1e-5)


def test_finger_statics_match_finite_differences_and_pinocchio_gravity():
    """The object-frame contact Jacobian of a finger is the finite difference of its contact
    point (fixed to the link) over the finger's joints, and its gravity rows give pinocchio's
    generalized gravity for any gravity vector."""
    from planner.grasp import load_grasp
    from planner.realization import realize
    from planner.resources import bundled_grasp

    g = realize(load_grasp(bundled_grasp("icub/sphere_ir2m.yaml")))
    hand, T = g.hand, np.asarray(g.obj.T_palm_obj)
    R = T[:3, :3]
    for f, (pts, _) in g.patches.items():
        p_obj = pts[:1]
        st = finger_statics(hand, f, g.q, p_obj, T)
        p_palm = R @ p_obj[0] + T[:3, 3]
        link = min(hand.fingers[f].contact_links,
                   key=lambda l: hand.state(g.q).point_distance(p_palm, hand.collision.link_geometries[l]))
        T0 = hand.state(g.q).link_pose(link)
        p_link = np.linalg.inv(T0) @ np.r_[p_palm, 1.0]
        cols = list(hand.fingers[f].q_index)
        num = np.zeros((3, len(cols)))
        for k, c in enumerate(cols):
            dq = np.zeros(len(g.q))
            dq[c] = 1e-6
            hi = R.T @ (hand.state(g.q + dq).link_pose(link) @ p_link)[:3]
            lo = R.T @ (hand.state(g.q - dq).link_pose(link) @ p_link)[:3]
            num[:, k] = (hi - lo) / 2e-6
        np.testing.assert_allclose(st.jacobians[0, :3], num, atol=1e-6)
        g_obj = np.array([1.0, -2.0, 9.0])
        np.testing.assert_allclose(st.gravity @ g_obj, hand.state(g.q).gravity_torques(R @ g_obj)[cols], atol=1e-12)
        np.testing.assert_allclose(st.effort, hand.effort[cols])


def test_controller_force_problem_respects_the_joint_rows():
    """The controller's grasp force optimization with a finger's joint rows keeps J^T f within
    the limits (here binding), and without a feasible one returns None."""
    P = np.array([[0.02, 0, 0], [-0.02, 0, 0]])
    N = np.array([[-1.0, 0, 0], [1.0, 0, 0]])
    load = np.array([0, 0, -1.0, 0, 0, 0])
    J = np.array([[-LEVER_M], [0.0], [0.0]])  # (3, 1): tau = L f_n
    rows = [([0], *torque_rows([J], [0.05], [0.0])), ([1], *torque_rows([-J], [0.05], [0.0]))]
    f = balance_forces(P, N, 2.0 * N, load, np.zeros(3), Friction(1.0, 0.0), 0.1, 100.0, margins=((1.0, 0.0),),
                       joint_rows=rows)
    assert f is not None and np.allclose(f.sum(axis=0), -load[:3], atol=1e-7)
    assert LEVER_M * float(f[0] @ N[0]) <= 0.05 + 1e-9  # the 2 N squeeze wanted is cut to 1 N
    weak = [([0], *torque_rows([J], [0.01], [0.0])), ([1], *torque_rows([-J], [0.01], [0.0]))]
    assert balance_forces(P, N, 2.0 * N, load, np.zeros(3), Friction(1.0, 0.0), 0.1, 100.0, margins=((1.0, 0.0),),
                          joint_rows=weak) is None


def test_hand_effort_comes_from_the_urdf_or_the_hand_yaml(tmp_path):
    """The iCub model's joints give 0.5 N m (its URDF); the Allegro's hand.yaml overrides the
    URDF's placeholder 15 N m with 0.7; a bad override is a one-line error naming the key."""
    import shutil

    from planner.errors import SpecError
    from planner.hand import Hand
    from planner.resources import hand_dir

    icub, allegro = Hand.load("icub_right"), Hand.load("allegro_right")
    assert np.all(icub.effort == 0.5) and set(icub.effort_source) == {"urdf"}
    assert np.all(allegro.effort == 0.7) and set(allegro.effort_source) == {"hand.yaml"}
    src = hand_dir("icub_right")
    for name in ("hand.yaml", "icub_right.urdf"):
        shutil.copy(src / name, tmp_path / name)
    spec = (tmp_path / "hand.yaml").read_text()
    (tmp_path / "hand.yaml").write_text(spec + "effort: {thumb_1: 0.2}\n")
    h = Hand.load(tmp_path / "hand.yaml")
    i = h.joint_names.index("thumb_1")
    assert h.effort[i] == 0.2 and h.effort_source[i] == "hand.yaml" and h.effort[0] == 0.5
    (tmp_path / "hand.yaml").write_text(spec + "effort: {thumb_1: -1}\n")
    with pytest.raises(SpecError, match=r"effort\.thumb_1"):
        Hand.load(tmp_path / "hand.yaml")
    (tmp_path / "hand.yaml").write_text(spec + "effort: {thumbb: 0.3}\n")
    with pytest.raises(SpecError, match="thumbb"):
        Hand.load(tmp_path / "hand.yaml")


# --------------------------------------------------------------------------- verification


def test_a_failed_verification_removes_the_transition_and_the_search_goes_on(monkeypatch):
    """plan_regrasp with verify: a sequence whose replay fails at plan step k loses that step's
    graph edge and the next best sequence is verified and returned; the plan records the
    rejected sequence and the directions it passed in. A failure at state 0 ends the search."""
    import planner.sim.verify as verify
    from planner.errors import NoSequenceError
    from planner.grasp import load_grasp
    from planner.options import PlanOptions
    from planner.realization import realize
    from planner.regrasp import plan_regrasp
    from planner.resources import bundled_grasp

    a, b = (realize(load_grasp(bundled_grasp(n))) for n in ("icub/box_parallel_extension.yaml", "icub/box_ir2m.yaml"))
    calls, orders = [], []

    def first_fails(at_state: bool):
        """A verify_plan whose first verification fails side_+x at step 1 (at the state it
        reaches, or in the step) and whose later ones pass."""
        def fake(plan, hand, directions, workers=None, meanwhile=None):
            if meanwhile is not None:  # (the physics check, run while the replays run)
                meanwhile()
            calls.append([s.finger + ":" + s.action for s in plan.steps])
            orders.append([n for n, _ in directions])
            ok = len(calls) > 1
            rows = tuple((n, ok or n != "side_+x", "PASS" if ok or n != "side_+x" else "FAIL: made up",
                          None if ok or n != "side_+x" else 1, at_state, 0.1, 0.1) for n, _ in directions)
            return verify.Verification(ok, rows, 0.0)
        return fake

    monkeypatch.setattr(verify, "verify_plan", first_fails(at_state=False))
    opts = PlanOptions.for_execution(motion=False, time_limit_s=0)
    unverified = plan_regrasp(a, b, PlanOptions.for_execution(motion=False, time_limit_s=0, verify=False))
    res = plan_regrasp(a, b, opts)
    rec = res.plan.summary["verification"]
    # the second sequence is replayed side_+x first (the direction that rejected the first
    # one), then in the other directions as planned, in one verification
    assert len(calls) == 2 and rec["attempts"] == 2 and rec["passed"]
    assert orders == [["palm_down", "palm_up", "side_+x", "side_-x", "side_+y", "side_-y"],
                      ["side_+x", "palm_down", "palm_up", "side_-x", "side_+y", "side_-y"]]
    assert set(rec["directions"]) == {"palm_down", "palm_up", "side_+x", "side_-x", "side_+y", "side_-y"}
    assert rec["rejected"][0]["step"] == 1 and rec["rejected"][0]["direction"] == "side_+x"
    assert rec["rejected"][0]["order"] == list(unverified.sequence.order(unverified.graph.graph["problem"]))
    assert calls[0] == [s.finger + ":" + s.action for s in unverified.plan.steps]
    # the edge of step 1 (a lift's move, or a land) is not in the returned sequence
    assert calls[1] != calls[0]

    # a failure measured at the state a step reaches removes every move into that state
    calls.clear()
    monkeypatch.setattr(verify, "verify_plan", first_fails(at_state=True))
    res = plan_regrasp(a, b, opts)
    bad = dict(unverified.plan.states[2].fingers)
    assert res.plan.summary["verification"]["attempts"] == 2
    assert all(dict(s.fingers) != bad for s in res.plan.states)

    def at_start(plan, hand, directions, workers=None, meanwhile=None):
        if meanwhile is not None:  # (the physics check, run while the replays run)
            meanwhile()
        return verify.Verification(False, tuple((n, False, "FAIL: dropped", -1, False, 40.0, 9.0) for n, _ in directions),
                                   0.0)

    monkeypatch.setattr(verify, "verify_plan", at_start)
    with pytest.raises(NoSequenceError, match="initial grasp .* does not hold in the simulator"):
        plan_regrasp(a, b, opts)


def test_when_every_sequence_fails_in_the_simulator_more_contacts_are_tried_then_the_error_says_why(monkeypatch):
    """Replays that fail every sequence (at its second step): the planner adds rounds of
    intermediate contacts after the graph's sequences are used up (a bounded number), then
    fails with one line naming the sequences that failed in the simulator."""
    import planner.sim.verify as verify
    from planner.errors import NoSequenceError
    from planner.grasp import load_grasp
    from planner.options import PlanOptions
    from planner.realization import realize
    from planner.regrasp import RESUME_ROUNDS, plan_regrasp
    from planner.resources import bundled_grasp

    a, b = (realize(load_grasp(bundled_grasp(n))) for n in ("icub/box_parallel_extension.yaml", "icub/box_ir2m.yaml"))
    calls, orders = [], []

    def never(plan, hand, directions, workers=None, meanwhile=None):
        if meanwhile is not None:  # (the physics check, run while the replays run)
            meanwhile()
        calls.append(1)
        rows = tuple((n, False, "FAIL: made up", 1, False, 9.0, 9.0) for n, _ in directions)
        return verify.Verification(False, rows, 0.0)

    import planner.regrasp as regrasp

    searches = []
    search = regrasp.anytime_search

    def counted(*args, prior=None, **kw):
        searches.append(prior is not None)
        return search(*args, prior=prior, **kw)

    monkeypatch.setattr(verify, "verify_plan", never)
    monkeypatch.setattr(regrasp, "anytime_search", counted)
    with pytest.raises(NoSequenceError) as err:
        plan_regrasp(a, b, PlanOptions.for_execution(motion=False, verify_attempts=100, repose=False))
    text = str(err.value)
    assert "sequences that failed in the simulator" in text and "FAIL: made up" in text and "\n" not in text
    assert searches[0] is False and 1 <= sum(searches) <= RESUME_ROUNDS  # rounds resumed, a bounded number
    assert 1 < len(calls) < 100


def test_state_holds_as_planned_only_with_the_plans_fingers():
    """A state passes the honest check when nothing but the plan's fingers carries the object
    and each of them touches: the palm carrying, or a planned finger off the object, fails."""
    from planner.sim.report import StateReport

    def state(sim, carriers):
        return StateReport(1, True, 1.0, ("thumb", "index", "middle"), tuple(sim), True, 0.01, True, 0.01, 3,
                           0.1, 0.1, {}, {}, tuple(carriers))

    assert state(["index", "middle", "thumb"], ["index", "thumb"]).holds_as_planned
    assert not state(["index", "middle", "palm", "thumb"], ["index", "palm", "thumb"]).holds_as_planned
    assert not state(["palm", "thumb"], ["palm", "thumb"]).holds_as_planned
    assert not state(["index", "thumb"], ["index", "thumb"]).holds_as_planned
    assert state(["index", "middle", "palm", "thumb"], ["index", "middle", "thumb"]).holds_as_planned  # a graze


def test_parallel_replays_equal_serial_ones(tmp_path):
    """replay_directions with two worker processes gives the serial run's reports, number for
    number (each replay is deterministic and independent)."""
    from planner.grasp import load_grasp
    from planner.gravity import gravity_directions
    from planner.plan import read_plan
    from planner.plan_data import write_plan
    from planner.options import PlanOptions
    from planner.realization import realize
    from planner.regrasp import plan_regrasp
    from planner.resources import bundled_grasp
    from planner.sim.verify import replay_directions

    a, b = (realize(load_grasp(bundled_grasp(n))) for n in ("icub/sphere_ir2m.yaml", "icub/sphere_four_finger.yaml"))
    plan = plan_regrasp(a, b, PlanOptions.for_execution(motion=False, verify=False, gravity_set=2)).plan
    path = write_plan(plan, tmp_path / "p.json")
    rd = read_plan(path)
    dirs = gravity_directions(a.hand.palm_normal, 2)
    serial = replay_directions(rd, a.hand, dirs, workers=1)
    parallel = replay_directions(rd, a.hand, dirs, workers=2)
    for s, p in zip(serial, parallel):
        assert (s.passed, s.verdict, s.max_drift_mm, s.max_drift_deg, s.sim_steps) == (
            p.passed, p.verdict, p.max_drift_mm, p.max_drift_deg, p.sim_steps)
        assert [r.carried_n for r in s.states] == [r.carried_n for r in p.states]
    assert not math.isnan(serial[0].max_drift_mm)


def test_moves_taken_out_before_a_resumed_round_are_still_known_to_the_explanation(monkeypatch):
    """After every sequence failed in the simulator the search resumes with intermediate
    contacts in a new graph that skips the moves taken out: the new graph still records them
    (``removed_moves``, and ``removed_with_state`` for the moves into a state the simulator
    rejected, which the refusal's explanation names), every time the search returns."""
    import planner.regrasp as regrasp
    import planner.sim.verify as verify
    from planner.errors import NoSequenceError
    from planner.grasp import load_grasp
    from planner.options import PlanOptions
    from planner.realization import realize
    from planner.resources import bundled_grasp

    a, b = (realize(load_grasp(bundled_grasp(n))) for n in ("icub/box_parallel_extension.yaml", "icub/box_ir2m.yaml"))

    def never(plan, hand, directions, workers=None, meanwhile=None):
        if meanwhile is not None:  # (the physics check, run while the replays run)
            meanwhile()
        return verify.Verification(False, tuple((n, False, "FAIL: made up", 1, False, 9.0, 9.0)
                                                for n, _ in directions), 0.0)

    search, seen = regrasp.anytime_search, []

    def checked(*args, prior=None, **kw):
        lazy, info = search(*args, prior=prior, **kw)
        seen.append((prior is not None and lazy is not prior, set(lazy.removed),
                     set(lazy.G.graph.get("removed_moves", ())) | set(lazy.G.graph.get("removed_with_state", ()))
                     | set(lazy.G.graph.get("removed_stuck", ()))))
        return lazy, info

    monkeypatch.setattr(verify, "verify_plan", never)
    monkeypatch.setattr(regrasp, "anytime_search", checked)
    with pytest.raises(NoSequenceError):
        regrasp.plan_regrasp(a, b, PlanOptions.for_execution(motion=False, verify_attempts=100, repose=False))
    assert any(new and removed for new, removed, _ in seen)  # a resumed round in a new graph, after removals
    assert all(recorded == removed for _, removed, recorded in seen)


def test_an_initial_grasp_the_simulator_drops_ends_the_plan_without_reposing_routes(monkeypatch):
    """Every plan starts at the initial grasp: when the simulator drops it, no reposing move can
    pass either. The reposing routes were tried anyway (36.8 s, 26 s of it replays, and a
    2,000-character refusal repeating the drop and naming 'step -1' on a sweep's grasp); the
    plan now ends at the drop (`InitialGraspDrops`)."""
    import planner.pose_search as pose_search
    import planner.sim.verify as verify
    from planner.errors import InitialGraspDrops
    from planner.grasp import load_grasp
    from planner.options import PlanOptions
    from planner.realization import realize
    from planner.regrasp import plan_regrasp
    from planner.resources import bundled_grasp

    def at_start(plan, hand, directions, workers=None, meanwhile=None):
        if meanwhile is not None:
            meanwhile()
        return verify.Verification(False, tuple((n, False, "FAIL: dropped", -1, False, 40.0, 9.0) for n, _ in directions),
                                   0.0)

    def no_route(*_a, **_k):
        raise AssertionError("a reposing route was tried after the initial grasp dropped")

    g = realize(load_grasp(bundled_grasp("icub/box_ir2m.yaml")))
    assert pose_search.candidate_poses(g, g)  # (the routes exist for this grasp: they would be tried)
    monkeypatch.setattr(verify, "verify_plan", at_start)
    monkeypatch.setattr(pose_search, "plan_with_reposing", no_route)
    with pytest.raises(InitialGraspDrops) as err:
        plan_regrasp(g, g, PlanOptions.for_execution(motion=False))
    assert str(err.value).startswith("the initial grasp 'box_ir2m' does not hold in the simulator (palm_down: FAIL: "
                                     "dropped); no sequence starting from it can pass, nor a reposing move")
