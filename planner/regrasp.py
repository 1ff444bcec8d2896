"""The regrasp pipeline: two realized grasps in, a finger-gaiting `Plan` out.

1. Contact slots per finger (`planner.slots`): its initial and final contacts and, on
   request (``intermediate`` N), N intermediate contacts from the finger's reachable
   contacts (`planner.slots.reachable_contacts`: in-limit postures closed onto the object,
   cached per hand and object).
2. `planner.gait_search.LazyGraph` (ranked best-first search evaluating only the states it
   reaches; or the greedy baseline) over those slots, with finger-finger collisions
   checked pairwise with coal. Anytime (``intermediate`` 0, ``time_limit_s`` not 0): when no
   sequence exists, rounds of intermediate contacts for the fingers that block progress
   (`planner.explain.failure_analysis`) and a new search, until found or out of time.
3. Finger paths, lazily: only for the gait steps of candidate sequences, best-ranked
   first; a step whose path cannot be planned removes its edge and the search goes on.
4. The winning sequence expanded into plan states and lift / move / land steps.

Options: `planner.options` (`PlanOptions`).
"""

from __future__ import annotations

import logging
import math
import re
import time
from dataclasses import asdict, dataclass, replace
from typing import Any, Callable, Mapping

import networkx as nx
import numpy as np

from planner.audit import audit_plan
from planner.closure import GRIP_CONE_SIDES
from planner.errors import InitialGraspDrops, InputError, MotionError, NoSequenceError, SpecError, UnknownNameError
from planner.fileio import describe
from planner.explain import explain_failure, failure_analysis
from planner.graph import LIFTED, GaitProblem, annotate_removable, seed_graph
from planner.helper import cores
from planner.options import PlanOptions, gravity_directions_of, verifies
from planner.plan_data import Alternative, Plan, PlanState, PlanStep, hand_files_record
from planner.realization import RealizedGrasp, realized_grasp
from planner.retreat import retreat_blocked
from planner.sim import snapshots
from planner.gait_search import REMOVED_RECORDS, GaitSequence, LazyGraph, greedy
from planner.slots import add_intermediate, add_slots, build_problem, holding_grasp, node_q


@dataclass(frozen=True)
class PlanResult:
    """What `plan_regrasp` returns: the plan plus things worth printing."""

    plan: Plan
    graph: nx.DiGraph
    sequence: GaitSequence
    alternatives: tuple[GaitSequence, ...]
    elapsed_s: float
    failed_moves: tuple[str, ...]
    verify_s: float | None = None
    #: with `plan_gaits`' ``whole``: the larger plan the verification replayed (and the physics
    #: check passed), its verification recorded
    whole: Plan | None = None


#: Progress of a long plan (search rounds, finger paths, verification replays): `logging`
#: INFO records; the CLI shows them on a terminal (``-q`` hides them).
log = logging.getLogger("planner")


def check_same_setup(initial, final, pose: bool = False) -> None:
    """Refuse two grasps that do not share hand, object and friction (and, with ``pose``, the
    object's pose: the gait search alone; the planner joins different poses by reposing
    moves, `planner.pose_search`).

    Args:
        initial, final: `planner.grasp.GraspSpec` of the two grasps.
    """
    a, b = initial, final
    checks = [
        ("hand", a.hand_ref, b.hand_ref),
        ("object.shape", a.object.shape, b.object.shape),
        ("object.size", a.object.size, b.object.size),
        ("object.mesh", a.object.mesh_path, b.object.mesh_path),
        *((("object.position", a.object.position, b.object.position),
           ("object.quat_xyzw", a.object.quat_xyzw, b.object.quat_xyzw)) if pose else ()),
        ("object.mass_kg", a.object.to_data()["mass_kg"], b.object.to_data()["mass_kg"]),  # None (volume x density) differs from a number
        ("friction", (a.friction.mu, a.friction.gamma, a.friction.edges), (b.friction.mu, b.friction.gamma, b.friction.edges)),
    ]
    for key, va, vb in checks:
        same = va == vb if isinstance(va, str) or va is None else np.allclose(np.asarray(va, float), np.asarray(vb, float), atol=1e-9)
        if not same and key == "object.quat_xyzw":  # q and -q are one orientation
            same = np.allclose(np.asarray(va, float), -np.asarray(vb, float), atol=1e-9)
        if not same:
            raise SpecError(b.path, key, f"differs from the initial grasp ({a.path}): {va} vs {vb}; both grasps must share "
                                         f"hand, object{', object pose' if pose else ''} and friction")


# ------------------------------------------------------------------ motion


def _straight_gait(hand, obj, q_a, q_b, finger, **_):
    """Without the motion planner: lift to the open posture, land from it."""
    idx = list(hand.fingers[finger].q_index)
    q_open = np.asarray(hand.q_open, float)[idx]
    out = {}
    if q_a is not None:
        out["lift"] = np.array([np.asarray(q_a, float)[idx], q_open])
    if q_b is not None:
        out["land"] = np.array([q_open, np.asarray(q_b, float)[idx]])
    return out


def _motion_gait(options: PlanOptions, verbose: bool = False):
    from planner.motion import available_planners, plan_gait_step  # OMPL: only when finger motions are planned

    if options.motion_planner not in available_planners():
        raise UnknownNameError("motion planner", options.motion_planner, available_planners())

    # moves not found even with no other finger in the way, by their end postures: not
    # planned again in the plan's other states (`plan_gait_step`'s failed_moves; a thumb the
    # object and palm keep from its final contact failed 25 states' paths of 20 000 collision
    # checks each, 137 s, on exp10 v2's Allegro box)
    failed_moves: dict = {}

    def gait(hand, obj, q_a, q_b, finger):
        return plan_gait_step(
            hand, obj, q_a, q_b, finger,
            planner=options.motion_planner, max_checks=options.motion_checks, seed=options.seed,
            verbose=verbose, failed_moves=failed_moves,
        )

    return gait


