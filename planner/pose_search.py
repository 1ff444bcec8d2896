"""Plans that move the object: finger gaits at a pose, joined by reposing moves.

The search's states are (object pose, contact assignment). Candidate poses ``P``, in order
(`candidate_poses`): the final grasp's pose and the initial grasp's (when they differ), the
object carried a lifted finger's clearance and a lift's retreat away from a finger that
cannot back off its contact, then the poses that rest the object on the palm from either
grasp (`planner.repose.settle_pose`: a thumb that cannot lift because nothing opposes it can
lift once the palm does). For each, the initial grasp is taken to ``P`` (a `Leg`: fingers
that cannot follow lifted or released first, then the reposing move), the final grasp
likewise (its leg reversed ends the plan), and the gait search (`planner.regrasp.plan_gaits`)
joins the two at ``P``. The first candidate that gives a plan is returned (poses tried in that
order: the fewest and shortest object motions first); each is work-bounded, so the answer
does not depend on the machine's load. When the grasps' poses differ and no candidate pose
joins them, the plan may go through an intermediate grasp whose contacts every holding finger
keeps along the object's path (`planner.intermediate`): gaits at the initial grasp's pose to
it, its reposing move to the final grasp's pose, gaits there to the final grasp
(`compose_through`); those are tried after the poses, on what is left of the budget, the gaits
at the final grasp's pose searched first without verification (an intermediate grasp they
cannot take to the final one is dropped before its gaits at the initial grasp's pose are
replayed). Each plan must pass the physics check `replay` and `verify` run
(`planner.audit.audit_plan`); with verification the whole plan (gaits and
reposing moves) is then replayed in the planned directions before it is returned.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import TYPE_CHECKING

import numpy as np

from planner.errors import MotionError, NoSequenceError, PlannerError
from planner.model import PALM
from planner.options import PlanOptions, gravity_directions_of, verifies
from planner.plan_data import OBJECT, Plan, PlanState, PlanStep, order_entry, pose_vector
from planner.realization import PENETRATION_TOL_M
from planner.repose import (FOLLOW_TOL_M, FollowError, Reposing, _holds, at_pose, pose_distance, repose, settle_pose,
                            state_reason)

if TYPE_CHECKING:
    from planner.regrasp import PlanResult

log = logging.getLogger("planner")

#: A pose at most this close to another candidate (mm, deg) is the same candidate.
SAME_POSE = (0.05, 0.05)
#: A reposing move in the summary's order.
REPOSE = order_entry(OBJECT, "repose")


def grasp_state(grasp, options: PlanOptions, label: str) -> PlanState:
    """The plan state of a realized grasp under the plan's options (the search's own node
    data: patches under the contact model, closure, grip forces, hold factors, removable
    fingers); its fingers labelled ``label`` (or "lifted")."""
    from planner.graph import annotate_removable, seed_graph
    from planner.slots import build_problem

    problem = build_problem(grasp, grasp, replace(options, intermediate=0))
    G = seed_graph(problem)
    v = problem.start
    annotate_removable(G, [v])
    d = G.nodes[v]
    return PlanState(
        fingers={f: label if f in grasp.patches else "lifted" for f in problem.fingers},
        patches=d["patches"], is_force_closure=d["closure"].is_force_closure, metric=d["metric"],
        removable=tuple(sorted(d["removable"])), q=tuple(float(x) for x in grasp.q),
        grip_force_n=d.get("grip_force"), grip_force_by_gravity_n=d.get("grip_forces"),
        hold_factor_by_gravity=G.graph["evaluator"].hold_factors(v))


def identical(Ta, Tb) -> bool:
    """Two poses equal to rounding (1e-9): no object motion between them."""
    return bool(np.allclose(np.asarray(Ta, float), np.asarray(Tb, float), rtol=0.0, atol=1e-9))


def _same(Ta, Tb) -> bool:
    mm, deg = pose_distance(Ta, Tb)
    return mm <= SAME_POSE[0] and deg <= SAME_POSE[1]


def candidate_poses(initial, final) -> list[tuple[str, np.ndarray]]:
    """(name, pose) of the poses the gaits may happen at, in the order they are tried."""
    from planner.synth_sample import PALM_TOUCH_GAP_M  # where ``synth --palm`` rests an object on the palm

    Ta, Tb = np.asarray(initial.obj.T_palm_obj, float), np.asarray(final.obj.T_palm_obj, float)
    out = []
    if not identical(Ta, Tb):
        out += [("the final grasp's pose", Tb), ("the initial grasp's pose", Ta)]
    # a finger that cannot back off its contact (held against the object by its own joint
    # limits) is released by carrying the object away from it, a lift's distance along its
    # contact normal (`leg`); in the final grasp, the object is carried onto it
    # (the clearance a lifted finger keeps from the object first, then a lift's retreat)
    from planner.finger_scene import DEFAULT_CLEARANCE_M
    from planner.realization import wedged_fingers
    from planner.retreat import DEFAULT_LIFT_M

    for which, g in (("initial", initial), ("final", final)):
        T = np.asarray(g.obj.T_palm_obj, float)
        for f in wedged_fingers(g):
            n = _away_from(g, f, DEFAULT_CLEARANCE_M)
            if n is None:
                continue
            for d in (DEFAULT_CLEARANCE_M, DEFAULT_LIFT_M):
                P = T.copy()
                P[:3, 3] += d * n / np.linalg.norm(n)
                if not any(_same(P, X) for _, X in out):
                    out.append((f"{d * 1e3:g} mm away from {f} in the {which} grasp (it cannot back off)", P))
    if "free" not in (initial.spec.palm, final.spec.palm):
        for which, g in (("initial", initial), ("final", final)):
            s = settle_pose(g, PALM_TOUCH_GAP_M)
            if s is not None and not any(_same(s[0], T) for _, T in out):
                out.append((f"resting on the palm ({s[1] * 1e3:.1f} mm from the {which} grasp's pose)", s[0]))
    return out


def through_poses(initial, final) -> list[tuple[str, np.ndarray | None]]:
    """(name, pose) of the poses an intermediate grasp (`planner.intermediate`) is carried to
    from the initial grasp's pose, in the order they are tried: the final grasp's own (pose
    None) when the poses differ; then resting on the palm from the final grasp (the final
    grasp's leg there, reversed, ends the plan): the palm lets a thumb that nothing else
    opposes lift, so the gaits there can move it."""
    from planner.synth_sample import PALM_TOUCH_GAP_M

    out: list[tuple[str, np.ndarray | None]] = []
    if not identical(initial.obj.T_palm_obj, final.obj.T_palm_obj):
        out.append(("the final grasp's pose", None))
    if "free" not in (initial.spec.palm, final.spec.palm):
        s = settle_pose(final, PALM_TOUCH_GAP_M)
        if s is not None:
            out.append((f"resting on the palm ({s[1] * 1e3:.1f} mm from the final grasp's pose)", s[0]))
    return out


def palm_frees(grasp, on_palm, options: PlanOptions) -> bool:
    """Whether ``on_palm`` (``grasp`` taken to rest on the palm) lets a finger lift that cannot
    lift in ``grasp``: the others and the palm hold the object without it (the search's state
    test) where, at ``grasp``'s own pose, the others alone do not. `plan_with_reposing` asks
    it of the final grasp before it computes intermediate grasps to carry onto the palm: a
    bound on the work, not a proof (the gaits on the palm start from the intermediate grasp,
    whose fingers are not asked: a pair where only those are freed by the palm is not tried)."""
    for f in grasp.patches:
        if f == PALM or f not in on_palm.patches:
            continue
        if state_reason(_without(grasp, [f]), options) is not None \
                and state_reason(_without(on_palm, [f]), options) is None:
            return True
    return False


def _away_from(g, finger: str, d: float):
    """The direction (palm frame, unit) to carry the object ``d`` along that takes it farthest
    from ``finger`` (its links' distance to the object, measured with the object moved): the
    finger's mean contact normal or one of the palm axes; None when none gains half of ``d``."""
    T = np.asarray(g.obj.T_palm_obj, float)
    state = g.hand.state(g.q)
    n = np.mean([T[:3, :3] @ c.normal for c in g.contacts if c.finger == finger], axis=0)
    cands = ([n / np.linalg.norm(n)] if np.linalg.norm(n) > 1e-9 else []) + list(np.eye(3)) + list(-np.eye(3))
    best, gain = None, 0.5 * d
    d0 = state.finger_object_distance(g.obj, finger)
    for u in cands:
        P = T.copy()
        P[:3, 3] += d * u
        dd = state.finger_object_distance(g.obj.with_pose(P), finger) - d0
        if dd > gain + 1e-12:
            best, gain = u, dd
    return best


@dataclass
class Leg:
    """A grasp taken to a candidate pose: fingers that cannot follow the object lifted first
    (at the grasp's own pose, in order), then the reposing move of the others.

    Attributes:
        grasp: the grasp the leg starts from (its own pose).
        lifts: (finger, paths, grasp after) per lifted finger: ``paths`` the gait paths
            ("lift", and "move" when the motion planner gives one), the grasp measured without it.
        move: the reposing move, None when the grasp is at the pose already.
        end: the grasp at the candidate pose (a released finger at the open posture).
        releases: (finger, path) per finger the move carried the object away from (its lift
            could not be planned: typically a finger that cannot back off its contact,
            `planner.retreat.retreat_blocked`): its joints kept during the move, then ``path``
            (joint waypoints) to the open posture at the candidate pose.
    """

    grasp: object
    lifts: list
    move: Reposing | None
    end: object
    releases: list = field(default_factory=list)


def leg(grasp, P, options: PlanOptions, gait_fn) -> Leg:
    """Take ``grasp`` to the pose ``P``: repose it; a finger that cannot follow
    (`planner.repose.FollowError`) is lifted first when the others hold the object without
    it (the search's state test), and the move is tried again, until at most two fingers
    are left. A finger that cannot be lifted (it cannot back off its contact: held against
    the object by its own joint limits) is released instead: it keeps its joints while the
    others carry the object away from it, then opens at ``P``.

    Raises:
        MotionError: the move fails otherwise (why, at which waypoint).
    """
    T = np.asarray(grasp.obj.T_palm_obj, float)
    g, lifts, still = grasp, [], []
    if identical(P, T):
        return Leg(grasp, [], None, grasp)
    while True:
        try:
            r = repose(g, P, options, still=tuple(still))
            break
        except FollowError as err:
            f = err.finger
            touching = [x for x in g.patches if x != PALM and x not in still]
            if len(touching) <= 2 or f not in touching:
                raise
            without = replace(g, patches=MappingProxyType({k: v for k, v in g.patches.items() if k != f}))
            why = state_reason(without, options)
            if why == "too many fingers lifted":
                why = "--max-lifted allows no more fingers off the object"
            if why is not None:
                raise MotionError(f"{err}; and without {f} the grasp is no valid state ({why})") from None
            try:
                paths = gait_fn(g.hand, g.obj, g.q, None, f)
            except MotionError:
                still.append(f)  # it cannot back off: the others carry the object away from it
                continue
            idx = list(g.hand.fingers[f].q_index)
            q = np.array(g.q, dtype=float)
            q[idx] = np.asarray(paths["move" if "move" in paths else "lift"], float)[-1]
            g2 = at_pose(g, T, q)
            if f in g2.patches or state_reason(g2, options) is not None:
                raise MotionError(f"{err}; and without {f} the grasp is no valid state") from None
            lifts.append((f, paths, g2))
            g = g2
    end, releases = r.end, []
    for f in still:
        path = _open_path(end, f, options)
        if path is None:
            raise MotionError(f"{f} was released by moving the object away, and cannot open from there without "
                              f"touching the object or another finger")
        q = np.array(end.q, dtype=float)
        q[list(end.hand.fingers[f].q_index)] = path[-1]
        end = at_pose(end, P, q)
        releases.append((f, path))
    if any(f in end.patches for f in still) or state_reason(end, options) is not None:
        raise MotionError(f"with {', '.join(still)} released the grasp at the candidate pose is no valid state")
    return Leg(grasp, lifts, r, end, releases)


def _open_path(g, finger: str, options: PlanOptions, step_rad: float = 0.01):
    """A joint path of ``finger`` from its joints in ``g`` to the open posture, free of the
    object and the other links: the straight line when it is, else (with finger paths,
    ``options.motion``) the motion planner's, keeping from the object the clearance the finger
    has at its start (at most a lift's, `planner.finger_scene.DEFAULT_CLEARANCE_M`); None when
    there is none."""
    from planner.contacts import collisions

    hand = g.hand
    idx = list(hand.fingers[finger].q_index)
    a = np.asarray(g.q, float)[idx]
    b = np.asarray(hand.q_open, float)[idx]
    n = max(1, int(math.ceil(float(np.max(np.abs(b - a))) / step_rad)))
    path = [a + (b - a) * k / n for k in range(n + 1)]
    q = np.array(g.q, dtype=float)
    for wp in path[1:]:
        q[idx] = wp
        if collisions(hand, q, g.obj, fingers=[finger]):
            break
    else:
        return np.array(path)
    if not options.motion:
        return None
    from planner.finger_scene import DEFAULT_CLEARANCE_M
    from planner.motion import plan_finger_move  # OMPL: only when finger paths are planned

    gap = hand.state(g.q).finger_object_distance(g.obj, finger)
    if not gap > 0.0:
        return None
    goal = np.array(g.q, dtype=float)
    goal[idx] = b
    try:
        return np.asarray(plan_finger_move(hand, g.obj, g.q, goal, finger, planner=options.motion_planner,
                                           max_checks=options.motion_checks, seed=options.seed,
                                           clearance_m=max(0.0, min(DEFAULT_CLEARANCE_M, 0.9 * gap))), float)
    except MotionError:
        return None


class _Builder:
    """Plan states and steps in order; a state's object pose is written when it differs
    from the plan's (the initial grasp's)."""

    def __init__(self, options: PlanOptions, hand, T0):
        self.options, self.hand, self.T0 = options, hand, np.asarray(T0, float)
        self.joints = tuple(hand.joint_names)
        self.states: list[PlanState] = []
        self.steps: list[PlanStep] = []

    def pose(self, T):
        return None if identical(T, self.T0) else pose_vector(T)

    def state(self, st: PlanState, T) -> None:
        self.states.append(replace(st, object_pose=self.pose(T)))

    def grasp(self, g, label: str) -> None:
        self.state(grasp_state(g, self.options, label), g.obj.T_palm_obj)

    def step(self, finger: str, action: str, path, object_path=None, fingers=None) -> None:
        frm = len(self.states) - 1
        names = self.hand.fingers[finger].joints if finger != OBJECT else \
            tuple(j for f in fingers for j in self.hand.fingers[f].joints)
        self.steps.append(PlanStep(finger, action, frm, frm + 1, tuple(names),
                                   tuple(tuple(float(v) for v in wp) for wp in path),
                                   None if object_path is None else tuple(pose_vector(T) for T in object_path)))

    def reposing(self, r: Reposing) -> None:
        idx = [k for f in r.fingers for k in self.hand.fingers[f].q_index]
        self.step(OBJECT, "repose", [q[idx] for q in r.q_path], r.poses, r.fingers)


def compose(initial, final, options: PlanOptions, first: Leg, gait: Plan | None, last: Leg, P) -> Plan:
    """One plan: ``first`` (the initial grasp's fingers lifted, reposed to ``P``), the gait
    plan at ``P``, ``last`` reversed (reposed back to the final grasp's pose, its fingers
    landed)."""
    return compose_at(initial, final, options, first, gait, last, P)[0]


def compose_at(initial, final, options: PlanOptions, first: Leg, gait: Plan | None, last: Leg, P) -> tuple[Plan, int]:
    """`compose`, and the index of the gait plan's first step in it."""
    hand = initial.hand
    b = _Builder(options, hand, initial.obj.T_palm_obj)
    b.grasp(initial, "initial")
    for f, paths, g in first.lifts:
        b.step(f, "lift", paths["lift"])
        b.grasp(_with_q(g, paths["lift"][-1], f) if "move" in paths else g, "initial")
        if "move" in paths:
            b.step(f, "move", paths["move"])
            b.grasp(g, "initial")
    if first.move is not None:
        b.reposing(first.move)
        g = first.move.end
        gone = [f for f, _ in first.releases]
        for f, path in first.releases:  # carried away from: it opens at P (holding nothing)
            b.grasp(g, "initial")
            b.step(f, "move", path)
            g = _without(_with_q(g, path[-1], f), gone)
        if gait is not None:
            b.state(gait.states[0], P)
        else:
            b.grasp(first.end, "initial")
    elif gait is not None:
        b.states[-1] = replace(gait.states[0], object_pose=b.pose(P))
    at = len(b.steps)
    if gait is not None:
        k0 = len(b.states) - 1
        for s in gait.states[1:]:
            b.state(s, P)
        b.steps += [replace(s, from_state=s.from_state + k0, to_state=s.to_state + k0) for s in gait.steps]
    _leg_back(b, last, final)
    moves = [x.move for x in (first, last) if x.move is not None]
    order = [order_entry(f, "lift") for f, _, _ in first.lifts] + ([REPOSE] if first.move is not None else []) \
        + (list(gait.summary.get("order", [])) if gait else []) + _leg_back_order(last)
    return _finish(initial, options, b, moves, gait, order, len(first.lifts) + len(last.lifts), P), at


def _leg_back(b: "_Builder", last: Leg, final) -> None:
    """The steps and states of the final grasp's leg ``last`` reversed, after ``b``'s last
    state (``last.end``, at the candidate pose): released fingers back where they hold, the
    reposing move back to the final grasp's pose, the lifted fingers landed."""
    if last.move is not None:
        back = last.move.reversed()
        lifted_final = last.lifts[-1][2] if last.lifts else final
        g = last.end
        gone = [f for f, _ in last.releases]
        for f, path in reversed(last.releases):  # back where it holds, before the object is carried onto it
            b.step(f, "move", np.asarray(path, float)[::-1])
            g = _without(_with_q(g, path[0], f), gone)
            b.grasp(g, "final")
        b.reposing(back)
        b.grasp(lifted_final, "final")
    for i in range(len(last.lifts) - 1, -1, -1):
        f, paths, _ = last.lifts[i]
        before = last.lifts[i - 1][2] if i > 0 else final
        if "move" in paths:
            b.step(f, "move", np.asarray(paths["move"], float)[::-1])
            b.grasp(_with_q(last.lifts[i][2], paths["lift"][-1], f), "final")
        b.step(f, "land", np.asarray(paths["lift"], float)[::-1])
        b.grasp(before, "final")


def _leg_back_order(last: Leg) -> list[str]:
    """The summary's order of `_leg_back`'s steps."""
    return ([REPOSE] if last.move is not None else []) + [order_entry(f, "land", "final") for f, _, _ in reversed(last.lifts)]


def compose_through(initial, final, options: PlanOptions, gait_a: Plan | None, move: Reposing,
                    gait_b: Plan | None, back: Leg | None = None) -> Plan:
    """One plan through an intermediate grasp (`planner.intermediate`): ``gait_a`` at the
    initial grasp's pose from it to the intermediate grasp (None: the initial grasp is it),
    the reposing ``move`` of the intermediate grasp to the final grasp's pose, ``gait_b`` there
    to the final grasp (None: the move ends at it). With ``back`` (the final grasp's `Leg` to
    another pose, e.g. resting on the palm): the move goes to that pose, ``gait_b`` there to
    ``back.end``, then ``back`` reversed to the final grasp."""
    return compose_through_at(initial, final, options, gait_a, move, gait_b, back)[0]


def compose_through_at(initial, final, options: PlanOptions, gait_a: Plan | None, move: Reposing,
                       gait_b: Plan | None, back: Leg | None = None) -> tuple[Plan, int]:
    """`compose_through`, and the index of ``gait_b``'s first step in it."""
    target = final if back is None else back.end
    Ta, Tb = np.asarray(initial.obj.T_palm_obj, float), np.asarray(target.obj.T_palm_obj, float)
    b = _Builder(options, initial.hand, Ta)
    if gait_a is None:
        b.grasp(initial, "initial")
    else:
        for st in gait_a.states:
            b.state(st, Ta)
        b.steps += list(gait_a.steps)
    b.reposing(move)
    at = len(b.steps)
    if gait_b is None:
        b.grasp(target, "final")
    else:
        k0 = len(b.states)  # (the gaits at B start at the move's last state: their steps follow it)
        for st in gait_b.states:
            b.state(st, Tb)
        b.steps += [replace(s, from_state=s.from_state + k0, to_state=s.to_state + k0) for s in gait_b.steps]
    order = (list(gait_a.summary.get("order", [])) if gait_a else []) + [REPOSE] \
        + (list(gait_b.summary.get("order", [])) if gait_b else [])
    moves, extra = [move], 0
    if back is not None:
        _leg_back(b, back, final)
        order += _leg_back_order(back)
        moves += [back.move] if back.move is not None else []
        extra = len(back.lifts)
    base = gait_a or gait_b
    extra += int(gait_b.summary.get("gait_steps", 0)) if gait_a is not None and gait_b is not None else 0
    return _finish(initial, options, b, moves, base, order, extra, Tb), at


def _finish(initial, options: PlanOptions, b: _Builder, moves, base: Plan | None, order, extra_steps: int, P) -> Plan:
    """The plan of the states and steps ``b`` built: ``base`` (a gait plan of it, or None) its
    records, the summary's order, reposing moves, gait steps (``base``'s and ``extra_steps``)
    and metrics of the whole."""
    hand = initial.hand
    summary = dict(base.summary) if base else {
        "strategy": options.strategy, "gait_steps": 0, "graph_edges_in_sequence": 0, "graph_nodes": 0,
        "graph_edges": 0, "blocked_states": 0, "rank": options.rank, "search": {}}
    summary.pop("verification", None)
    summary.update(order=order, reposing={
        "moves": len(moves),
        "object_path_mm": round(sum(r.distance_mm for r in moves), 3),
        "object_path_deg": round(sum(r.angle_deg for r in moves), 3),
        "pose": list(pose_vector(P))})
    summary["gait_steps"] = int(summary.get("gait_steps", 0)) + extra_steps
    metrics = [s.metric for s in b.states]
    summary["bottleneck_metric"] = float(min(metrics))
    summary["mean_metric"] = float(np.mean(metrics))
    grips = [s.grip_force_n for s in b.states if s.grip_force_n is not None]
    summary["bottleneck_grip_force_n"] = max(grips) if grips else None
    if base is not None:
        # (the gait search had a share of the reposing candidates' --verify-attempts: the option given is recorded)
        return replace(base, object=initial.spec.object.to_data(), summary=summary, states=tuple(b.states),
                       steps=tuple(b.steps),
                       parameters={**(base.parameters or {}), "verify_attempts": options.verify_attempts})
    from planner.plan_data import hand_files_record

    spec = initial.spec
    from planner.closure import GRIP_CONE_SIDES

    parameters = {k: v for k, v in vars(options).items() if k not in ("workers", "engine")}
    directions = gravity_directions_of(options, hand)  # as the gait plans record them (regrasp._make_plan)
    parameters["gravity_directions"] = [{"name": n, "gravity": list(g)} for n, g in directions] or None
    parameters["grip_cone_sides"] = GRIP_CONE_SIDES if directions else None
    return Plan(hand={"name": hand.name, "spec": spec.hand_ref, "files": hand_files_record(hand)},
                object=spec.object.to_data(),
                friction={"mu": spec.friction.mu, "gamma": spec.friction.gamma, "edges": spec.friction.edges},
                inputs={}, parameters=parameters, summary=summary, joints=b.joints, states=tuple(b.states),
                steps=tuple(b.steps))


def _same_grasp(a, b) -> bool:
    """The same fingers touching, the same joints: no gaits between them."""
    return set(a.patches) == set(b.patches) and np.array_equal(a.q, b.q)


def _without(g, fingers):
    """``g`` with the patches of ``fingers`` left out (fingers that hold nothing there: released
    ones, which may still graze the object)."""
    return replace(g, patches=MappingProxyType({k: v for k, v in g.patches.items() if k not in fingers}))


def _with_q(g, q_finger, finger):
    """``g`` re-measured with ``finger`` at ``q_finger`` (still off the object)."""
    q = np.array(g.q, dtype=float)
    q[list(g.hand.fingers[finger].q_index)] = q_finger
    return at_pose(g, g.obj.T_palm_obj, q)


#: A finger whose contact is the same in both grasps at the candidate pose (its outermost
#: contact points this close, m: twice the follower's tolerance, as the audit allows a contact
#: to stay on its object point) keeps one posture there:
SNAP_M = 2 * FOLLOW_TOL_M
#: ... when its joints differ by at most this (rad): the two legs' IK ends near each other,
#: and one waypoint joins them.
SNAP_RAD = 0.05
#: Farther apart (another IK solution touching the same point: a redundant finger's
#: self-motion, its pad rolling on the point), the postures are joined by a re-posturing
#: path with the object still: waypoints at most `SNAP_RAD` apart, the outermost contact
#: kept on its object point by the reposing follower at every one (its point on the link
#: moving from the one posture's to the other's), each measured as a plan state. At most
#: this far (rad, the largest joint change): a longer self-motion is no snap.
REPOSTURE_MAX_RAD = 0.5


def _snap(first: Leg, back: Leg, options: PlanOptions) -> tuple[Leg, Leg]:
    """The two legs' grasps at the candidate pose with one posture per shared contact: a
    finger touching the same object point in both (`SNAP_M`, `SNAP_RAD`) takes the other
    leg's joints at the end of the leg that moves the object (a last waypoint with the
    object still: the contact kept, the joints re-postured; `_reposture`, or when it fails
    the fingers within `SNAP_RAD` alone in one waypoint), so the gait search sees one
    contact, not two it would have to lift between. Legs that do not move, or a result that
    is no valid state, are left as they are."""
    a, b = first.end, back.end
    for leg_, other in ((back, a), (first, b)):
        if leg_.move is None or leg_.releases:  # (a released finger opened after the move: no last waypoint)
            continue
        g = leg_.end
        q = np.array(g.q, dtype=float)
        changed = []
        holds_g, holds_o = _holds(g), _holds(other)  # each finger's outermost contact first
        for f in g.hand.fingers:
            if f not in g.patches or f not in other.patches or f not in leg_.move.fingers:  # (the move's joints only)
                continue
            pa = holds_g[f][0][2] if f in holds_g else None  # its outermost contact point (object frame)
            pb = holds_o[f][0][2] if f in holds_o else None
            qa, qb = np.asarray(g.finger_q[f]), np.asarray(other.finger_q[f])
            if pa is None or pb is None or np.linalg.norm(pa - pb) > SNAP_M or np.max(np.abs(qa - qb)) > REPOSTURE_MAX_RAD:
                continue
            if np.array_equal(qa, qb):
                continue  # (postures within the slot tolerance are re-postured too: a plan joins states exactly)
            q[list(g.hand.fingers[f].q_index)] = qb
            changed.append(f)
        if not changed:
            continue
        path = _reposture(g, other, changed, options)
        if path is None:  # a farther finger cannot re-posture: the ones within SNAP_RAD still join in one waypoint
            near = [f for f in changed
                    if np.max(np.abs(np.asarray(g.finger_q[f]) - np.asarray(other.finger_q[f]))) <= SNAP_RAD]
            if not near:
                continue
            q = np.array(g.q, dtype=float)
            for f in near:
                q[list(g.hand.fingers[f].q_index)] = other.finger_q[f]
            path = q[None, :]
        g2 = at_pose(g, g.obj.T_palm_obj, q)
        if set(g2.patches) != set(g.patches) or state_reason(g2, options) is not None:
            continue
        r = leg_.move
        move = Reposing(np.vstack([r.q_path, path]), np.concatenate([r.poses] + [r.poses[-1:]] * len(path)),
                        r.fingers, r.start, g2)
        snapped = replace(leg_, move=move, end=g2)
        if leg_ is back:
            back = snapped
        else:
            first = snapped
        break  # one side re-postured is enough
    return first, back


def _reposture(g, other, fingers, options):
    """Joint waypoints (k, nq) taking ``fingers`` of ``g`` to their postures in ``other`` (the
    same object pose, each touching the same point with the same outermost link) with the
    object still, the last one exactly ``other``'s postures; None when a finger cannot keep
    its contact on the way or a waypoint is no valid state (`SNAP_RAD`, `REPOSTURE_MAX_RAD`).
    Each waypoint moves the fingers' joints along the straight line between the postures and
    the reposing follower (`planner.repose._follow`) puts the outermost contact back on its
    object point, its point on the link interpolated between the two postures' (the pad rolls)."""
    from planner.repose import _follow

    hand = g.hand
    T = np.asarray(g.obj.T_palm_obj, float)
    lo, hi = np.asarray(hand.lower, float), np.asarray(hand.upper, float)
    holds_a, holds_b = _holds(g), _holds(other)  # each finger's outermost contact first
    ends = {}
    for f in fingers:
        la, pla, poa, R_rel, n_obj = holds_a[f][0]
        lb, plb, pob, _, _ = holds_b[f][0]
        if la != lb:
            return None
        ends[f] = (la, pla, plb, poa, pob, np.asarray(g.finger_q[f], float), np.asarray(other.finger_q[f], float),
                   R_rel, n_obj)
    dq = max(float(np.max(np.abs(e[6] - e[5]))) for e in ends.values())
    n = max(1, int(math.ceil(dq / SNAP_RAD)))
    q = np.array(g.q, dtype=float)
    out = []
    for k in range(1, n + 1):
        s = k / n
        for f, (link, pla, plb, poa, pob, qa, qb, R_rel, n_obj) in ends.items():
            idx = list(hand.fingers[f].q_index)
            q[idx] = qa + s * (qb - qa)
            if k < n:  # the contact kept: the link point rolling from the one posture's to the other's
                hold = [(link, (1 - s) * pla + s * plb, (1 - s) * poa + s * pob, R_rel, n_obj)]
                q, worst, _ = _follow(hand, f, q, hold, T, lo, hi, twist=False)
                if worst > 2 * FOLLOW_TOL_M:
                    return None
        if k < n:
            w = at_pose(g, T, q)
            if not set(ends) <= set(w.patches) or any(d > PENETRATION_TOL_M for _, _, d in w.collisions) \
                    or state_reason(w, options) is not None:  # (as `planner.repose.repose` judges a waypoint)
                return None
        out.append(q.copy())
    return np.array(out)


def first_clause(err) -> str:
    """The first clause of a refusal (up to its first "; " outside parentheses): what failed,
    without the advice."""
    text, depth = str(err), 0
    for i, ch in enumerate(text):
        depth += (ch == "(") - (ch == ")")
        if depth == 0 and text.startswith("; ", i):
            return text[:i]
    return text


def plan_with_reposing(initial, final, options: PlanOptions, inputs, verbose: bool, gaits, gait_fn,
                       known: str | None = None) -> tuple[Plan, float | None, str]:
    """The first candidate pose (`candidate_poses`) joined by reposing moves and gaits.

    ``gaits(a, b, options, on_replay, budget=, whole=)`` is the gait planner
    (`planner.regrasp.plan_gaits`), returning a `planner.regrasp.PlanResult` and calling
    ``on_replay()`` once per sequence its verification replays; ``gait_fn(hand, obj, q_a, q_b,
    finger)`` the finger paths of
    one gait (lifting a finger that cannot follow a reposing move); ``known``: the first clause
    of the gait refusal at the grasps' own pose (a candidate failing the same way says so).
    The candidates share one ``options.verify_attempts`` (sequences replayed, the gaits' and
    the whole plans'): once it is spent the candidates left are not tried, so a refusal costs
    about that many replays beyond the gaits' at the grasps' own pose; and one
    ``options.max_rounds`` (`planner.regrasp.RoundBudget`: rounds of intermediate contacts
    their gait searches add). Where the plan around the gaits is known when they are searched
    (a candidate pose; the intermediate grasp's gaits at the final grasp's pose), each sequence
    is verified inside it (`planner.regrasp.plan_gaits`' ``whole``), once. Returns (plan,
    seconds of verification replays or None, a sentence on what was tried); raises
    NoSequenceError with every candidate's reason.
    """
    hand = initial.hand
    Ta, Tb = np.asarray(initial.obj.T_palm_obj, float), np.asarray(final.obj.T_palm_obj, float)
    tried = []
    directions = gravity_directions_of(options, hand)
    verifying = verifies(options.verify, options.strategy, directions, reposes=True)
    verify_s = 0.0
    replays = 0  # sequences the verification replayed, every candidate's (gaits and whole plans)
    stopped = False  # the budget ran out before every candidate was tried
    from planner.regrasp import RoundBudget

    rounds = RoundBudget(options.max_rounds)  # the candidates' gait searches share one --max-rounds

    def replayed() -> None:
        nonlocal replays
        replays += 1

    said = []  # the budget's words were said once (the next candidates short)

    def starved(clause: str, stopped: bool) -> str:
        """A gait refusal's clause, saying so when the spent budget stopped its search (``stopped``:
        it would have made a round of intermediate contacts and none was left)."""
        if not stopped:
            return clause
        if said:
            return clause + " (no rounds left)"
        said.append(True)
        return clause + (" (no rounds of intermediate contacts were left: the searches before it spent the "
                         f"--max-rounds {options.max_rounds} they share)")

    def checked(plan: Plan, where: str, replayed_in: PlanResult | None = None) -> Plan | None:
        """``plan`` with the inputs, once it passes the physics check `replay` and `verify` run
        (`planner.audit.audit_plan`) and, when verifying, the simulator; else None (why in ``tried``).
        ``replayed_in``: the gait search that verified ``plan`` whole (`planner.regrasp.plan_gaits`'
        ``whole``): its replays count, none is run again."""
        nonlocal replays, verify_s
        from planner.audit import audit_plan

        plan = replace(plan, inputs=dict(inputs or {}))
        rep = audit_plan(plan, hand, verified=False)
        if not rep.ok:
            tried.append(f"{where}: the plan fails a physics check ({rep.problems[0]})")
            return None
        if replayed_in is not None:
            verify_s += replayed_in.verify_s or 0.0
        elif verifying:
            from planner.sim.verify import default_workers, verify_suspects_first

            replays += 1  # (a plan whose gaits just held is replayed whole even past the budget)
            check = verify_suspects_first(plan, hand, directions, set(), workers=options.workers or default_workers(),
                                          engine=options.engine)
            verify_s += check.wall_time_s
            if not check.passed:
                nm, step, verdict, _ = check.first_failure()
                at = f"step {step}" if step >= 0 else "its first state"
                tried.append(f"{where}: the plan failed in the simulator ({nm} at {at}: {first_clause(verdict)})")
                return None
            plan = replace(plan, summary={**plan.summary, "verification": {**check.record(), "attempts": 1,
                                                                             "rejected": []}})
        return plan

    for name, P in candidate_poses(initial, final):
        if verifying and replays >= options.verify_attempts:
            tried.append(f"not tried at {name} and after: {replays} sequences were replayed at the poses before "
                         f"(--verify-attempts)")
            stopped = True
            break
        log.info("reposing: trying the gaits at %s", name)
        try:
            first = leg(initial, P, options, gait_fn)
            back = leg(final, P, options, gait_fn)
        except MotionError as err:
            tried.append(f"at {name}: {err}")
            continue
        first, back = _snap(first, back, options)
        a, b = first.end, back.end
        try:
            same = set(a.patches) == set(b.patches) and all(
                np.allclose(a.finger_q[f], b.finger_q[f], atol=options.same_slot_tol_rad) for f in a.patches if f != PALM)
            left = replace(options, verify_attempts=options.verify_attempts - replays) if verifying else options
            around = (lambda g, first=first, back=back, P=P: compose_at(initial, final, options, first, g, back, P)) \
                if verifying else None
            before = rounds.stopped
            res = None if same else gaits(a, b, left, replayed, budget=rounds, whole=around)
        except (NoSequenceError, PlannerError) as err:
            clause = first_clause(err)
            tried.append(f"at {name}: " + starved("the gaits fail for the same reason" if clause == known else clause,
                                                  rounds.stopped > before))
            continue
        if res is not None and res.whole is not None:  # verified whole with its gaits
            plan = checked(res.whole, f"at {name}", res)
        else:
            plan = checked(compose(initial, final, options, first, None if res is None else res.plan, back, P),
                           f"at {name}")
        if plan is not None:
            return plan, (verify_s if verifying else None), name
    def through(target, back: Leg | None, at_b: str):
        """gait -> repose -> gait through an intermediate grasp whose contacts follow the object
        from the initial grasp's pose to ``target``'s (the final grasp, or with ``back`` the final
        grasp's leg to another pose, ``back.end``, then ``back`` reversed); ``at_b`` names that
        pose. (plan, name) of the first that passes, else None (why in ``tried``)."""
        nonlocal stopped
        from planner.intermediate import intermediate_grasps

        log.info("reposing: trying intermediate grasps whose contacts follow the object to %s", at_b)
        through_, words = intermediate_grasps(initial, target, options)
        tried.append(words if back is None else f"to {at_b}: {words}")
        for it in through_:
            name = f"through an intermediate grasp ({it.words()})" + ("" if back is None else f" to {at_b}")
            if verifying and replays >= options.verify_attempts:
                tried.append(f"not tried {name} and after: {replays} sequences were replayed before (--verify-attempts)")
                stopped = True
                return None
            end, owed = it.move.end, 0
            if verifying and options.strategy == "graph" and not _same_grasp(initial, it.grasp) \
                    and not _same_grasp(end, target):
                # the gaits at the final grasp's pose searched first, unverified: a grasp they
                # cannot take to the final one is left before the gaits at the initial grasp's
                # pose are searched and replayed. Its rounds are taken from the shared budget;
                # given back just before the verified search there makes them again
                probe = RoundBudget(rounds.left)
                try:
                    gaits(end, target, replace(options, verify=False), lambda: None, budget=probe)
                except (NoSequenceError, PlannerError) as err:
                    rounds.take(probe.used)
                    rounds.stopped += probe.stopped
                    tried.append(f"{name}: at {at_b}: {starved(first_clause(err), probe.stopped > 0)}")
                    continue
                owed = probe.used
                rounds.take(owed)
            gaits_ = []
            for which, where, a, b in (("initial", "the initial grasp's pose", initial, it.grasp),
                                       ("final", at_b, end, target)):
                if _same_grasp(a, b):
                    gaits_.append(None)
                    continue
                if verifying and replays >= options.verify_attempts:  # (the gaits at A took what was left)
                    tried.append(f"{name}: the gaits at {where} not tried: {replays} sequences were "
                                 f"replayed before (--verify-attempts)")
                    break
                try:
                    left = replace(options, verify_attempts=options.verify_attempts - replays) if verifying else options
                    # the gaits at the final grasp's pose are verified in the whole plan (the
                    # gaits at A, which hold alone, replayed again with the move before them)
                    around = None if which == "initial" or not verifying else \
                        (lambda g, ga=gaits_[0], it=it: compose_through_at(initial, final, options, ga, it.move, g,
                                                                           back))
                    if which == "final":  # (the probe's rounds, made again here)
                        rounds.give(owed)
                        owed = 0
                    before = rounds.stopped
                    # (a refusal's first clause is kept: the grasp at its end is not replayed alone for
                    # the words after it)
                    res = gaits(a, b, left, replayed, budget=rounds, whole=around, final_alone=False)
                    if res.whole is not None:
                        plan = checked(res.whole, name, res)
                        if plan is not None:
                            return plan, name
                        break
                    gaits_.append(res.plan)
                except (NoSequenceError, PlannerError) as err:
                    tried.append(f"{name}: at {where}: {starved(first_clause(err), rounds.stopped > before)}")
                    break
            if len(gaits_) < 2:
                continue
            plan = checked(compose_through(initial, final, options, gaits_[0], it.move, gaits_[1], back), name)
            if plan is not None:
                return plan, name
        return None

    for at_b, P in through_poses(initial, final):
        if stopped:
            break
        back = None
        if P is not None:  # the final grasp taken there first
            try:
                back = leg(final, P, options, gait_fn)
            except MotionError as err:
                tried.append(f"through an intermediate grasp to {at_b}: the final grasp's leg there: {err}")
                continue
            if PALM in back.end.patches and not palm_frees(final, back.end, options):
                tried.append(f"through an intermediate grasp to {at_b}: not tried: the palm there lets no finger of "
                             f"the final grasp lift that cannot lift at its own pose")
                continue
        found = through(final if back is None else back.end, back, at_b)
        if found is not None:
            return found[0], (verify_s if verifying else None), found[1]
    mm, deg = pose_distance(Ta, Tb)
    differ = None if identical(Ta, Tb) else f"the grasps' object poses differ by {mm:.1f} mm / {deg:.1f} deg"
    if stopped:  # (whether a pose left would join them is not known)
        head = (f"{differ + ' and the' if differ else 'the'} search for a reposing move stopped on the "
                f"--verify-attempts budget ({replays} sequences replayed) before trying every candidate pose")
    else:
        head = f"{differ} and no reposing move joins them" if differ else "no reposing move helps"
    raise NoSequenceError(f"{head}: " + ("; ".join(tried) if tried else
                                         "no candidate pose (the palm is free in a grasp or has no geometry)"))
