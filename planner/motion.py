"""Finger paths: joint-space motion of one finger around the object (OMPL).

This is the only module that imports OMPL. A gait step of a finger is three paths
(see docs/INTERFACES.md, plan file): **lift** (retreat from contact A a few mm along
the outward normal, Jacobian steps), **move** (joint-space transfer from the retreat
to the approach configuration above contact B, keeping a clearance from the object;
straight line when free, otherwise an OMPL planner) and **land** (approach along the
normal and close onto contact B, ending exactly at the contact configuration).

Paths are arrays ``(m, n_finger_joints)`` of that finger's joint values, in the order
of ``hand.fingers[finger].joints``; consecutive waypoints differ by at most
``resolution_rad`` in every joint, the first row is the start and the last the goal.
The other fingers do not move.

A coupled finger (`planner.hand.Coupling`) is planned in its free coordinates (its drivers
and uncoupled joints): the OMPL space is theirs, the lift and land step them
(`planner.hand.Finger.step`), and every waypoint has its followers set by the coupling (a
straight line between coupled ends is coupled: the coupling is affine).

Here: the OMPL glue, the move (:func:`plan_finger_move`) and the gait step
(:func:`plan_gait_step`). The lift and land are `planner.retreat`; the finger's view of the
collision layer and the path helpers are `planner.finger_scene`.

Console output. OMPL logs through its own C++ handler; every call here runs with
OMPL's log level set to ``LOG_NONE`` (restored afterwards) unless ``verbose=True``.
The OMPL objects (state space, planner, validity callback...) live only inside
:func:`_solve_ompl` and hold no reference cycle, so nothing of OMPL is alive at
interpreter exit and nanobind has no leak to report (its "leaked instances/functions"
lines appear only for objects still alive at shutdown).
"""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Iterator, Mapping
from types import MappingProxyType

import numpy as np
from ompl import base as ob
from ompl import geometric as og
from ompl import util as ou

from planner.errors import InputError, MotionError, UnknownNameError
from planner.finger_scene import (
    DEFAULT_CLEARANCE_M,
    DEFAULT_TOUCH_TOL_M,
    FingerScene,
    as_q,
    check_limits,
    check_positive,
    densify,
    finger_of,
    first_invalid,
)
from planner.options import MOTION_CHECKS, MOTION_PLANNER_CLASSES
from planner.retreat import DEFAULT_LIFT_M, retreat


# the planner names and classes: `planner.options.MOTION_PLANNER_CLASSES`
def _registered_planners() -> Mapping[str, str]:
    return MappingProxyType({k: v for k, v in MOTION_PLANNER_CLASSES.items() if hasattr(og, v)})


PLANNERS: Mapping[str, str] = _registered_planners()
"""Registered planners: name -> OMPL class in ``ompl.geometric`` (only those installed)."""


def available_planners() -> tuple[str, ...]:
    """Names accepted by ``planner=``, sorted."""
    return tuple(sorted(PLANNERS))


def _planner_class_name(name: str) -> str:
    try:
        return PLANNERS[name]
    except (KeyError, TypeError):
        raise UnknownNameError("planner", str(name), PLANNERS) from None


# --------------------------------------------------------------------------- OMPL


@contextlib.contextmanager
def _ompl_output(verbose: bool) -> Iterator[None]:
    """OMPL's log level is global: silence it (or open it up) and restore it after."""
    previous = ou.getLogLevel()
    ou.setLogLevel(ou.LOG_INFO if verbose else ou.LOG_NONE)
    try:
        yield
    finally:
        ou.setLogLevel(previous)


def _as_checks(max_checks) -> int:
    if isinstance(max_checks, bool) or int(max_checks) != max_checks:
        raise InputError(f"max_checks must be a whole number of collision checks; got {max_checks!r}")
    return int(max_checks)


def _ompl_seed(seed: int) -> int:
    # OMPL rejects 0 ("seed cannot be 0") and keeps a 32-bit seed.
    return int(seed) % (2**32 - 1) + 1