def _gaits(seq: GaitSequence):
    """Group the edges of a sequence into gaits: (i_lift or None, i_land or None, finger)."""
    i, n = 0, len(seq.actions)
    while i < n:
        finger, action = seq.actions[i]
        if action == "lift" and i + 1 < n and seq.actions[i + 1] == (finger, "land"):
            yield i, i + 1, finger
            i += 2
        elif action == "lift":
            yield i, None, finger
            i += 1
        else:
            yield None, i, finger
            i += 1


def _plan_motions(hand, obj, problem, seq: GaitSequence, gait_fn, cache: dict) -> list:
    """Paths of every gait of a sequence; raises _EdgeFailed naming the failed edge."""
    out = []
    for i_lift, i_land, finger in _gaits(seq):
        u = seq.nodes[i_lift] if i_lift is not None else None
        w = seq.nodes[i_land + 1] if i_land is not None else None
        key = (finger, u, w)
        if key not in cache:
            q_a = node_q(hand, problem, u) if u is not None else None
            q_b = node_q(hand, problem, w) if w is not None else None
            try:
                cache[key] = gait_fn(hand, obj, q_a, q_b, finger)
            except MotionError as err:
                cache[key] = err
        result = cache[key]
        if isinstance(result, MotionError):
            edge = (seq.nodes[i_land], seq.nodes[i_land + 1]) if i_land is not None else (seq.nodes[i_lift], seq.nodes[i_lift + 1])
            k = problem.fingers.index(finger)
            raise _EdgeFailed(edge, finger, str(result), lift_from=u[k] if u is not None else None,
                              land_on=w[k] if w is not None else None)
        out.append((i_lift, i_land, finger, result))
    return out


def _final_alone_words(final: RealizedGrasp, options: PlanOptions) -> str:
    """When every sequence failed in the simulator: the final grasp replayed alone (`hold_alone`,
    as ``check --execution`` replays it), and ``"; the final grasp 'X' alone does not hold in
    the simulator either (DIRECTION: VERDICT)"`` when it fails, else "". Said, not decided on:
    a plan arriving at a grasp can hold where the grasp taken alone does not (the iCub pen
    turned in the tripod, `grasps/icub/pen_writing_pose.yaml`)."""
    failure = hold_alone(final, options).first_failure()
    if failure is None:
        return ""
    return (f"; the final grasp {final.spec.name!r} alone does not hold in the simulator either ({failure[0]}: "
            f"{failure[2]}; check --execution replays it so)")


def _with_final_alone(err: NoSequenceError, final: RealizedGrasp, options: PlanOptions) -> NoSequenceError:
    """``err`` of a `plan_gaits` run with ``final_alone=False`` with the final grasp's words
    (`_final_alone_words`) put where that run left them out (``err.final_alone_at``), the
    final grasp replayed alone now; ``err`` itself when there is nothing to add."""
    at = getattr(err, "final_alone_at", None)
    words = "" if at is None else _final_alone_words(final, options)
    if not words:
        return err
    text = str(err)
    return NoSequenceError(text[:at] + words + text[at:], err.report)


def _rejected_words(rejected) -> str:
    """Sequences the simulator rejected, in words: order, direction, step and verdict each."""
    return "; ".join(f"{' '.join(x['order'])}: {x['direction']} at step {x['step']}: {x['verdict']}" for x in rejected)


def _rejected_summary(rejected, moves: list[str], planned: list[str]) -> str:
    """The rejected sequences merged by where they failed ("5 at lift thumb in side_-x, ...";
    ``moves``: the plan step each failed at, "lift thumb"), and what the user can act on: the
    directions that failed, when others held."""
    where: dict[tuple[str, str], int] = {}
    for x, move in zip(rejected, moves):
        where[(move, x["direction"])] = where.get((move, x["direction"]), 0) + 1
    parts = [f"{n} at {move} in {d}" for (move, d), n in sorted(where.items(), key=lambda kv: (-kv[1], kv[0]))]
    failed = sorted({x["direction"] for x in rejected})
    words = "failed " + ", ".join(parts)
    if len(rejected) > 1:
        words += (" (the directions are replayed in order, those that had rejected a sequence first; the first of "
                  "them to fail rejects it and stops the others)")
    if len(planned) > len(failed):
        words += (f"; every rejection was in {', '.join(failed)} of the {len(planned)} planned direction(s): if the "
                  f"hand will not be held so, plan for the orientations it will be held in (--gravity NAME, e.g. "
                  f"palm_up, or --gravity-set N)")
    return words


def _step_edges(seq: GaitSequence, motions) -> list[tuple]:
    """The graph edge of every plan step `_make_plan` writes for these motions: a lift and
    the move after it are the lift's edge, a landing its own (a move with no lift before it
    belongs to the landing)."""
    out = []
    for i_lift, i_land, _finger, paths in motions:
        lift = (seq.nodes[i_lift], seq.nodes[i_lift + 1]) if i_lift is not None else None
        land = (seq.nodes[i_land], seq.nodes[i_land + 1]) if i_land is not None else None
        for action in ("lift", "move", "land"):
            if action in paths:
                out.append(land if action == "land" or lift is None else lift)
    return out


