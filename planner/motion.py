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
from collections.abc import Iterator, Mapping
from types import MappingProxyType

import numpy as np

from planner.contacts import TOUCH_TOL_M
from planner.errors import InputError, MotionError, UnknownNameError

DEFAULT_CLEARANCE_M = 0.002
"""Distance a moving finger keeps from the object outside the lift/land steps."""
DEFAULT_TOUCH_TOL_M = TOUCH_TOL_M
"""Finger-object penetration tolerated at a contact (the lift/land ends), as in contacts."""
DEFAULT_LIFT_M = 0.005
"""Retreat of the contact point along the outward normal in a lift (and approach in a land)."""
MAX_LIFT_M = 0.03
"""A lift gives up when the finger is not clear of the object after this retreat."""
_ROTATION_WEIGHT_M = 0.03
"""Rigid retreat: a link rotation error of 1 rad weighs as much as this translation error."""
_LIFT_LAG_M = 0.002
"""A retreat step whose contact point trails its target by more than this is stuck (it slides)."""
_REPEL_MARGIN_M = 0.003
"""`_retreat_repel` pushes away every link within the clearance plus this of the object."""

# name -> OMPL geometric planner class. Asymptotically optimal planners stop at their
# first solution (cost threshold +inf): the path is then shortened by PathSimplifier.
# PRM and PRM* grow their roadmap in a second thread, so their paths are not
# guaranteed to be reproducible from the seed; every other planner here is. FMT and BFMT are left out:
# they stop after a fixed number of samples whatever the time budget.
_PLANNER_CLASSES = {
    "rrtconnect": "RRTConnect",
    "rrt": "RRT",
    "rrtstar": "RRTstar",
    "informedrrtstar": "InformedRRTstar",
    "sorrtstar": "SORRTstar",
    "prm": "PRM",
    "prmstar": "PRMstar",
    "kpiece": "KPIECE1",
    "bkpiece": "BKPIECE1",
    "lbkpiece": "LBKPIECE1",
    "bitstar": "BITstar",
    "aorrtc": "AORRTC",
}


def _registered_planners() -> Mapping[str, str]:
    from ompl import geometric as og

    return MappingProxyType({k: v for k, v in _PLANNER_CLASSES.items() if hasattr(og, v)})


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
    from ompl import util as ou

    previous = ou.getLogLevel()
    ou.setLogLevel(ou.LOG_INFO if verbose else ou.LOG_NONE)
    try:
        yield
    finally:
        ou.setLogLevel(previous)


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
    timeout_s: float,
    seed: int,
    resolution_rad: float,
    verbose: bool,
) -> np.ndarray | None:
    """Plan in the box ``[lower, upper]`` of R^n; returns the simplified waypoints or None.

    Every OMPL object is local to this frame (see the module docstring), so the caller
    raises its error after they are gone.
    """
    from ompl import base as ob
    from ompl import geometric as og
    from ompl import util as ou

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
        si.setStateValidityChecker(lambda s: bool(is_valid(np.fromiter((s[i] for i in range(n)), float, n))))
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
            ob.timedPlannerTerminationCondition(float(timeout_s)),
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


# ---------------------------------------------------------------- collision scene