def _solve_ompl(
    is_valid,
    start: np.ndarray,
    goal: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    *,
    planner: str,
    max_checks: int,
    seed: int,
    resolution_rad: float,
    verbose: bool,
) -> np.ndarray | None:
    """Plan in the box ``[lower, upper]`` of R^n; returns the simplified waypoints or None.

    The planner stops at its first solution or after ``max_checks`` calls of ``is_valid``
    (checked by OMPL once per planner iteration, so a few more may run).

    Every OMPL object is local to this frame (see the module docstring), so the caller
    raises its error after they are gone.
    """
    n = len(start)
    with _ompl_output(False):
        # Re-seeding OMPL's generator of seeds makes the samplers created below
        # reproducible. After the first plan OMPL logs an error that "changing the seed
        # will not lead to deterministic sampling": true only for samplers that already
        # exist, and none of ours do, so it is silenced even when verbose.
        ou.RNG.setSeed(_ompl_seed(seed))
    with _ompl_output(verbose):
        space = ob.RealVectorStateSpace(n)
        bounds = ob.RealVectorBounds(n)
        for i in range(n):
            bounds.setLow(i, float(lower[i]))
            bounds.setHigh(i, float(upper[i]))
        space.setBounds(bounds)
        si = ob.SpaceInformation(space)
        checks = [0]

        def valid(s) -> bool:
            checks[0] += 1
            return bool(is_valid(np.fromiter((s[i] for i in range(n)), float, n)))

        si.setStateValidityChecker(valid)
        # Motions are checked every resolution_rad (L2 norm, so every joint moves less).
        si.setStateValidityCheckingResolution(resolution_rad / space.getMaximumExtent())
        si.setup()
        s_start = space.allocState()
        s_goal = space.allocState()
        for i in range(n):
            s_start[i] = float(start[i])
            s_goal[i] = float(goal[i])
        pdef = ob.ProblemDefinition(si)
        pdef.setStartAndGoalStates(s_start, s_goal)
        objective = ob.PathLengthOptimizationObjective(si)
        objective.setCostThreshold(ob.Cost(math.inf))  # any solution satisfies it
        pdef.setOptimizationObjective(objective)
        algo = getattr(og, _planner_class_name(planner))(si)
        algo.setProblemDefinition(pdef)
        algo.setup()
        ptc = ob.plannerOrTerminationCondition(
            ob.PlannerTerminationCondition(lambda: checks[0] >= max_checks),
            ob.exactSolnPlannerTerminationCondition(pdef),
        )
        algo.solve(ptc)
        if not pdef.hasExactSolution():
            return None
        path = pdef.getSolutionPath()
        # Shortcutting without a time budget keeps it deterministic; simplifyMax gives
        # about the same length for four times the collision checks.
        simplifier = og.PathSimplifier(si)
        simplifier.ropeShortcutPath(path)
        simplifier.reduceVertices(path)
        simplifier.partialShortcutPath(path)
        waypoints = np.array(
            [[path.getState(k)[i] for i in range(n)] for k in range(path.getStateCount())]
        )
    return waypoints


# --------------------------------------------------------------- finger transfer


def _plan_move(
    scene: FingerScene,
    a: np.ndarray,
    b: np.ndarray,
    *,
    planner: str,
    max_checks: int,
    seed: int,
    clearance_m: float,
    resolution_rad: float,
    verbose: bool,
) -> np.ndarray:
    name = scene.finger.name
    if not scene.is_valid(a, clearance_m):
        raise MotionError(f"finger {name}: start configuration is not free: {scene.explain(a, clearance_m)}")
    if not scene.is_valid(b, clearance_m):
        raise MotionError(f"finger {name}: goal configuration is not free: {scene.explain(b, clearance_m)}")
    straight = densify(np.array([a, b]), resolution_rad)
    if first_invalid(scene, straight, clearance_m) is None:
        return straight
    lower = np.asarray(scene.hand.lower, dtype=float)[scene.idx]
    upper = np.asarray(scene.hand.upper, dtype=float)[scene.idx]
    t0 = time.perf_counter()
    f = scene.finger
    if not f.coupled:
        waypoints = _solve_ompl(
            lambda q: scene.is_valid(q, clearance_m),
            a, b, lower, upper,
            planner=planner, max_checks=max_checks, seed=seed,
            resolution_rad=resolution_rad, verbose=verbose,
        )
    else:
        # a coupled finger is planned over its free coordinates (its drivers and uncoupled
        # joints); a follower moves |m| times its driver, so the checks are |m| times finer
        free = list(f.free)
        full = np.array(a, dtype=float)

        def expand(z):
            full[free] = z
            return f.couple(full)

        fine = max([1.0] + [abs(m) for _, _, m, _ in f.coupled])
        waypoints = _solve_ompl(
            lambda z: scene.is_valid(expand(z), clearance_m),
            a[free], b[free], lower[free], upper[free],
            planner=planner, max_checks=max_checks, seed=seed,
            resolution_rad=resolution_rad / fine, verbose=verbose,
        )
        if waypoints is not None:
            waypoints = np.array([expand(z) for z in waypoints])
    if waypoints is None:
        raise MotionError(
            f"finger {name}: {planner} found no collision-free path in {max_checks} collision checks "
            f"({time.perf_counter() - t0:.1f} s; clearance {clearance_m * 1000:.1f} mm)"
        )
    waypoints[0], waypoints[-1] = a, b
    path = densify(waypoints, resolution_rad)
    bad = first_invalid(scene, path, clearance_m)
    if bad is not None:  # OMPL checks the same resolution; this guards the interpolation
        raise MotionError(f"finger {name}: planned path fails its re-check at waypoint {bad}: "
                          f"{scene.explain(path[bad], clearance_m)}")
    return path