_AUDIT_AT = re.compile(r"(states|steps)\[(\d+)\]")


def _audit_step(problem: str) -> tuple[int | None, bool]:
    """The plan step a physics-check problem line is about, and whether it is about the state
    the step reaches (``states[k]``: step k - 1) rather than the step's path (``steps[k]``);
    (None, False) for a line about something else (the inputs, the hand, the parameters)."""
    m = _AUDIT_AT.match(problem)
    if m is None:
        return None, False
    k = int(m.group(2))
    return (k - 1, True) if m.group(1) == "states" else (k, False)


def _drop_step(lazy: LazyGraph, problem: GaitProblem, seq: GaitSequence, motions, step: int, at_state: bool) -> None:
    """Take a failed plan step's move out of the graph; when the state it reaches failed,
    every move into that state goes too (but the final grasp's: only this move into it,
    another landing may reach it)."""
    edge = _step_edges(seq, motions)[step]
    lazy.remove_edge(*edge)
    if at_state and edge[1] != problem.goal:
        lazy.remove_state(edge[1])


class _EdgeFailed(Exception):
    """A gait whose finger paths could not be planned: the graph edge to drop, the finger and
    the slots it lifted off (``lift_from``) and landed on (``land_on``), None if it did not."""

    def __init__(self, edge, finger, why, lift_from=None, land_on=None):
        self.edge, self.finger, self.why = edge, finger, why
        self.lift_from, self.land_on = lift_from, land_on
        super().__init__(why)


def _forbid_stuck_contacts(lazy: LazyGraph, hand, obj, bad: _EdgeFailed, stuck: dict) -> None:
    """After a failed gait: a contact of it the finger cannot back off whatever the other
    fingers do (`planner.retreat.retreat_blocked`, cached in ``stuck`` per finger and slot)
    is never lifted off nor landed on again (one test instead of a re-plan per state); the
    initial or final grasp's contact of a finger that must move ends the search at once.

    Raises:
        NoSequenceError: the finger must leave its initial contact or reach its final one.
    """
    problem = lazy.problem
    i = problem.fingers.index(bad.finger)
    for slot in sorted({bad.lift_from, bad.land_on} - {None, LIFTED}):
        if problem.slots[bad.finger][slot].q is None:
            continue
        if (bad.finger, slot) not in stuck:
            stuck[(bad.finger, slot)] = retreat_blocked(hand, obj, problem.slots[bad.finger][slot].q, bad.finger)
        why = stuck[(bad.finger, slot)]
        if why is None:
            continue
        if problem.start[i] != problem.goal[i] and slot in (problem.start[i], problem.goal[i]):
            which = "leave its initial" if slot == problem.start[i] else "reach its final"
            raise NoSequenceError(f"finger {bad.finger} must {which} contact, and no finger path can: {why}")
        lazy.forbid(i, slot)


# ------------------------------------------------------------------ main entry


INTERMEDIATE_PER_ROUND = 2
"""Intermediate contacts added per blocking finger in each round of the anytime search."""
RESUME_ROUNDS = 3
"""Rounds of intermediate contacts added after every sequence of the graph failed later
(a finger path OMPL did not find, a replay that failed): a bound on the work."""


class RoundBudget:
    """Rounds of intermediate contacts several gait searches share (`plan_gaits`' ``budget``:
    the reposing candidates', `planner.pose_search.plan_with_reposing`, share one
    ``--max-rounds`` as they share one ``--verify-attempts``). Every round a search makes
    takes one, the anytime rounds and those after rejected sequences alike; a search with none
    left searches the contacts it has. A bound on the work, not the time."""

    def __init__(self, rounds: int):
        self.left = max(0, int(rounds))
        self.used = 0
        self.stopped = 0  # searches it stopped: they would have made a round, and none was left

    def take(self, n: int = 1) -> None:
        self.left -= n
        self.used += n

    def give(self, n: int) -> None:
        """Rounds taken for work that is about to be made again (and taken again then)."""
        self.left += n
        self.used -= n

    @property
    def spent(self) -> bool:
        return self.left <= 0


def _failed_words(problem: GaitProblem, bad: "_EdgeFailed") -> str:
    return f"{bad.finger} {problem.labels(bad.edge[0])[bad.finger]}->{problem.labels(bad.edge[1])[bad.finger]}: {bad.why}"


def _count(total: dict[str, int], more: Mapping[str, int]) -> None:
    for f, n in more.items():
        total[f] = total.get(f, 0) + n


def _goal_invalid(lazy: LazyGraph) -> bool:
    """The final grasp is no valid state (its fingers collide, it cannot hold the load...):
    no intermediate contact can change that."""
    goal = lazy.problem.goal
    lazy.ev.evaluate([goal])
    return lazy.ev.blocked_reason(goal) is not None


