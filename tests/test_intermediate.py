"""Intermediate grasps for reposing (planner.intermediate): contacts each finger keeps alone
along the object's path, re-checked here by forward kinematics (not by the planner's own
follower), grasps valid at both ends, and a pair whose thumb must change its object point
planned as gaits at the initial pose, one reposing move, gaits at the final pose.

The pair is exp10's Allegro cylinder (small): pose B is pose A moved 9.1 mm and turned 8.3 deg,
the two grasps' thumb contacts are far apart on the object and neither thumb follows the
object to the other pose, so every plan needs a thumb gait."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from planner.grasp import load_grasp
from planner.intermediate import (DISTINCT_M, MARGIN_RAD, finger_choices, follow_alone, intermediate_grasps,
                                  joint_margin)
from planner.options import PlanOptions
from planner.realization import realize
from planner.repose import FOLLOW_TOL_M, _holds, object_path, state_reason

PAIRS = Path(__file__).resolve().parents[1] / "experiments" / "results" / "exp10_pairs"
OPTS = PlanOptions.for_execution(motion=False, verify=False)


@pytest.fixture(scope="module")
def pair():
    name = "allegro_right_cylinder_small"
    return tuple(realize(load_grasp(PAIRS / f"{name}_{k}.yaml"), suggest=False) for k in ("initial", "final"))


@pytest.fixture(scope="module")
def through(pair):
    return intermediate_grasps(*pair, OPTS)


def _point(hand, q, link, p_link):
    T = hand.state(q).link_pose(link)
    return T[:3, :3] @ p_link + T[:3, 3]


def _on(T, p_obj):
    return T[:3, :3] @ p_obj + T[:3, 3]


def _with(hand, finger, q_finger, q=None):
    q = np.array(hand.q_open if q is None else q, dtype=float)
    q[list(hand.fingers[finger].q_index)] = q_finger
    return q


def test_a_finger_following_alone_keeps_its_contact_on_its_object_point(pair):
    a, b = pair
    hand = a.hand
    path = object_path(a.obj.T_palm_obj, b.obj.T_palm_obj)
    for f, h in _holds(a).items():
        link, p_link, p_obj = h[0][:3]
        qs = []
        k, why, q_end, margin = follow_alone(hand, a.obj, f, a.q, h, path, True, qs)
        assert len(qs) == k + 1 and (why == "") == (k == len(path) - 1) and why in ("", "follow", "deep")
        for j, qf in enumerate(qs):  # forward kinematics at every waypoint passed
            assert np.linalg.norm(_point(hand, _with(hand, f, qf, a.q), link, p_link) - _on(path[j], p_obj)) \
                <= 2 * FOLLOW_TOL_M
        assert np.allclose(q_end[list(hand.fingers[f].q_index)], qs[-1])
        assert margin == pytest.approx(min(joint_margin(hand, f, _with(hand, f, x)) for x in qs))


def test_sampled_thumb_contacts_are_reached_at_both_poses_off_the_joint_limits(pair):
    a, b = pair
    hand = a.hand
    path = object_path(a.obj.T_palm_obj, b.obj.T_palm_obj)
    # neither grasp's own thumb contact follows the object to the other pose
    assert follow_alone(hand, a.obj, "thumb", a.q, _holds(a)["thumb"], path, True)[0] < len(path) - 1
    assert follow_alone(hand, b.obj, "thumb", b.q, _holds(b)["thumb"], path[::-1], True)[0] < len(path) - 1
    choices = finger_choices(a, b, "thumb", keep=3)
    assert choices and all(c.source == "sampled" for c in choices)
    Ta, Tb = np.asarray(a.obj.T_palm_obj), np.asarray(b.obj.T_palm_obj)
    for c in choices:
        qa, qb = _with(hand, "thumb", c.q_a), _with(hand, "thumb", c.path[-1])
        T_link = hand.state(qa).link_pose(c.link)
        p_link = T_link[:3, :3].T @ (_on(Ta, c.p_obj) - T_link[:3, 3])  # its contact point on the link, at A
        assert hand.state(qa).finger_object_distance(a.obj, "thumb") > -1e-3  # touching, not inside
        assert np.linalg.norm(_point(hand, qb, c.link, p_link) - _on(Tb, c.p_obj)) <= 2 * FOLLOW_TOL_M
        assert min(joint_margin(hand, "thumb", qa), joint_margin(hand, "thumb", qb)) >= MARGIN_RAD
        assert len(c.path) == len(path)
    pts = [c.p_obj for c in choices]
    assert all(np.linalg.norm(p - r) >= DISTINCT_M for i, p in enumerate(pts) for r in pts[:i])


def test_intermediate_grasps_hold_at_both_poses_and_put_the_thumb_elsewhere(pair, through):
    a, b = pair
    out, words = through
    assert out, words
    assert "reposed from A to B" in words
    thumb_a, thumb_b = _holds(a)["thumb"][0][2], _holds(b)["thumb"][0][2]
    for it in out:
        g, end = it.grasp, it.move.end
        assert np.allclose(g.obj.T_palm_obj, a.obj.T_palm_obj) and np.allclose(end.obj.T_palm_obj, b.obj.T_palm_obj)
        assert state_reason(g, OPTS) is None and state_reason(end, OPTS) is None
        assert not g.missing and set(c.finger for c in it.choices) <= set(end.patches)
        p = _holds(g)["thumb"][0][2]
        assert np.linalg.norm(p - thumb_a) > DISTINCT_M and np.linalg.norm(p - thumb_b) > DISTINCT_M
        # each chosen finger's outermost contact is on its object point at B, by forward kinematics
        for c in it.choices:
            link, p_link, p_obj = _holds(g)[c.finger][0][:3]
            assert np.linalg.norm(_point(g.hand, end.q, link, p_link) - _on(end.obj.T_palm_obj, p_obj)) \
                <= 2 * FOLLOW_TOL_M


def test_a_pair_whose_thumb_must_move_plans_gaits_then_one_reposing_move_then_gaits(pair):
    """Today's candidate poses all fail on this pair (an end grasp's thumb cannot follow and
    nothing holds without it); through an intermediate grasp it plans: gaits at pose A, the
    intermediate grasp's reposing move, gaits at pose B, and the plan passes the physics
    check `replay` and `verify` run."""
    from planner.audit import audit_plan
    from planner.plan_data import OBJECT, pose_matrix
    from planner.regrasp import plan_regrasp

    a, b = pair
    plan = plan_regrasp(a, b, replace(OPTS, motion=True)).plan  # (finger paths by the motion planner, as `plan` does)
    assert audit_plan(plan, a.hand).ok
    moves = [k for k, s in enumerate(plan.steps) if s.action == "repose"]
    assert len(moves) == 1 and plan.steps[moves[0]].finger == OBJECT
    k = moves[0]
    assert 0 < k < len(plan.steps) - 1  # gaits before and after it
    path = plan.steps[k].object_path
    assert np.allclose(pose_matrix(path[0]), a.obj.T_palm_obj, atol=1e-6)
    assert np.allclose(pose_matrix(path[-1]), b.obj.T_palm_obj, atol=1e-6)
    assert any(s.finger == "thumb" for s in plan.steps[:k]) or any(s.finger == "thumb" for s in plan.steps[k + 1:])
    assert plan.summary["reposing"]["moves"] == 1


def test_the_gaits_at_the_final_pose_wait_for_a_budget_the_gaits_at_the_initial_pose_left(pair, through, monkeypatch):
    """The intermediate grasps share the candidates' ``--verify-attempts``: when the gaits at
    the initial pose replayed all of it, the gaits at the final pose are not searched (with
    no attempts left) and the refusal says so."""
    import planner.intermediate as inter
    from planner import pose_search
    from planner.errors import NoSequenceError

    a, b = pair
    monkeypatch.setattr(inter, "intermediate_grasps", lambda x, y, o: (through[0][:1], "one intermediate grasp"))
    monkeypatch.setattr(pose_search, "candidate_poses", lambda x, y: [])
    monkeypatch.setattr(pose_search, "through_poses", lambda x, y: [("the final grasp's pose", None)])
    calls = []

    class Held:  # a gait plan that held (its contents are not read before the final pose's gaits)
        plan = whole = None

    def gaits(x, y, o, on_replay, **_):
        calls.append((o.verify, o.verify_attempts))
        for _ in range(o.verify_attempts if o.verify else 0):
            on_replay()
        return Held()

    with pytest.raises(NoSequenceError) as err:
        pose_search.plan_with_reposing(a, b, PlanOptions.for_execution(motion=False, verify_attempts=4), {}, False,
                                       gaits, None)
    assert calls == [(False, 4), (True, 4)]  # (the gaits at the final pose searched first, unverified)
    assert "the gaits at the final grasp's pose not tried: 4 sequences were replayed before" in str(err.value)


def test_an_intermediate_grasp_the_final_pose_gaits_cannot_leave_is_dropped_before_any_replay(pair, through,
                                                                                              monkeypatch):
    """The gaits at the final grasp's pose are searched first, unverified: when none exists,
    the intermediate grasp is dropped before its gaits at the initial pose are searched and
    replayed; the refusal names why, and the rounds of intermediate contacts that search made
    come out of the candidates' shared --max-rounds."""
    import planner.intermediate as inter
    from planner import pose_search
    from planner.errors import NoSequenceError

    a, b = pair
    two = (through[0] * 2)[:2]
    monkeypatch.setattr(inter, "intermediate_grasps", lambda x, y, o: (two, "two intermediate grasps"))
    monkeypatch.setattr(pose_search, "candidate_poses", lambda x, y: [])
    monkeypatch.setattr(pose_search, "through_poses", lambda x, y: [("the final grasp's pose", None)])
    calls = []

    def gaits(x, y, o, on_replay, budget=None, **_):
        calls.append((o.verify, budget.left))
        budget.take()
        raise NoSequenceError("no finger-gaiting sequence: made up")

    with pytest.raises(NoSequenceError) as err:
        pose_search.plan_with_reposing(a, b, PlanOptions.for_execution(motion=False, max_rounds=4), {}, False,
                                       gaits, None)
    assert calls == [(False, 4), (False, 3)]  # no verified search; the first probe's round taken
    assert str(err.value).count("at the final grasp's pose: no finger-gaiting sequence: made up") == 2
    assert "no rounds" not in str(err.value)

    calls.clear()

    def starving(x, y, o, on_replay, budget=None, **_):  # (stopped by the budget as anytime_search is)
        calls.append((o.verify, budget.left))
        if budget.spent:
            budget.stopped += 1
        budget.take(budget.left)
        raise NoSequenceError("no finger-gaiting sequence: made up")

    with pytest.raises(NoSequenceError) as err:
        pose_search.plan_with_reposing(a, b, PlanOptions.for_execution(motion=False, max_rounds=1), {}, False,
                                       starving, None)
    assert calls == [(False, 1), (False, 0)]
    assert str(err.value).count("no rounds of intermediate contacts were left") == 1