def plan_finger_move(
    hand,
    obj,
    q_start,
    q_goal,
    finger: str,
    *,
    planner: str = "rrtconnect",
    max_checks: int = MOTION_CHECKS,
    seed: int = 0,
    clearance_m: float = DEFAULT_CLEARANCE_M,
    touch_tol_m: float = DEFAULT_TOUCH_TOL_M,
    resolution_rad: float = 0.01,
    verbose: bool = False,
) -> np.ndarray:
    """Collision-free joint-space path of one finger; the other fingers stay at ``q_start``.

    The straight joint-space line is tried first (checked every ``resolution_rad``);
    when it collides, the OMPL planner ``planner`` searches the finger's joint box,
    seeded with ``seed`` (same seed, same path), and its path is simplified and
    re-interpolated. Validity: every link of the finger keeps ``clearance_m`` from the
    object and does not penetrate the palm, the other fingers or its own non-adjacent
    links (pairs as in ``planner.contacts.collisions``).

    Args:
        hand: a ``planner.hand.Hand``.
        obj: a ``planner.objects.GraspObject`` (pose ``T_palm_obj``).
        q_start: hand configuration (nq,); its values of the other fingers are kept.
        q_goal: hand configuration (nq,); only the finger's joints are read.
        finger: name of the moving finger.
        planner: one of :func:`available_planners`.
        max_checks: work bound: collision checks of the OMPL search (`MOTION_CHECKS`).
        seed: OMPL random seed.
        clearance_m: distance kept from the object.
        touch_tol_m: finger-object penetration tolerated at contacts (used by the
            lift and land of :func:`plan_gait_step`; the move keeps ``clearance_m``).
        resolution_rad: maximum joint step between waypoints (and of collision checks).
        verbose: let OMPL log to the console.

    Returns:
        (m, n_finger_joints) joint waypoints in ``hand.fingers[finger].joints`` order;
        first row = start, last row = goal.

    Raises:
        UnknownNameError: unknown planner or finger.
        InputError: bad shapes, non-finite values or a configuration outside joint limits.
        MotionError: start or goal in collision, or no path within ``max_checks``.
    """
    _planner_class_name(planner)
    f = finger_of(hand, finger)
    check_positive(max_checks=max_checks, clearance_m=clearance_m, resolution_rad=resolution_rad)
    max_checks = _as_checks(max_checks)
    if not (np.isfinite(touch_tol_m) and touch_tol_m >= 0):
        raise InputError(f"touch_tol_m must be >= 0; got {touch_tol_m!r}")
    qs = as_q(hand, q_start, "q_start")
    qg = as_q(hand, q_goal, "q_goal")
    a = check_limits(hand, f, qs[list(f.q_index)], "q_start")
    b = check_limits(hand, f, qg[list(f.q_index)], "q_goal")
    scene = FingerScene(hand, obj, qs, finger, touch_tol_m)
    return _plan_move(
        scene, a, b, planner=planner, max_checks=max_checks, seed=seed,
        clearance_m=clearance_m, resolution_rad=resolution_rad, verbose=verbose,
    )