def anytime_search(problem: GaitProblem, initial, options: PlanOptions, t0: float,
                    prior: LazyGraph | None = None, budget: RoundBudget | None = None) -> tuple[LazyGraph, dict]:
    """Lazy ranked search, then (anytime mode: ``options.intermediate`` 0 and a time limit)
    rounds of intermediate contacts for the fingers that block progress
    (`planner.explain.failure_analysis`), until a sequence is found or the time limit passes.

    ``prior``: a search whose sequences all failed later (finger paths, verification): one
    more round starts from its graph, keeping the moves and states it removed, bounded by
    the round (one) rather than the clock, so the plan does not depend on the time the
    paths and replays took.

    ``budget``: rounds shared with other searches (`RoundBudget`); none are made once it is spent.

    Returns the last `LazyGraph` and what to record: rounds, contacts added per finger,
    states expanded, whether the ranking is exact, ``found`` (the sequences) and ``tried``
    (a sentence for the failure message).
    """
    deadline = t0 + options.time_limit_s if options.time_limit_s and prior is None else None
    auto = options.intermediate == 0 and options.time_limit_s != 0 and options.max_rounds > 0
    evaluator, added, rounds, expanded, unheld, held = None, {}, 0, 0, {}, set()
    lazy, found, out_of_time, starved = prior, [], False, False
    removed = set(prior.removed) if prior is not None else set()
    removed_states = set(prior.removed_states) if prior is not None else set()
    # the moves taken out, by why: named by the explanation of a failure
    records = {k: list(prior.G.graph.get(k, ())) for k in REMOVED_RECORDS} if prior is not None else {}
    forbidden = set(prior.forbidden) if prior is not None else set()
    if prior is not None:
        evaluator = prior.ev
    while True:
        if lazy is None:
            lazy = LazyGraph(problem, options.rank, evaluator=evaluator, deadline=deadline,
                             helpers=min(1, (options.workers or cores()) - 1))
            lazy.removed |= removed
            lazy.G.graph.update((k, list(moves)) for k, moves in records.items() if moves)
            lazy.removed_states |= removed_states
            lazy.forbidden |= forbidden
            evaluator = lazy.ev
            found = lazy.best(options.alternatives)
            expanded += lazy.G.graph["expanded"]
            out_of_time = lazy.timed_out or (deadline is not None and time.perf_counter() > deadline)
            if found or not auto or out_of_time or _goal_invalid(lazy) or (prior is not None and rounds >= 1) \
                    or rounds >= options.max_rounds:
                break
        if budget is not None and budget.spent:
            starved = True  # (the rounds it would make next are gone)
            budget.stopped += 1
            break
        # contacts for the fingers that could unblock progress, scored against the states
        # they should complete; every second round (and when those give none) one more for
        # every finger, scored as --intermediate N scores them (after m such rounds every
        # finger has had the m contacts of --intermediate m, or contacts at their places);
        # a finger the other fingers cannot hold the object without, in its second such
        # round (or when nothing else is left), gets a grasp of the others without it:
        # several new contacts at once (`holding_grasp`)
        analysis = failure_analysis(lazy.G)
        needs: dict[str, list] = {}
        for f, ctx in analysis["needs"]:
            needs.setdefault(f, []).append(ctx)
        problem, new = add_intermediate(problem, initial, {f: INTERMEDIATE_PER_ROUND for f in needs}, options, needs,
                                        deadline=deadline)
        if not new or rounds % 2 == 1:
            problem, more = add_intermediate(problem, initial, {f: 1 for f in problem.fingers}, options, deadline=deadline)
            _count(new, more)
        for f in analysis["unheld"]:
            unheld[f] = unheld.get(f, 0) + 1
            if f not in held and (unheld[f] == 2 or not new) and time.perf_counter() <= (deadline or math.inf):
                held.add(f)
                grasp = holding_grasp(problem, initial.hand, initial.obj, f, options.contact_model)
                problem, more = add_slots(problem, initial, {g: s for g, s in grasp.items() if s not in problem.slots[g]})
                _count(new, more)
        if not new:
            break
        rounds += 1
        if budget is not None:
            budget.take()
        _count(added, new)
        lazy = None
    spent = time.perf_counter() - t0
    what = ", ".join(f"{f} {n}" for f, n in added.items())
    if not auto:
        tried = (f"{options.intermediate} intermediate contacts per finger were tried" if options.intermediate else
                 "no intermediate contacts were tried (no --intermediate N, and --max-rounds or --time-limit 0)")
    elif _goal_invalid(lazy):
        tried = "no intermediate contacts were tried: they cannot make the final grasp valid"
    elif starved and not out_of_time:
        tried = (f"{rounds} round(s) of intermediate contacts were tried ({what or 'none added'}) in {spent:.1f} s; the "
                 f"rounds shared with the other searches were spent (--max-rounds {options.max_rounds})")
    elif rounds == 0 and not out_of_time:
        tried = "no intermediate contact could be added: the fingers that block progress reach no further contact"
    else:
        tried = (f"{rounds} round(s) of intermediate contacts were tried ({what or 'none added'}) in {spent:.1f} s"
                 + (f"; the time limit of {options.time_limit_s:g} s was reached before the round limit (the result "
                    "depends on this machine's speed: raise --time-limit)" if out_of_time else
                    f"; the round limit was reached (--max-rounds {options.max_rounds})" if rounds >= options.max_rounds
                    and prior is None else "; the blocking fingers reach no further contact"))
    if lazy.timed_out and not found:
        tried += f" (the search stopped after {lazy.G.graph['expanded']} states)"
    info = {"rounds": rounds, "intermediate_added": dict(sorted(added.items())), "expanded_states": expanded,
            "exact": bool(lazy.G.graph["search_exact"]), "found": found, "tried": tried}
    return lazy, info


