"""Plans that move the object: finger gaits at a pose, joined by reposing moves.

The search's states are (object pose, contact assignment). Candidate poses ``P``, in order:
the final grasp's pose and the initial grasp's (when they differ), then the poses that rest
the object on the palm from either grasp (`planner.repose.settle_pose`: a thumb that cannot
lift because nothing opposes it can lift once the palm does). For each, the initial grasp is
reposed to ``P`` with its contacts fixed on the object, the final grasp likewise (its move
reversed ends the plan), and the gait search (`planner.regrasp.plan_gaits`) joins the two at
``P``. The first candidate that gives a plan is returned (poses tried in that order: the
fewest and shortest object motions first); each is work-bounded, so the answer does not
depend on the machine's load. With verification the whole plan (gaits and reposing moves)
is replayed in the planned directions before it is returned.
"""

from __future__ import annotations

import logging
import time
from dataclasses import replace

import numpy as np

from planner.errors import MotionError, NoSequenceError, PlannerError
from planner.model import PALM
from planner.options import PlanOptions, gravity_directions_of
from planner.plan_data import OBJECT, Plan, PlanState, PlanStep, pose_vector
from planner.repose import Reposing, pose_distance, repose, settle_pose

log = logging.getLogger("planner")

#: The object rests on the palm this far from it (half the touch tolerance of the contacts,
#: `planner.contacts.TOUCH_TOL_M`, as ``synth --palm`` places it).
SETTLE_GAP_FRACTION = 0.5
#: A pose at most this close to another candidate (mm, deg) is the same candidate.
SAME_POSE = (0.05, 0.05)


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


def _same(Ta, Tb) -> bool:
    mm, deg = pose_distance(Ta, Tb)
    return mm <= SAME_POSE[0] and deg <= SAME_POSE[1]


def candidate_poses(initial, final) -> list[tuple[str, np.ndarray]]:
    """(name, pose) of the poses the gaits may happen at, in the order they are tried."""
    from planner.contacts import TOUCH_TOL_M

    Ta, Tb = np.asarray(initial.obj.T_palm_obj, float), np.asarray(final.obj.T_palm_obj, float)
    out = []
    if not _same(Ta, Tb):
        out += [("the final grasp's pose", Tb), ("the initial grasp's pose", Ta)]
    if "free" not in (initial.spec.palm, final.spec.palm):
        for which, g in (("initial", initial), ("final", final)):
            s = settle_pose(g, SETTLE_GAP_FRACTION * TOUCH_TOL_M)
            if s is not None and not any(_same(s[0], T) for _, T in out):
                out.append((f"resting on the palm ({s[1] * 1e3:.1f} mm from the {which} grasp's pose)", s[0]))
    return out


def _repose_step(r: Reposing, frm: int, joints: tuple[str, ...], hand) -> PlanStep:
    idx = [k for f in r.fingers for k in hand.fingers[f].q_index]
    names = tuple(joints[k] for k in idx)
    return PlanStep(OBJECT, "repose", frm, frm + 1, names,
                    tuple(tuple(float(v) for v in q[idx]) for q in r.q_path),
                    tuple(pose_vector(T) for T in r.poses))