class _FingerScene:
    """One moving finger of a hand held at ``q_ref``: its paths' view of the collision layer.

    The queries are `planner.collision.HandState` queries on ``hand.state(q_ref)`` with the
    finger moved by `HandState.with_finger` (only its chain re-posed; the palm, the other
    fingers and the object keep their pose, and their side of the clearance check is built
    once). A configuration is valid (`HandState.clearance`) when every link of the finger
    is at least ``object_margin_m`` from the object (negative: tolerated penetration, a
    signed distance on a mesh object too, `planner.collision.signed_distance_geometry`) and
    does not penetrate the palm, the other fingers or the non-adjacent links of its own
    finger (touching is fine; the allowed pairs and the 1 um threshold of
    ``planner.contacts.collisions``).
    """

    def __init__(self, hand, obj, q_ref: np.ndarray, finger: str, touch_tol_m: float):
        self.hand = hand
        self.finger = hand.fingers[finger]
        self.idx = np.asarray(self.finger.q_index, dtype=int)
        self.q_ref = np.array(q_ref, dtype=float)
        self.touch_tol_m = float(touch_tol_m)
        self.obj = obj
        self._T_palm_obj = np.asarray(obj.T_palm_obj, dtype=float)
        self.moving_links = hand.collision.finger_links(finger)
        if not self.moving_links:
            raise MotionError(f"finger {finger!r} has no collision geometry")
        self.base = hand.state(self.q_ref)

    def state(self, q_finger: np.ndarray):
        """The hand with this finger at ``q_finger`` (`HandState.with_finger`)."""
        return self.base.with_finger(self.finger.name, q_finger)

    def full_q(self, q_finger: np.ndarray) -> np.ndarray:
        q = self.q_ref.copy()
        q[self.idx] = q_finger
        return q

    def link_poses(self, q_finger: np.ndarray) -> np.ndarray:
        """``T_palm_link`` of the moving links, (k, 4, 4)."""
        return self.state(q_finger).finger_link_poses(self.finger.name)

    # -- queries
    def is_valid(self, q_finger: np.ndarray, object_margin_m: float) -> bool:
        """True when the finger at ``q_finger`` respects the margins (see class doc)."""
        return self.state(q_finger).clearance(self.obj, self.finger.name, object_margin_m)

    def object_distances(self, q_finger: np.ndarray) -> list[tuple[float, str, np.ndarray, np.ndarray]]:
        """Signed distance of every moving geometry to the object (negative: penetration).

        Returns a list of ``(distance_m, link, p_link_palm (3,), p_object_palm (3,))``:
        the nearest points on the link and on the object, palm frame.
        """
        return self.state(q_finger).object_distances(self.obj, self.finger.name)

    def object_distance(self, q_finger: np.ndarray) -> tuple[float, str, np.ndarray, np.ndarray]:
        """The entry of :meth:`object_distances` nearest to the object."""
        return min(self.object_distances(q_finger), key=lambda r: r[0])

    def point_on_link(self, q_finger: np.ndarray, link: str, p_palm: np.ndarray) -> np.ndarray:
        """Palm-frame point ``p_palm`` expressed in the frame of ``link`` at ``q_finger``."""
        T = self.link_poses(q_finger)[self.moving_links.index(link)]
        return T[:3, :3].T @ (np.asarray(p_palm, dtype=float) - T[:3, 3])

    def explain(self, q_finger: np.ndarray, object_margin_m: float) -> str:
        """A short human-readable reason why ``q_finger`` is invalid."""
        reasons = self.state(q_finger).clearance_violations(self.obj, self.finger.name, object_margin_m)
        return "; ".join(reasons) or "no collision found"


# ------------------------------------------------------------------- path helpers


def _densify(waypoints: np.ndarray, resolution_rad: float) -> np.ndarray:
    """Insert points so no joint moves more than ``resolution_rad`` between rows."""
    waypoints = np.asarray(waypoints, dtype=float)
    rows = [waypoints[0]]
    for a, b in zip(waypoints[:-1], waypoints[1:]):
        steps = max(1, int(math.ceil(np.max(np.abs(b - a)) / resolution_rad - 1e-9)))
        t = np.arange(1, steps)[:, None] / steps
        rows.extend(a + t * (b - a))
        rows.append(b)  # waypoints exactly, not a + 1.0 * (b - a)
    return np.array(rows)


def _first_invalid(scene: _FingerScene, path: np.ndarray, margins) -> int | None:
    margins = np.broadcast_to(np.asarray(margins, dtype=float), (len(path),))
    for k, (q, m) in enumerate(zip(path, margins)):
        if not scene.is_valid(q, m):
            return k
    return None


def _as_q(hand, q, what: str) -> np.ndarray:
    nq = len(hand.joint_names)
    arr = np.array(q, dtype=float)
    if arr.shape != (nq,):
        raise InputError(f"{what} must have shape ({nq},) (hand joints {', '.join(hand.joint_names)}); got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{what} has non-finite values")
    return arr