def plan_regrasp(
    initial, final, options: PlanOptions = PlanOptions(), inputs: Mapping[str, Any] | None = None, verbose: bool = False
) -> PlanResult:
    """Plan a regrasp from one realized grasp to another: finger gaits, and reposing moves of
    the object where the grasps' object poses differ or gaits alone find nothing
    (``options.repose``; `planner.pose_search`).

    Args:
        initial, final: `planner.realization.RealizedGrasp` (same hand, object, friction), or
            grasp files (paths) or `GraspSpec`s, realized here.
        options, inputs, verbose: as `plan_gaits`.

    Returns:
        `PlanResult`; a plan with reposing moves has ``sequence`` None and an empty graph.

    Raises:
        NoSequenceError: no plan; the message says why (the gaits' refusal and, when
            reposing was tried, why each candidate pose failed).
    """
    if not isinstance(options, PlanOptions):  # (an AttributeError deep inside before)
        raise InputError(f"options: expected a PlanOptions (e.g. PlanOptions(motion=False)), got {describe(options)}")
    if not isinstance(initial, RealizedGrasp) or not isinstance(final, RealizedGrasp):
        (initial, rec_i), (final, rec_f) = realized_grasp(initial), realized_grasp(final)
        if inputs is None:
            inputs = {k: v for k, v in (("initial", rec_i), ("final", rec_f)) if v is not None}
    check_same_setup(initial.spec, final.spec, pose=not options.repose)
    # a sequence replayed after another was rejected resumes where the rejected one's replay
    # stood at the moves they share (`planner.sim.snapshots`: the same verdicts, less simulation)
    with snapshots.scope():
        return _plan_regrasp(initial, final, options, inputs, verbose)


def _plan_regrasp(initial, final, options: PlanOptions, inputs, verbose: bool) -> PlanResult:
    """`plan_regrasp` once the grasps are realized."""
    from planner.pose_search import candidate_poses, first_clause, identical, plan_with_reposing
    from planner.repose import pose_distance, state_reason

    t0 = time.perf_counter()
    mm, deg = pose_distance(initial.obj.T_palm_obj, final.obj.T_palm_obj)
    moved = not identical(initial.obj.T_palm_obj, final.obj.T_palm_obj)
    first_err = None
    if not moved:
        # reposing moves may follow: the final grasp is replayed alone for the refusal's words
        # only once no plan is found (`_with_final_alone`)
        reposes = options.repose and options.strategy == "graph"
        try:
            return plan_gaits(initial, final, options, inputs, verbose, final_alone=not reposes)
        except NoSequenceError as err:
            if isinstance(err, InitialGraspDrops) or not reposes or not candidate_poses(initial, final) \
                    or state_reason(initial, options) is not None or state_reason(final, options) is not None:
                # (an end grasp that is no valid state cannot be moved either)
                raise _with_final_alone(err, final, options) from None
            first_err = err
    log.info("object poses differ by %.1f mm / %.1f deg: reposing moves" if moved else
             "no gait sequence at this pose: trying reposing moves (%.1f mm / %.1f deg)", mm, deg)
    try:
        gait_fn = _motion_gait(options, verbose) if options.motion else _straight_gait
        plan, verify_s, _ = plan_with_reposing(initial, final, options, inputs, verbose,
                                               lambda a, b, o, r=None, **kw: plan_gaits(a, b, o, inputs, verbose, r, **kw),
                                               gait_fn,
                                               None if first_err is None else first_clause(first_err))
    except NoSequenceError as err:
        if first_err is None:
            raise
        # the reposing outcome before the gait refusal's closing advice ("to go on: ...")
        words = str(_with_final_alone(first_err, final, options))
        cut = words.rfind("; to go on: ")
        cut = len(words) if cut < 0 else cut
        raise NoSequenceError(f"{words[:cut]}; with the object moved: {err}{words[cut:]}", first_err.report) from None
    return PlanResult(plan, nx.DiGraph(), None, (), time.perf_counter() - t0, (), verify_s)


def end_grasp_replay(grasp: RealizedGrasp, gravity=None, *, engine: str | None = None, workers: int | None = None):
    """The simulator's half of execution mode's test of an end grasp (``check --execution``):
    ``grasp`` as the one-state plan ``plan G G --execution`` makes of it (the execution contact
    model; ``gravity`` a palm-frame vector, else the six directions of execution mode), replayed
    as that plan's verification replays it: the gravity ramped on, then held. Returns the
    `planner.sim.verify.Verification`. Raises NoSequenceError when execution mode's static test
    refuses the grasp (`planner.realization.execution_verdict` says why, first)."""
    return hold_alone(grasp, PlanOptions.for_execution(gravity=gravity, engine=engine, workers=workers))


def hold_alone(grasp: RealizedGrasp, options: PlanOptions):
    """``grasp`` as a one-state plan made with ``options`` (its contact model, gravity
    directions), replayed as that plan's verification replays it, in ``options.engine`` with
    ``options.workers``: `planner.sim.verify.Verification`. Raises NoSequenceError when the
    static test refuses the grasp."""
    from planner.sim.verify import default_workers, verify_suspects_first  # an engine: only when replaying

    one = plan_gaits(grasp, grasp, replace(options, verify=False, motion=False))
    return verify_suspects_first(one.plan, grasp.hand, gravity_directions_of(options, grasp.hand), [],
                                 workers=options.workers or default_workers(), engine=options.engine)