def test_a_probe_that_finds_gaits_is_charged_when_the_gaits_at_the_initial_pose_fail(pair, through, monkeypatch):
    """The rounds the final pose's unverified search makes are taken from the shared budget:
    given back only for the verified search there, which makes them again. When the gaits at
    the initial pose fail after it, they stay taken, so the intermediate grasps together make
    at most --max-rounds rounds (here the probe takes two and finds gaits, the initial pose's
    search takes one and fails, for each of two intermediate grasps)."""
    import planner.intermediate as inter
    from planner import pose_search
    from planner.errors import NoSequenceError

    a, b = pair
    two = (through[0] * 2)[:2]
    monkeypatch.setattr(inter, "intermediate_grasps", lambda x, y, o: (two, "two intermediate grasps"))
    monkeypatch.setattr(pose_search, "candidate_poses", lambda x, y: [])
    monkeypatch.setattr(pose_search, "through_poses", lambda x, y: [("the final grasp's pose", None)])
    calls, made = [], []

    class Found:
        plan = whole = None

    def gaits(x, y, o, on_replay, budget=None, **_):
        calls.append((o.verify, budget.left))
        n = min(2 if not o.verify else 1, budget.left)
        budget.take(n)
        made.append(n)
        if not o.verify:
            return Found()
        raise NoSequenceError("no finger-gaiting sequence: made up")

    with pytest.raises(NoSequenceError):
        pose_search.plan_with_reposing(a, b, PlanOptions.for_execution(motion=False, max_rounds=4), {}, False,
                                       gaits, None)
    assert calls == [(False, 4), (True, 2), (False, 1), (True, 0)]
    assert sum(made) == 4