def plan_gait_step(
    hand,
    obj,
    q_contact_a,
    q_contact_b,
    finger: str,
    n_a_palm=None,
    n_b_palm=None,
    *,
    q_others=None,
    planner: str = "rrtconnect",
    max_checks: int = MOTION_CHECKS,
    seed: int = 0,
    clearance_m: float = DEFAULT_CLEARANCE_M,
    touch_tol_m: float = DEFAULT_TOUCH_TOL_M,
    lift_m: float = DEFAULT_LIFT_M,
    resolution_rad: float = 0.01,
    verbose: bool = False,
    failed_moves: dict | None = None,
) -> dict:
    """Paths of one gait step of ``finger``: lift off contact A, move, land on contact B.

    Lift: the contact point backs off ``lift_m`` along the outward normal (damped
    least-squares steps of the contact Jacobian) until the finger clears the object by
    ``clearance_m``; it may touch the object (within ``touch_tol_m``) only at the
    contact end. Move: :func:`plan_finger_move` from the lifted to the approach
    configuration, with clearance. Land: the time reverse of a lift from contact B, so
    the finger approaches along B's normal and closes exactly onto ``q_contact_b`` (the
    contact found by the closing procedure, thesis eqs. (8)-(9), when the grasp was
    realized). A finger without contact A starts lifted at its open posture (no lift); a
    finger without contact B ends lifted at its open posture (no land).

    Args:
        hand: a ``planner.hand.Hand``.
        obj: a ``planner.objects.GraspObject``.
        q_contact_a: hand configuration (nq,) with the finger on contact A, or None.
        q_contact_b: hand configuration (nq,) with the finger on contact B, or None
            (only the finger's joints are read).
        finger: name of the moving finger.
        n_a_palm, n_b_palm: inward contact normals (3,) in the palm frame; by default the
            object's surface normal at the point nearest to the finger.
        q_others: configuration (nq,) of the other fingers; default ``q_contact_a``,
            else ``q_contact_b``.
        planner, max_checks, seed, clearance_m, touch_tol_m, resolution_rad, verbose:
            as in :func:`plan_finger_move` (``max_checks`` bounds the move).
        lift_m: retreat along the normal in metres.
        failed_moves: a memo of moves not found, shared by the gaits of one plan (None: none).
            A move (lifted to approach posture) not found among the other fingers is planned
            once more between the same two postures as if the hand had no other finger
            (`planner.finger_scene.FingerScene` ``others=False``: every configuration valid
            with them is valid without them); not found there either, the pair of postures is
            remembered and a later gait between them, whatever the other fingers' contacts,
            fails at once with that reason. A heuristic of a bounded planner (not found
            within ``max_checks``; RRT samples at random), not a proof that no path exists;
            it spares re-planning a path the object and palm block, state after state.

    Returns:
        dict with ``lift``, ``move``, ``land``: (m, n_finger_joints) paths in
        ``hand.fingers[finger].joints`` order (a step that does not apply is absent:
        no ``lift`` without contact A, no ``land`` without contact B); each path starts
        where the previous one ends. ``q_lifted`` and ``q_approach``:
        full hand configurations (nq,) after the lift and before the land; ``joints``:
        the finger's joint names.

    Raises:
        UnknownNameError: unknown planner or finger.
        InputError: bad shapes or values, or both contacts None.
        MotionError: the finger cannot lift, land or move within the budget.
    """
    _planner_class_name(planner)
    f = finger_of(hand, finger)
    check_positive(max_checks=max_checks, clearance_m=clearance_m, resolution_rad=resolution_rad, lift_m=lift_m)
    max_checks = _as_checks(max_checks)
    if not (np.isfinite(touch_tol_m) and touch_tol_m >= 0):
        raise InputError(f"touch_tol_m must be >= 0; got {touch_tol_m!r}")
    if q_contact_a is None and q_contact_b is None:
        raise InputError("plan_gait_step needs q_contact_a or q_contact_b (both are None)")
    idx = list(f.q_index)
    qa = None if q_contact_a is None else as_q(hand, q_contact_a, "q_contact_a")
    qb = None if q_contact_b is None else as_q(hand, q_contact_b, "q_contact_b")
    if q_others is not None:
        base = as_q(hand, q_others, "q_others")
    else:
        base = qa if qa is not None else qb
    q_open = np.asarray(hand.q_open, dtype=float)[idx]
    a = q_open.copy() if qa is None else check_limits(hand, f, qa[idx], "q_contact_a")
    b = q_open.copy() if qb is None else check_limits(hand, f, qb[idx], "q_contact_b")
    scene = FingerScene(hand, obj, base, finger, touch_tol_m)
    common = dict(lift_m=lift_m, clearance_m=clearance_m, resolution_rad=resolution_rad)

    lift = None if qa is None else retreat(scene, a, n_a_palm, what="lift off contact A", **common)
    land = None if qb is None else retreat(scene, b, n_b_palm, what="land on contact B", **common)[::-1].copy()
    start = a if lift is None else lift[-1]
    goal = b if land is None else land[0]
    params = dict(planner=planner, max_checks=max_checks, seed=seed, clearance_m=clearance_m,
                  resolution_rad=resolution_rad, verbose=verbose)
    # the object by its pose and identity (the memo holds it: its id is not reused meanwhile)
    key = None if failed_moves is None else (finger, start.tobytes(), goal.tobytes(), id(obj),
                                             np.asarray(obj.T_palm_obj, dtype=float).tobytes())
    if key is not None and failed_moves.get(key) is not None:
        raise MotionError(failed_moves[key][0])
    try:
        move = _plan_move(scene, start, goal, **params)
    except MotionError:
        if key is None or key in failed_moves:  # (found alone before: the other fingers are in the way)
            raise
        try:
            _plan_move(FingerScene(hand, obj, base, finger, touch_tol_m, others=False), start, goal, **params)
        except MotionError as alone:
            failed_moves[key] = (f"{alone} (not found with no other finger in the way either: not tried again "
                                 f"between these postures)", obj)
            raise MotionError(failed_moves[key][0]) from None
        failed_moves[key] = None
        raise
    out = {"joints": tuple(f.joints)}
    if lift is not None:
        out["lift"] = lift
    out["move"] = move
    if land is not None:
        out["land"] = land
    out["q_lifted"] = scene.full_q(start)
    out["q_approach"] = scene.full_q(goal)
    return out