def plan_gaits(
    initial, final, options: PlanOptions = PlanOptions(), inputs: Mapping[str, Any] | None = None, verbose: bool = False,
    on_replay: Callable[[], Any] | None = None, budget: RoundBudget | None = None,
    whole: Callable[[Plan], tuple[Plan, int]] | None = None, final_alone: bool = True,
) -> PlanResult:
    """Plan a finger-gaiting sequence from one realized grasp to another, the object fixed.

    Args:
        initial, final: `planner.realization.RealizedGrasp` (same hand, object, pose, friction), or
            grasp files (paths) or `GraspSpec`s, realized here.
        options: planner parameters.
        inputs: what to record under the plan's ``inputs`` (paths and sha256).
        verbose: let the motion planner print its log.
        on_replay: called once per sequence the verification replays (a caller sharing
            ``--verify-attempts`` among several searches counts them).
        budget: rounds of intermediate contacts shared with other searches (`RoundBudget`),
            the rounds after rejected sequences included; None: this search's own
            ``--max-rounds``, and up to `RESUME_ROUNDS` after rejected sequences.
        whole: when the gaits are part of a larger plan (reposing moves before or after them,
            `planner.pose_search`): the gait plan -> (that plan, the index of its first gait
            step). The verification replays and the physics check checks the larger plan, once
            per sequence (not the gaits, then the whole again); a failure in a gait step rejects
            the sequence as usual, one outside the gaits ends the search (no other sequence mends
            it). The result's ``whole`` is the larger plan that passed.
        final_alone: when every sequence failed in the simulator, replay the final grasp alone
            for the refusal's words (`_final_alone_words`); False: not now (the refusal's
            ``final_alone_at`` says where the words go, `_with_final_alone`): for a caller that
            keeps only the refusal's first clause (`planner.pose_search`'s gaits to an
            intermediate grasp) or may still find a plan another way (reposing moves,
            `_plan_regrasp`): the replay would be spent for nothing.

    Returns:
        `PlanResult` with the plan, the graph and the ranked sequences.

    Raises:
        NoSequenceError: no sequence exists (or none whose moves can be executed);
            the message says why.
    """
    if not isinstance(initial, RealizedGrasp) or not isinstance(final, RealizedGrasp):
        # paths or GraspSpecs: realized here, their files recorded as the CLI records them
        (initial, rec_i), (final, rec_f) = realized_grasp(initial), realized_grasp(final)
        if inputs is None:
            inputs = {k: v for k, v in (("initial", rec_i), ("final", rec_f)) if v is not None}
    check_same_setup(initial.spec, final.spec, pose=True)
    gait_fn = _motion_gait(options, verbose) if options.motion else _straight_gait
    t0 = time.perf_counter()
    hand, obj = initial.hand, initial.obj
    for which, g in (("initial", initial), ("final", final)):
        c = g.closure_under(options.contact_model)
        if not c.is_force_closure:
            model = "" if options.contact_model == "patch" else f" with the {options.contact_model!r} contact model"
            raise NoSequenceError(f"the {which} grasp {g.spec.name!r} is not force closure{model} (metric {c.metric:.3g})")
    problem = build_problem(initial, final, options)
    failed: list[str] = []
    cache: dict = {}
    stuck: dict = {}
    directions = gravity_directions_of(options, hand)
    verifying = verifies(options.verify, options.strategy, directions)
    verified, rejected, verify_s, workers, plan = None, [], 0.0, None, None
    rejected_moves: list[str] = []  # the plan step each rejected sequence failed at, in words
    unsound: list[str] = []  # moves the plan's physics check refused: the move and its first problem

    def with_final_alone(head: str) -> tuple[str, int | None]:
        """A refusal after every sequence failed in the simulator, up to ``head``: (the text with
        the final grasp's words, None) when ``final_alone``; else (``head``, where the words go
        later: the refusal's ``final_alone_at``, `_with_final_alone`); gaits inside a larger
        plan (``whole``, a reposing candidate's): (``head``, None), one replay per candidate
        pose is not spent on words."""
        if whole is not None:
            return head, None
        if final_alone:
            return head + _final_alone_words(final, options), None
        return head, len(head)
    if verifying:
        from planner.sim.verify import default_workers, engines_of, verify_suspects_first  # an engine: only when verifying

        workers = options.workers or default_workers()
        engine_names = " and ".join(engines_of(options.engine))  # an engine not installed: refused before the search
    if options.strategy == "greedy":  # thesis Algorithm 2: only visits the states it walks through
        G = seed_graph(problem)
        candidates = [replace(greedy(G), rank=options.rank)]
        try:
            motions = _plan_motions(hand, obj, problem, candidates[0], gait_fn, cache)
        except _EdgeFailed as bad:
            raise NoSequenceError(f"greedy sequence has a finger move that cannot be planned: {_failed_words(problem, bad)}") from None
        search_info = {"rounds": 0}
    else:
        log.info("searching the grasp-state graph")
        lazy, search_info = anytime_search(problem, initial, options, t0, budget=budget)
        problem, G = lazy.problem, lazy.G
        candidates = search_info.pop("found")
        log.info("search: %d sequence(s) found, %d round(s) of intermediate contacts, %.1f s",
                 len(candidates), search_info["rounds"], time.perf_counter() - t0)
        resumed = 0
        for _ in range(50):
            resume = not candidates and resumed < RESUME_ROUNDS and options.intermediate == 0 \
                and options.time_limit_s != 0 and bool(failed or rejected or unsound)
            if resume and budget is not None and budget.spent:
                budget.stopped += 1  # (a round after the rejected sequences, and none left)
                resume = False
            if resume:
                # every sequence of this graph failed later: one more round of intermediate
                # contacts, keeping what was removed
                resumed += 1
                lazy, more_info = anytime_search(problem, initial, options, t0, prior=lazy, budget=budget)
                problem, G = lazy.problem, lazy.G
                candidates = more_info.pop("found")
                search_info["rounds"] += more_info["rounds"]
                for f, n in more_info["intermediate_added"].items():
                    search_info["intermediate_added"][f] = search_info["intermediate_added"].get(f, 0) + n
                search_info["expanded_states"] += more_info["expanded_states"]
                search_info["exact"] = search_info["exact"] and more_info["exact"]
                if not candidates:
                    search_info["tried"] += f"; after the failed moves, {more_info['tried']}"
                continue
            if not candidates:
                err = explain_failure(G, intermediate_tried=bool(options.intermediate or search_info["rounds"]),
                                      tried=search_info["tried"])
                if failed:
                    counts = {m: failed.count(m) for m in dict.fromkeys(failed)}
                    moves = "; ".join(m + (f" (x{n} states)" if n > 1 else "") for m, n in counts.items())
                    err = NoSequenceError(f"{err}; finger moves that could not be planned: {moves}", err.report)
                alone_at = None
                if rejected:
                    text, alone_at = with_final_alone(f"{err}; sequences that failed in the simulator ({len(rejected)}): "
                                                      f"{_rejected_words(rejected[:2])}")
                    err = NoSequenceError(text, err.report)
                if unsound:
                    err = NoSequenceError(f"{err}; moves the plan's physics check refused ({len(unsound)}): "
                                          f"{'; '.join(unsound[:2])}", err.report)
                err.final_alone_at = alone_at
                raise err
            try:
                if options.motion:
                    log.info("finger paths for %s", " ".join(candidates[0].order(problem)))
                motions = _plan_motions(hand, obj, problem, candidates[0], gait_fn, cache)
            except _EdgeFailed as bad:
                failed.append(_failed_words(problem, bad))
                lazy.remove_edge(*bad.edge)
                if options.motion:
                    _forbid_stuck_contacts(lazy, hand, obj, bad, stuck)
                candidates = lazy.best(options.alternatives)
                continue
            if not verifying:
                break
            annotate_removable(G, [v for s in candidates for v in s.nodes])
            plan = _make_plan(initial, final, options, inputs or {}, problem, G, candidates[0], candidates[1:], motions,
                              search_info)
            replayed, k0 = (plan, 0) if whole is None else whole(plan)
            log.info("verifying in %s: attempt %d, %d direction(s) in %d process(es)", engine_names, len(rejected) + 1,
                     len(directions), min(workers, len(directions)))
            # the physics check `replay` and `verify` run on a plan file (`planner.audit`) runs
            # here while the first replays run in their processes, on a core they leave free
            # (`planner.sim.verify.replay_directions`' meanwhile): a plan it refuses is
            # never returned and its replays count for nothing. Without the input files: the
            # plan is made from these grasps, and gaits at a reposing candidate's pose start and
            # end at the files' grasps moved there (`planner.pose_search`)
            audits = []
            # the directions are replayed in order, those that rejected a sequence before
            # first (the latest first): the first to fail rejects it and stops the others (a
            # sequence they reject again costs their replays only; a bound on the work, not
            # the time)
            check = verify_suspects_first(replayed, hand, directions, [r["direction"] for r in reversed(rejected)],
                                          workers=workers,
                                          engine=options.engine,
                                          meanwhile=lambda: audits.append(audit_plan(replace(replayed, inputs={}), hand, verified=False)))
            audit = audits[0]
            if not audit.ok:
                step, at_state = _audit_step(audit.problems[0])
                if step is not None and whole is not None:
                    if not k0 <= step < k0 + len(plan.steps):  # (states[k0], the gaits' first state, is step k0 - 1's)
                        raise NoSequenceError(f"the plan fails a physics check ({audit.problems[0]})")
                    step -= k0
                if step is None or step < 0:  # not a move of this sequence: no other sequence mends it
                    raise NoSequenceError(
                        f"the best sequence ({' '.join(candidates[0].order(problem))}) fails the physics check replay "
                        f"and verify run on a plan: {audit.problems[0]}; no plan is returned that they would refuse "
                        f"(--no-verify returns it unchecked)")
                # a move (or the state it reaches) the check refuses: it goes, as one the
                # simulator rejected would, and the next sequence is tried (its replays ignored)
                unsound.append(f"{plan.steps[step].action} {plan.steps[step].finger}: {audit.problems[0]}")
                log.info("physics check refused %s", unsound[-1])
                _drop_step(lazy, problem, candidates[0], motions, step, at_state)
                candidates = lazy.best(options.alternatives)
                continue
            if on_replay is not None:
                on_replay()
            verify_s += check.wall_time_s
            log.info("verification %s (%.1f s)", "passed" if check.passed else "failed: " + check.first_failure()[0],
                     check.wall_time_s)
            if check.passed:
                verified = check
                break
            name, step, verdict, at_state = check.first_failure()
            if whole is not None:
                if not k0 <= step < k0 + len(plan.steps):  # not a gait: a reposing move, a lift or landing around
                    at = (f"step {step}: {replayed.steps[step].action} {replayed.steps[step].finger}" if step >= 0
                          else "its first state")
                    from planner.pose_search import first_clause

                    raise NoSequenceError(f"the plan failed in the simulator ({name} at {at}: {first_clause(verdict)})")
                step -= k0
            seq = candidates[0]
            rejected.append({"order": list(seq.order(problem)), "direction": name, "step": step, "verdict": verdict})
            rejected_moves.append(f"{plan.steps[step].action} {plan.steps[step].finger}" if step >= 0 else "state 0")
            if verbose:
                print(f"verify: sequence {_rejected_words(rejected[-1:])}")
            if step < 0:
                raise InitialGraspDrops(f"the initial grasp {initial.spec.name!r} does not hold in the simulator "
                                        f"({name}: {verdict}); no sequence starting from it can pass, nor a reposing "
                                        f"move (--no-verify returns one anyway)")
            if len(rejected) >= options.verify_attempts:
                head = (f"no sequence held in the simulator in {len(rejected)} attempt(s) (--verify-attempts; "
                        f"{verify_s:.1f} s of replays): {_rejected_summary(rejected, rejected_moves, [n for n, _ in directions])}; "
                        f"the first: {_rejected_words(rejected[:1])}")
                head, alone_at = with_final_alone(head)
                err = NoSequenceError(f"{head}; --no-verify returns the best sequence unverified")
                err.final_alone_at = alone_at
                raise err
            # the re-search is bounded by the graph, not by the clock the replays spent: a
            # deadline passed during them would stop it where the last search stood (and make
            # the plan depend on the machine's load and the number of workers)
            lazy.deadline, lazy.timed_out = None, False
            _drop_step(lazy, problem, seq, motions, step, at_state)
            candidates = lazy.best(options.alternatives)
        else:
            counts = {m: failed.count(m) for m in dict.fromkeys(failed)}
            raise NoSequenceError("no executable sequence after 50 re-plans; impossible moves: "
                                  + "; ".join(m + (f" (x{n} states)" if n > 1 else "") for m, n in counts.items()))
        del search_info["tried"]
    best = candidates[0]
    if plan is None:  # (a verified plan is the one the replays ran)
        annotate_removable(G, [v for s in candidates for v in s.nodes])
        plan = _make_plan(initial, final, options, inputs or {}, problem, G, best, candidates[1:], motions, search_info)
    whole_plan = None
    if verifying:
        record = {**verified.record(), "attempts": len(rejected) + 1, "rejected": rejected}
        plan = replace(plan, summary={**plan.summary, "verification": record})
        if whole is not None:  # (its rejections at the whole plan's steps)
            shifted = [{**r, "step": r["step"] + k0 if r["step"] >= 0 else r["step"]} for r in rejected]
            whole_plan = replace(replayed, summary={**replayed.summary, "verification": {**record, "rejected": shifted}})
    return PlanResult(plan, G, best, tuple(candidates[1:]), time.perf_counter() - t0, tuple(failed),
                      verify_s if verifying else None, whole_plan)