def test_the_same_intermediate_grasps_with_one_process_or_two(pair):
    """Each finger's contacts are computed on their own (seeded per finger), so sampling half
    the fingers in a forked copy (`planner.helper.fork_map`, ``workers`` 2) gives the grasps and
    the words of one process."""
    one = intermediate_grasps(*pair, replace(OPTS, workers=1))
    two = intermediate_grasps(*pair, replace(OPTS, workers=2))
    assert one[1] == two[1]
    assert len(one[0]) == len(two[0]) >= 1
    for x, y in zip(one[0], two[0]):
        assert [(c.finger, c.source, c.link) for c in x.choices] == [(c.finger, c.source, c.link) for c in y.choices]
        for c, d in zip(x.choices, y.choices):
            assert np.array_equal(c.p_obj, d.p_obj) and np.array_equal(c.q_a, d.q_a) and np.array_equal(c.path, d.path)
        assert np.array_equal(x.grasp.q, y.grasp.q)


def _through_the_palm(monkeypatch):
    """exp10 v2's Allegro sphere pair (small offset), only the route through the palm searched:
    (initial, final, the palm's pose, plan_with_reposing's arguments after the options)."""
    from planner import pose_search
    from planner.regrasp import _straight_gait, plan_gaits

    v2 = PAIRS.parent / "exp10_pairs_v2"
    a, b = (realize(load_grasp(v2 / f"allegro_right_sphere_small_{k}.yaml")) for k in ("initial", "final"))
    monkeypatch.setattr(pose_search, "candidate_poses", lambda x, y: [])  # only the route through the palm
    poses = pose_search.through_poses(a, b)
    assert [name.split(" (")[0] for name, _ in poses] == ["the final grasp's pose", "resting on the palm"]
    monkeypatch.setattr(pose_search, "through_poses", lambda x, y: poses[1:])
    gaits = lambda x, y, o, r=None, **kw: plan_gaits(x, y, o, {}, False, r, **kw)  # noqa: E731
    return a, b, poses[1], ({}, False, gaits, _straight_gait)