def compose(initial, final, options: PlanOptions, first: Reposing | None, gait: Plan | None, last: Reposing | None,
            P: np.ndarray) -> Plan:
    """One plan: the initial grasp reposed to ``P`` (``first``), the gait plan at ``P``, the
    final grasp's move from ``P`` (``last``, already reversed); states whose object pose
    differs from the initial grasp's carry it."""
    hand = initial.hand
    joints = tuple(hand.joint_names)
    T0 = np.asarray(initial.obj.T_palm_obj, float)
    pose_P = None if _same(P, T0) else pose_vector(P)
    states: list[PlanState] = []
    steps: list[PlanStep] = []
    if first is not None:
        states.append(grasp_state(initial, options, "initial"))
        start = gait.states[0] if gait is not None else grasp_state(first.end, options, "initial")
        states.append(replace(start, object_pose=pose_P))
        steps.append(_repose_step(first, 0, joints, hand))
        offset = 1
    else:
        offset = 0
    if gait is not None:
        if first is None:
            states.append(replace(gait.states[0], object_pose=pose_P))
        states += [replace(s, object_pose=pose_P) for s in gait.states[1:]]
        steps += [replace(s, from_state=s.from_state + offset, to_state=s.to_state + offset) for s in gait.steps]
    if last is not None:
        if not states:
            states.append(replace(grasp_state(last.start, options, "initial"), object_pose=pose_P))
        Tb = np.asarray(final.obj.T_palm_obj, float)
        states.append(replace(grasp_state(final, options, "final"), object_pose=None if _same(Tb, T0) else pose_vector(Tb)))
        steps.append(_repose_step(last, len(states) - 2, joints, hand))
    base = gait if gait is not None else None
    order = ([f"{OBJECT}:repose"] if first is not None else []) + (list(base.summary.get("order", [])) if base else []) \
        + ([f"{OBJECT}:repose"] if last is not None else [])
    summary = dict(base.summary) if base else {"strategy": options.strategy, "gait_steps": 0}
    summary.pop("verification", None)
    moves = [r for r in (first, last) if r is not None]
    summary.update(order=order, reposing={
        "moves": len(moves),
        "object_path_mm": round(sum(r.distance_mm for r in moves), 3),
        "object_path_deg": round(sum(r.angle_deg for r in moves), 3),
        "pose": list(pose_vector(P))})
    metrics = [s.metric for s in states]
    summary["bottleneck_metric"] = float(min(metrics))
    summary["mean_metric"] = float(np.mean(metrics))
    grips = [s.grip_force_n for s in states if s.grip_force_n is not None]
    summary["bottleneck_grip_force_n"] = max(grips) if grips else None
    if base is not None:
        return replace(base, object=initial.spec.object.to_data(), summary=summary, states=tuple(states),
                       steps=tuple(steps))
    from planner.plan_data import hand_files_record

    spec = initial.spec
    parameters = {k: v for k, v in vars(options).items() if k not in ("workers", "engine")}
    return Plan(hand={"name": hand.name, "spec": spec.hand_ref, "files": hand_files_record(hand)},
                object=spec.object.to_data(),
                friction={"mu": spec.friction.mu, "gamma": spec.friction.gamma, "edges": spec.friction.edges},
                inputs={}, parameters=parameters, summary=summary, joints=joints, states=tuple(states),
                steps=tuple(steps))


def _first_clause(err) -> str:
    """The first clause of a refusal (up to its first "; "): what failed, without the advice."""
    return str(err).split("; ", 1)[0]


def plan_with_reposing(initial, final, options: PlanOptions, inputs, verbose: bool, gaits) -> tuple[Plan, float | None, str]:
    """The first candidate pose (`candidate_poses`) joined by reposing moves and gaits.

    ``gaits(a, b, options)`` is the gait planner (`planner.regrasp.plan_gaits`), returning a
    `planner.regrasp.PlanResult`. Returns (plan, seconds of verification replays or None, a
    sentence on what was tried); raises NoSequenceError with every candidate's reason.
    """
    hand = initial.hand
    Ta, Tb = np.asarray(initial.obj.T_palm_obj, float), np.asarray(final.obj.T_palm_obj, float)
    tried = []
    directions = gravity_directions_of(options, hand)
    verifying = options.verify and bool(directions)
    verify_s = 0.0
    for name, P in candidate_poses(initial, final):
        log.info("reposing: trying the gaits at %s", name)
        try:
            first = None if _same(P, Ta) else repose(initial, P, options)
            back = None if _same(P, Tb) else repose(final, P, options)
        except MotionError as err:
            tried.append(f"at {name}: {err}")
            continue
        a = initial if first is None else first.end
        b = final if back is None else back.end
        try:
            same = set(a.patches) == set(b.patches) and all(
                np.allclose(a.finger_q[f], b.finger_q[f], atol=options.same_slot_tol_rad) for f in a.patches if f != PALM)
            gait = None if same else gaits(a, b, options).plan
        except (NoSequenceError, PlannerError) as err:
            tried.append(f"at {name}: {_first_clause(err)}")
            continue
        plan = compose(initial, final, options, first, gait, None if back is None else back.reversed(), P)
        plan = replace(plan, inputs=dict(inputs or {}))
        if verifying:
            from planner.sim.verify import default_workers, verify_suspects_first

            check = verify_suspects_first(plan, hand, directions, set(), workers=options.workers or default_workers(),
                                          engine=options.engine)
            verify_s += check.wall_time_s
            if not check.passed:
                nm, step, verdict, _ = check.first_failure()
                tried.append(f"at {name}: the plan failed in the simulator ({nm} at step {step}: {_first_clause(verdict)})")
                continue
            plan = replace(plan, summary={**plan.summary, "verification": {**check.record(), "attempts": 1,
                                                                             "rejected": []}})
        return plan, (verify_s if verifying else None), name
    mm, deg = pose_distance(Ta, Tb)
    head = (f"the grasps' object poses differ by {mm:.1f} mm / {deg:.1f} deg and no reposing move joins them"
            if not _same(Ta, Tb) else "no reposing move helps")
    raise NoSequenceError(f"{head}: " + ("; ".join(tried) if tried else
                                         "no candidate pose (the palm is free in a grasp or has no geometry)"))