def _finger(hand, finger: str):
    try:
        return hand.fingers[finger]
    except KeyError:
        raise UnknownNameError("finger", finger, hand.fingers) from None


def _check_limits(hand, finger, q_finger: np.ndarray, what: str) -> np.ndarray:
    idx = list(finger.q_index)
    lo = np.asarray(hand.lower, dtype=float)[idx]
    hi = np.asarray(hand.upper, dtype=float)[idx]
    tol = 1e-6
    bad = [(j, v) for j, v, a, b in zip(finger.joints, q_finger, lo, hi) if v < a - tol or v > b + tol]
    if bad:
        j, v = bad[0]
        raise InputError(f"{what}: joint {j} = {v:.4f} rad is outside its limits")
    return np.clip(q_finger, lo, hi)


def _check_positive(**values: float) -> None:
    for name, v in values.items():
        if not (np.isfinite(v) and v > 0):
            raise InputError(f"{name} must be positive and finite; got {v!r}")


# --------------------------------------------------------------- finger transfer


def _plan_move(
    scene: _FingerScene,
    a: np.ndarray,
    b: np.ndarray,
    *,
    planner: str,
    timeout_s: float,
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
    straight = _densify(np.array([a, b]), resolution_rad)
    if _first_invalid(scene, straight, clearance_m) is None:
        return straight
    lower = np.asarray(scene.hand.lower, dtype=float)[scene.idx]
    upper = np.asarray(scene.hand.upper, dtype=float)[scene.idx]
    waypoints = _solve_ompl(
        lambda q: scene.is_valid(q, clearance_m),
        a, b, lower, upper,
        planner=planner, timeout_s=timeout_s, seed=seed,
        resolution_rad=resolution_rad, verbose=verbose,
    )
    if waypoints is None:
        raise MotionError(
            f"finger {name}: {planner} found no collision-free path in {timeout_s:g} s "
            f"(clearance {clearance_m * 1000:.1f} mm)"
        )
    waypoints[0], waypoints[-1] = a, b
    path = _densify(waypoints, resolution_rad)
    bad = _first_invalid(scene, path, clearance_m)
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
    timeout_s: float = 1.0,
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
        timeout_s: planning budget in seconds.
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
        MotionError: start or goal in collision, or no path within ``timeout_s``.
    """
    _planner_class_name(planner)
    f = _finger(hand, finger)
    _check_positive(timeout_s=timeout_s, clearance_m=clearance_m, resolution_rad=resolution_rad)
    if not (np.isfinite(touch_tol_m) and touch_tol_m >= 0):
        raise InputError(f"touch_tol_m must be >= 0; got {touch_tol_m!r}")
    qs = _as_q(hand, q_start, "q_start")
    qg = _as_q(hand, q_goal, "q_goal")
    a = _check_limits(hand, f, qs[list(f.q_index)], "q_start")
    b = _check_limits(hand, f, qg[list(f.q_index)], "q_goal")
    scene = _FingerScene(hand, obj, qs, finger, touch_tol_m)
    return _plan_move(
        scene, a, b, planner=planner, timeout_s=timeout_s, seed=seed,
        clearance_m=clearance_m, resolution_rad=resolution_rad, verbose=verbose,
    )


# ------------------------------------------------------------------ lift and land


def _inward_normal(scene: _FingerScene, p_object_palm: np.ndarray) -> np.ndarray:
    """Inward contact normal (palm frame) at the object point nearest to the finger."""
    T_palm_obj = scene._T_palm_obj
    R = T_palm_obj[:3, :3]
    p_obj = R.T @ (p_object_palm - T_palm_obj[:3, 3])
    _, n_out_obj, _ = scene.obj.closest_surface(p_obj)
    n_in = -(R @ np.asarray(n_out_obj, dtype=float))
    return n_in / np.linalg.norm(n_in)


def _retreat_dls(
    scene: _FingerScene,
    a: np.ndarray,
    n_in: np.ndarray,
    link: str,
    p_link: np.ndarray,
    *,
    rotation_weight_m: float,
    touch_margin: float,
    lift_m: float,
    clearance_m: float,
    step_m: float,
    damping: float = 1e-3,
) -> list[np.ndarray] | None:
    """Damped least squares moving ``p_link`` (on ``link``) along ``-n_in``; None if stuck.

    ``rotation_weight_m`` > 0 also asks the link to keep its orientation (a rigid
    retreat, so no other point of the link swings into the object), weighted so that
    1 rad of rotation costs as much as that many metres of position error.
    """
    hand = scene.hand
    k_link = scene.moving_links.index(link)
    lo = np.asarray(hand.lower, dtype=float)[scene.idx]
    hi = np.asarray(hand.upper, dtype=float)[scene.idx]

    def point(q):
        T = scene.link_poses(q)[k_link]
        return T[:3, :3] @ p_link + T[:3, 3]

    p0 = point(a)
    rows = 6 if rotation_weight_m > 0 else 3
    W = np.array([1.0, 1.0, 1.0] + [rotation_weight_m] * 3)[:rows, None]
    path = [a.copy()]
    q = a.copy()
    s = 0.0
    while s < MAX_LIFT_M:
        s += step_m
        target = p0 - s * n_in
        for _ in range(3):
            J = np.asarray(hand.frame_jacobian(scene.full_q(q), link, p_link), dtype=float)[:rows][:, scene.idx]
            err = np.zeros(rows)
            err[:3] = target - point(q)  # orientation target: no rotation (zero rows)
            Jw = W * J
            ew = W[:, 0] * err
            dq = np.linalg.solve(Jw.T @ Jw + damping**2 * np.eye(len(q)), Jw.T @ ew)
            q = np.clip(q + dq, lo, hi)
        if float(np.dot(p0 - point(q), n_in)) < s - _LIFT_LAG_M or not scene.is_valid(q, touch_margin):
            return None
        path.append(q.copy())
        if s >= lift_m - 1e-12 and scene.is_valid(q, clearance_m):
            return path
    return None


def _retreat_repel(
    scene: _FingerScene,
    a: np.ndarray,
    contact_link: str,
    *,
    touch_margin: float,
    lift_m: float,
    clearance_m: float,
    step_m: float,
    damping: float = 1e-3,
) -> list[np.ndarray] | None:
    """Push every link near the object away along its own surface normal; None if stuck.

    For a finger wrapped around an edge, backing off the contact point alone drags
    another phalanx along the object. Here each link within ``clearance_m + _REPEL_MARGIN_M`` (and
    the contact link) asks its nearest point to gain ``step_m`` of distance per step:
    one row ``n_out . J_point`` each, solved by damped least squares. Ends when the
    contact link is ``lift_m`` and every link ``clearance_m`` away from the object.
    """
    hand = scene.hand
    lo = np.asarray(hand.lower, dtype=float)[scene.idx]
    hi = np.asarray(hand.upper, dtype=float)[scene.idx]
    path = [a.copy()]
    q = a.copy()
    best, since_best = -math.inf, 0
    for _ in range(int(MAX_LIFT_M / step_m)):
        rows = []
        for d, link, p_link_palm, p_object_palm in scene.object_distances(q):
            if d >= clearance_m + _REPEL_MARGIN_M and link != contact_link:
                continue
            n_out = -_inward_normal(scene, p_object_palm)
            p_link = scene.point_on_link(q, link, p_link_palm)
            J = np.asarray(hand.frame_jacobian(scene.full_q(q), link, p_link), dtype=float)[:3][:, scene.idx]
            rows.append(n_out @ J)
        A = np.array(rows)
        dq = A.T @ np.linalg.solve(A @ A.T + damping**2 * np.eye(len(A)), np.full(len(A), step_m))
        q = np.clip(q + dq, lo, hi)
        if not scene.is_valid(q, touch_margin):
            return None
        path.append(q.copy())
        distances = {}
        for d, link, _, _ in scene.object_distances(q):
            distances[link] = min(d, distances.get(link, math.inf))
        if distances[contact_link] >= lift_m and min(distances.values()) >= clearance_m:
            return path
        progress = min(distances.values())
        if progress > best + 1e-5:
            best, since_best = progress, 0
        else:
            since_best += 1
            if since_best >= 5:  # joint limits: no link gets farther any more
                return None
    return None


def _retreat(
    scene: _FingerScene,
    a: np.ndarray,
    n_in_palm,
    *,
    lift_m: float,
    clearance_m: float,
    resolution_rad: float,
    what: str,
    step_m: float = 0.0005,
) -> np.ndarray:
    """Path from the contact configuration ``a`` backing off along the outward normal.

    The contact point is the point of the finger nearest to the object, fixed on its
    link. Damped least-squares steps of its Jacobian move it along ``-n_in_palm`` by
    ``step_m`` at a time until it has retreated ``lift_m`` and the whole finger keeps
    ``clearance_m`` from the object (at most ``MAX_LIFT_M``); first keeping the link's
    orientation (a rigid retreat), then, if that is stuck, the point only. If another
    phalanx stays against the object, every link near it is pushed away along its own
    normal (:func:`_retreat_repel`); last, the finger opens toward its open posture.
    Every state may touch the object no deeper than the contact itself or
    ``touch_tol_m``. Returns (m, n_finger_joints), first row ``a``.
    """
    hand = scene.hand
    name = scene.finger.name
    d0, link, p_palm, p_object_palm = scene.object_distance(a)
    n_in = _inward_normal(scene, p_object_palm) if n_in_palm is None else np.asarray(n_in_palm, float)
    norm = np.linalg.norm(n_in)
    if n_in.shape != (3,) or not np.isfinite(norm) or norm < 1e-9:
        raise InputError(f"contact normal of finger {name} must be a non-zero 3-vector; got {n_in_palm!r}")
    n_in = n_in / norm
    touch_margin = min(-scene.touch_tol_m, d0 - 1e-6)  # never deeper than the contact
    p_link = scene.point_on_link(a, link, p_palm)
    for rotation_weight_m in (_ROTATION_WEIGHT_M, 0.0):
        path = _retreat_dls(
            scene, a, n_in, link, p_link, rotation_weight_m=rotation_weight_m,
            touch_margin=touch_margin, lift_m=lift_m, clearance_m=clearance_m, step_m=step_m,
        )
        if path is not None:
            return _densify(np.array(path), resolution_rad)
    path = _retreat_repel(
        scene, a, link, touch_margin=touch_margin, lift_m=lift_m, clearance_m=clearance_m, step_m=step_m,
    )
    if path is not None:
        return _densify(np.array(path), resolution_rad)

    # Fallback: open the finger along a joint-space line, first only the closing
    # (flexion) joints, keeping abduction/opposition, then toward the whole open posture.
    lo = np.asarray(hand.lower, dtype=float)[scene.idx]
    hi = np.asarray(hand.upper, dtype=float)[scene.idx]
    q_open = np.clip(np.asarray(hand.q_open, dtype=float)[scene.idx], lo, hi)
    closing = np.isin(np.asarray(scene.finger.joints), np.asarray(scene.finger.close_joints or scene.finger.joints))
    for target in (np.where(closing, q_open, a), q_open):
        line = _densify(np.array([a, target]), resolution_rad)
        for k, q in enumerate(line[1:], start=1):
            if not scene.is_valid(q, touch_margin):
                break
            distances = scene.object_distances(q)
            lifted = min(d for d, l, _, _ in distances if l == link) >= lift_m
            if lifted and min(d for d, *_ in distances) >= clearance_m and scene.is_valid(q, clearance_m):
                return line[: k + 1]
    raise MotionError(
        f"finger {name}: cannot {what} (contact on {link}): neither a {lift_m * 1000:.1f} mm "
        f"retreat along the contact normal nor opening the finger is free"
    )


def retreat_blocked(
    hand,
    obj,
    q_finger,
    finger: str,
    *,
    clearance_m: float = DEFAULT_CLEARANCE_M,
    touch_tol_m: float = DEFAULT_TOUCH_TOL_M,
    lift_m: float = DEFAULT_LIFT_M,
    resolution_rad: float = 0.01,
) -> str | None:
    """Why a finger cannot back off a contact whatever the other fingers do, or None.

    The lift of `plan_gait_step` (`_retreat`, the same margins) from the finger's contact
    configuration ``q_finger`` with every other finger at its open posture: a contact whose
    finger is held against the object by its own joint limits (a thumb pressed sideways at
    full opposition) cannot be left, nor landed on (a landing is a lift reversed), in any
    state. Returns the reason, naming the finger, the link and the joints at a limit.
    """
    f = _finger(hand, finger)
    q_ref = np.array(hand.q_open, dtype=float)
    q_ref[list(f.q_index)] = q_finger
    scene = _FingerScene(hand, obj, q_ref, finger, touch_tol_m)
    a = np.asarray(q_finger, dtype=float)
    try:
        _retreat(scene, a, None, lift_m=lift_m, clearance_m=clearance_m, resolution_rad=resolution_rad,
                 what="back off this contact")
    except MotionError as err:
        lo = np.asarray(hand.lower, dtype=float)[scene.idx]
        hi = np.asarray(hand.upper, dtype=float)[scene.idx]
        tol = max(resolution_rad, 0.05 * float(np.max(hi - lo)))
        at = [f"{j} {a[k]:.2f} rad (limit {lo[k] if a[k] - lo[k] < hi[k] - a[k] else hi[k]:.2f})"
              for k, j in enumerate(f.joints) if min(a[k] - lo[k], hi[k] - a[k]) <= tol]
        return (f"{err}, even with every other finger open" + (f"; near their limits: {', '.join(at)}" if at else ""))
    return None


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
    timeout_s: float = 1.0,
    seed: int = 0,
    clearance_m: float = DEFAULT_CLEARANCE_M,
    touch_tol_m: float = DEFAULT_TOUCH_TOL_M,
    lift_m: float = DEFAULT_LIFT_M,
    resolution_rad: float = 0.01,
    verbose: bool = False,
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
        planner, timeout_s, seed, clearance_m, touch_tol_m, resolution_rad, verbose:
            as in :func:`plan_finger_move` (``timeout_s`` bounds the move).
        lift_m: retreat along the normal in metres.

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
    f = _finger(hand, finger)
    _check_positive(timeout_s=timeout_s, clearance_m=clearance_m, resolution_rad=resolution_rad, lift_m=lift_m)
    if not (np.isfinite(touch_tol_m) and touch_tol_m >= 0):
        raise InputError(f"touch_tol_m must be >= 0; got {touch_tol_m!r}")
    if q_contact_a is None and q_contact_b is None:
        raise InputError("plan_gait_step needs q_contact_a or q_contact_b (both are None)")
    idx = list(f.q_index)
    qa = None if q_contact_a is None else _as_q(hand, q_contact_a, "q_contact_a")
    qb = None if q_contact_b is None else _as_q(hand, q_contact_b, "q_contact_b")
    if q_others is not None:
        base = _as_q(hand, q_others, "q_others")
    else:
        base = qa if qa is not None else qb
    q_open = np.asarray(hand.q_open, dtype=float)[idx]
    a = q_open.copy() if qa is None else _check_limits(hand, f, qa[idx], "q_contact_a")
    b = q_open.copy() if qb is None else _check_limits(hand, f, qb[idx], "q_contact_b")
    scene = _FingerScene(hand, obj, base, finger, touch_tol_m)
    common = dict(lift_m=lift_m, clearance_m=clearance_m, resolution_rad=resolution_rad)

    lift = None if qa is None else _retreat(scene, a, n_a_palm, what="lift off contact A", **common)
    land = None if qb is None else _retreat(scene, b, n_b_palm, what="land on contact B", **common)[::-1].copy()
    start = a if lift is None else lift[-1]
    goal = b if land is None else land[0]
    move = _plan_move(
        scene, start, goal, planner=planner, timeout_s=timeout_s, seed=seed,
        clearance_m=clearance_m, resolution_rad=resolution_rad, verbose=verbose,
    )
    out = {"joints": tuple(f.joints)}
    if lift is not None:
        out["lift"] = lift
    out["move"] = move
    if land is not None:
        out["land"] = land
    out["q_lifted"] = scene.full_q(start)
    out["q_approach"] = scene.full_q(goal)
    return out