def test_the_gaits_on_the_palm_are_verified_inside_the_whole_plan_back_to_the_final_grasp(monkeypatch):
    """Verifying, the gaits on the palm are replayed inside the whole plan, the final grasp's leg
    back from the palm included (a stand-in simulator that passes everything): the plan replayed
    is the one returned, and it ends at the final grasp (pose and joints), not on the palm."""
    import planner.sim.verify as verify
    from planner import pose_search
    from planner.plan_data import pose_matrix

    replayed = []

    def stand_in(plan, hand, directions, workers=None, meanwhile=None, **_):
        if meanwhile is not None:
            meanwhile()
        replayed.append(plan)
        return verify.Verification(True, tuple((n, True, "PASS", None, False, 0.1, 0.1) for n, _ in directions), 0.0)

    monkeypatch.setattr(verify, "verify_plan", stand_in)
    a, b, (at_b, _), args = _through_the_palm(monkeypatch)
    plan, _, name = pose_search.plan_with_reposing(a, b, PlanOptions.for_execution(motion=False), *args)
    assert name.endswith(at_b) and plan.summary["verification"]["passed"]
    last = [p for p in replayed if p.steps == plan.steps]
    assert last  # the plan returned was replayed as it is
    end = plan.states[-1]
    assert np.allclose(pose_matrix(end.object_pose), b.obj.T_palm_obj, atol=1e-9)
    assert np.allclose(np.asarray(end.q), [b.q[list(b.hand.joint_names).index(j)] for j in plan.joints], atol=1e-9)
    assert sum(s.action == "repose" for s in plan.steps) == 2