def _make_plan(initial, final, options, inputs, problem, G, best, others, motions, search_info) -> Plan:
    hand = initial.hand
    states: list[PlanState] = []
    steps: list[PlanStep] = []

    def add_state(node, q) -> int:
        data = G.nodes[node]
        states.append(
            PlanState(
                fingers=data["labels"],
                patches=data["patches"],
                is_force_closure=data["closure"].is_force_closure,
                metric=data["metric"],
                removable=tuple(sorted(data["removable"])),
                q=tuple(float(v) for v in q),
                grip_force_n=data.get("grip_force"),
                grip_force_by_gravity_n=data.get("grip_forces"),
                hold_factor_by_gravity=G.graph["evaluator"].hold_factors(node),
            )
        )
        return len(states) - 1

    q = node_q(hand, problem, best.nodes[0])
    current = add_state(best.nodes[0], q)
    for i_lift, i_land, finger, paths in motions:
        idx = list(hand.fingers[finger].q_index)
        joints = tuple(hand.fingers[finger].joints)
        lifted_node = best.nodes[i_lift + 1] if i_lift is not None else best.nodes[i_land]
        for action in ("lift", "move", "land"):
            if action not in paths:
                continue
            path = np.asarray(paths[action], float)
            q = q.copy()
            q[idx] = path[-1]
            node = best.nodes[i_land + 1] if action == "land" else lifted_node
            nxt = add_state(node, q)
            steps.append(PlanStep(finger, action, current, nxt, joints, tuple(tuple(float(v) for v in wp) for wp in path)))
            current = nxt
    spec = initial.spec
    metrics = [G.nodes[v]["metric"] for v in best.nodes]
    summary = {
        "strategy": options.strategy,
        "gait_steps": best.gait_steps,
        "graph_edges_in_sequence": len(best.actions),
        "bottleneck_metric": best.bottleneck,
        "mean_metric": float(np.mean(metrics)),
        "graph_nodes": G.number_of_nodes(),
        "graph_edges": G.number_of_edges(),
        "blocked_states": len(G.graph["blocked"]),
        "order": list(best.order(problem)),
        "rank": options.rank,
        "bottleneck_grip_force_n": best.bottleneck_grip,
        "search": {k: v for k, v in search_info.items() if k != "tried"},  # "tried" is for the error message
    }
    parameters = asdict(options)
    del parameters["workers"]  # how many processes verified it changes nothing in the plan
    del parameters["engine"]  # the engine(s) verified in: summary.verification.engine
    directions = gravity_directions_of(options, hand)
    parameters["gravity_directions"] = [{"name": n, "gravity": list(g)} for n, g in directions] or None
    parameters["grip_cone_sides"] = GRIP_CONE_SIDES if directions else None
    return Plan(
        hand={"name": hand.name, "spec": spec.hand_ref, "files": hand_files_record(hand)},
        object=spec.object.to_data(),
        friction={"mu": spec.friction.mu, "gamma": spec.friction.gamma, "edges": spec.friction.edges},
        inputs=dict(inputs),
        parameters=parameters,
        summary=summary,
        joints=tuple(hand.joint_names),
        states=tuple(states),
        steps=tuple(steps),
        alternatives=tuple(
            Alternative(s.order(problem), s.bottleneck, s.gait_steps, s.mean_metric, s.bottleneck_grip) for s in others
        ),
    )