def test_an_intermediate_grasp_carried_onto_the_palm_lets_the_thumb_move_there(monkeypatch):
    """exp10 v2's Allegro sphere pair (small offset): in neither grasp can the thumb lift at its
    own pose (index and middle alone are no force closure). Through the palm: an intermediate
    grasp is carried from the initial grasp's pose to where the final grasp rests on the palm
    (`planner.pose_search.through_poses`), the gaits there move the thumb while the palm holds,
    and the final grasp's leg to the palm, reversed, ends the plan at the final grasp. Checked
    independently: the object poses of the plan's states (the initial, the palm's, the final),
    the thumb lifted only where the palm holds, and the physics check `verify` runs."""
    from planner import pose_search
    from planner.audit import audit_plan
    from planner.plan_data import OBJECT, pose_matrix
    from planner.repose import settle_pose
    from planner.synth_sample import PALM_TOUCH_GAP_M

    a, b, (at_b, _), args = _through_the_palm(monkeypatch)
    plan, _, name = pose_search.plan_with_reposing(a, b, replace(OPTS, motion=False), *args)
    assert name.startswith("through an intermediate grasp") and name.endswith(at_b)
    assert audit_plan(plan, a.hand).ok
    P = settle_pose(b, PALM_TOUCH_GAP_M)[0]

    def pose(i):
        st = plan.states[i]
        return np.asarray(a.obj.T_palm_obj if st.object_pose is None else pose_matrix(st.object_pose), float)

    moves = [k for k, s in enumerate(plan.steps) if s.action == "repose"]
    assert len(moves) == 2 and all(plan.steps[k].finger == OBJECT for k in moves)
    first, last = moves
    assert np.allclose(pose(plan.steps[first].from_state), a.obj.T_palm_obj, atol=1e-9)
    assert np.allclose(pose(plan.steps[first].to_state), P, atol=1e-9)
    assert np.allclose(pose(plan.steps[last].from_state), P, atol=1e-9)
    assert np.allclose(pose(len(plan.states) - 1), b.obj.T_palm_obj, atol=1e-9)
    thumb = [s for s in plan.steps if s.finger == "thumb" and s.action == "lift"]
    assert thumb  # the thumb moves ...
    for s in thumb:  # ... only where the palm holds
        assert plan.steps.index(s) > first and plan.steps.index(s) < last
        assert plan.states[s.to_state].palm_holds
    end = plan.states[-1]
    assert np.allclose(np.asarray(end.q), [b.q[list(b.hand.joint_names).index(j)] for j in plan.joints], atol=1e-9)


def test_the_gaits_to_an_intermediate_grasp_do_not_replay_it_alone_when_every_sequence_failed(pair, through,
                                                                                               monkeypatch):
    """When every sequence of the gaits from the initial grasp to an intermediate grasp failed in
    the simulator, the gait search replayed the intermediate grasp alone (as a final grasp:
    `planner.regrasp.hold_alone`) for its refusal's words, which the reposing search cuts off (it
    keeps a refusal's first clause): a one-state replay in every direction for nothing, per
    intermediate grasp. Only sequences are replayed now (a stand-in simulator failing each at its
    first step)."""
    import planner.intermediate as inter
    import planner.sim.verify as verify
    from planner import pose_search, regrasp
    from planner.errors import NoSequenceError

    a, b = pair
    monkeypatch.setattr(inter, "intermediate_grasps", lambda x, y, o: (through[0][:1], "one intermediate grasp"))
    monkeypatch.setattr(pose_search, "candidate_poses", lambda x, y: [])
    monkeypatch.setattr(pose_search, "through_poses", lambda x, y: [("the final grasp's pose", None)])
    states = []

    def fails(plan, hand, directions, workers=None, meanwhile=None, **_):
        if meanwhile is not None:
            meanwhile()
        states.append(len(plan.states))
        step = 0 if plan.steps else -1
        return verify.Verification(False, ((directions[0][0], False, "FAIL: made up", step, False, 9.0, 9.0),), 0.0)

    monkeypatch.setattr(verify, "verify_plan", fails)
    opts = PlanOptions.for_execution(motion=False, verify_attempts=2)
    with pytest.raises(NoSequenceError) as err:
        pose_search.plan_with_reposing(a, b, opts, {}, False,
                                       lambda x, y, o, r=None, **kw: regrasp.plan_gaits(x, y, o, {}, False, r, **kw),
                                       regrasp._straight_gait)
    assert "through an intermediate grasp" in str(err.value) and "at the initial grasp's pose" in str(err.value)
    assert states and all(n > 1 for n in states), states  # (1: the intermediate grasp replayed alone)
