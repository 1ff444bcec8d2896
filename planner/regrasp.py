"""The regrasp pipeline: two realized grasps in, a finger-gaiting `Plan` out.

1. Contact slots per finger: its initial and final contacts and, on request
   (``intermediate`` N), N intermediate contacts from the finger's reachable contacts
   (`reachable_contacts`: in-limit postures closed onto the object, cached per hand and
   object).
2. `planner.graph.LazyGraph` (ranked best-first search evaluating only the states it
   reaches; or the greedy baseline) over those slots, with finger-finger collisions
   checked pairwise with coal. Anytime (``intermediate`` 0, ``time_limit_s`` > 0): when no
   sequence exists, rounds of intermediate contacts for the fingers that block progress
   (`planner.graph.failure_analysis`) and a new search, until found or out of time.
3. Finger paths, lazily: only for the gait steps of candidate sequences, best-ranked
   first; a step whose path cannot be planned removes its edge and the search goes on.
4. The winning sequence expanded into plan states and lift / move / land steps.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import asdict, dataclass, replace
from typing import Any, Callable, Mapping

import networkx as nx
import numpy as np

from planner.closure import CONTACT_MODELS, GRIP_CONE_SIDES, apply_contact_model
from planner.grip import FRICTION_MARGIN, HOLD_FACTOR, finger_statics
from planner.errors import InputError, MotionError, NoSequenceError, PlannerError, SpecError, UnknownNameError
from planner.graph import (LIFTED, RANKS, GaitProblem, GaitSequence, LazyGraph, Slot, annotate_removable, explain_failure,
                           failure_analysis, greedy, seed_graph)
from planner.plan import Alternative, Plan, PlanState, PlanStep

STRATEGIES = ("graph", "greedy")
#: Friction fraction execution-mode plans must hold their load with: the grip model's
#: (`planner.grip.FRICTION_MARGIN`), which the replay controller uses too. Measured on exp7
#: (43 pairs, with the 1 N budget of before): 1.0 plans 33 pairs, 26 hold in all 7 gravity
#: directions; 0.75 plans 24, 22 hold; 0.5 plans 17, 17 hold.
EXECUTION_FRICTION_MARGIN = FRICTION_MARGIN


#: Ranges of the numeric planner options, checked by `PlanOptions` and, under their
#: command-line names (`PLAN_OPTION_FLAGS`), by the CLI (``planner.cli``): each bounds a loop
#: or a size (alternatives: ranked sequences; intermediate: contacts per finger, the graph
#: grows about quadratically with it). field -> (low, high, low is exclusive); a field with
#: several values (gravity) bounds each.
PLAN_OPTION_LIMITS = {
    "seed": (0, 2**32 - 1, False),
    "alternatives": (1, 100, False),
    "intermediate": (0, 8, False),
    "max_lifted": (1, 16, False),
    "verify_attempts": (1, 100, False),
    "max_rounds": (0, 1000, False),
    "workers": (1, 256, False),
    "motion_timeout_s": (0.0, 600.0, True),
    "time_limit_s": (0.0, 3600.0, False),
    "max_finger_force_n": (0.0, 1000.0, True),
    "hold_factor": (0.0, 100.0, True),
    "gravity": (-1000.0, 1000.0, False),
}
#: `regrasp plan` option of each `PLAN_OPTION_LIMITS` field named differently (``--time-limit``).
PLAN_OPTION_FLAGS = {"motion_timeout_s": "motion_timeout", "time_limit_s": "time_limit", "max_finger_force_n": "max_finger_force"}


def option_range(low, high, open_low: bool) -> str:
    """'[low, high]' or '(low, high]'."""
    return f"{'(' if open_low else '['}{low}, {high}]"


def in_range(value, low, high, open_low: bool) -> bool:
    """A real number (an integer when ``low`` is one; never a bool) within the range."""
    import numbers

    if isinstance(value, bool) or not isinstance(value, numbers.Integral if isinstance(low, int) else numbers.Real):
        return False
    return math.isfinite(value) and (low < value if open_low else low <= value) and value <= high


@dataclass(frozen=True)
class PlanOptions:
    """Planner parameters (all written to the plan's ``parameters``).

    Attributes:
        strategy: "graph" (ranked search) or "greedy" (thesis Algorithm 2).
        alternatives: number of ranked sequences to return (graph strategy).
        intermediate: intermediate contacts per finger, fixed (0: none, or added in rounds
            when needed: see ``time_limit_s``).
        seed: seed for motion planning (intermediate contacts come from a fixed per-finger
            pool, `reachable_contacts`).
        motion: plan finger paths with OMPL (False: straight joint-space segments).
        motion_planner: OMPL planner name (see planner.motion).
        motion_timeout_s: time budget per finger path.
        max_lifted: at most this many fingers lifted at once (None = no bound).
        same_slot_tol_rad: initial and final contacts closer than this (max joint
            difference) are one slot: the finger does not move.
        contact_model: "patch" (every patch point has a friction cone, as in the thesis)
            or "mean" (one contact per finger at the patch mean: what a rigid fingertip
            gives in the simulator; `planner.closure.CONTACT_MODELS`). Every state's
            closure, removability and exported patches use it.
        gravity: None (default: force closure only, as in the thesis) or the gravity
            vector in the palm frame, m/s^2, e.g. (0, 0, 9.81) with the palm facing down.
            Every state must then hold ``hold_factor`` times the object's weight within the
            hand's joint torque limits (`planner.grip.hold_capacity`: contact forces in the
            friction cones scaled by ``friction_margin``, ``|g(q) + J^T f| <= tau_max`` at
            every joint of the touching fingers, weight at the object origin).
        friction_margin: the grip forces against gravity are computed with ``mu`` and
            ``gamma`` scaled by this (0 < margin <= 1); execution mode uses
            ``EXECUTION_FRICTION_MARGIN``: a plan for execution must hold its load with a
            friction reserve, as the replay's controller does.
        max_finger_force_n: optional extra cap on every finger's normal force against
            gravity, N (default None: the joints' torque limits alone bound the grip).
        hold_factor: the multiple of the weight every state must hold (default
            `planner.grip.HOLD_FACTOR`, the replay controller's squeeze safety factor).
        verify: replay the best sequence in pybullet under every planned-for gravity
            direction before returning it (`planner.sim.verify`, directions in parallel
            processes); the transition that failed first is removed and the search goes on
            (execution mode's default; needs ``gravity`` or ``gravity_set``).
        verify_attempts: sequences replayed at most before giving up (a bound on the work,
            not on the time, so the plan does not depend on the machine's load).
        workers: processes for the verification replays (None: the cores available). The
            plan is the same for any number (not written to its parameters).
        gravity_set: None or a set size of `planner.gravity.GRAVITY_SET_SIZES` (1, 2, 6, 7):
            plan for several hand orientations at once, the named gravity directions of
            `planner.gravity.gravity_directions` (from the hand's ``palm_normal``). A state
            must then hold the weight in each of them. Exclusive with ``gravity``.
        rank: how sequences are ranked (`planner.graph.RANKS`): "metric" (the thesis:
            largest worst-case closure metric first) or "grip" (smallest largest grip force
            along the sequence first, then fewest gait steps, then the metric ranking;
            needs ``gravity`` or ``gravity_set``).
        execution: label of plans meant to be executed (`PlanOptions.for_execution`): it
            requires the "mean" contact model, the "grip" ranking and a gravity.
        max_rounds: with ``intermediate`` 0 the planner is anytime: when no sequence exists
            with the current contacts, it adds intermediate contacts
            (`INTERMEDIATE_PER_ROUND` per finger that blocks progress, from
            `reachable_contacts`) and searches again, round after round, until a sequence
            is found, no contact is left to add or ``max_rounds`` rounds were made. The
            rounds are deterministic and bounded by this count (and each search by its
            expanded states), not by the clock: the plan, or the explanation of a failure,
            is the same on a loaded machine. 0 disables the rounds.
        time_limit_s: a cap on the search time (graph strategy), s (0: no rounds). Reaching
            it is reported (the result then depends on the machine's speed); the work
            bounds normally end the search first. Finger paths are not counted.
    """

    strategy: str = "graph"
    alternatives: int = 4
    intermediate: int = 0
    seed: int = 0
    motion: bool = True
    motion_planner: str = "rrtconnect"
    motion_timeout_s: float = 2.0
    max_lifted: int | None = None
    same_slot_tol_rad: float = 1e-3
    contact_model: str = "patch"
    gravity: tuple[float, float, float] | None = None
    max_finger_force_n: float | None = None
    friction_margin: float = 1.0
    gravity_set: int | None = None
    rank: str = "metric"
    execution: bool = False
    time_limit_s: float = 60.0
    max_rounds: int = 4
    hold_factor: float = HOLD_FACTOR
    verify: bool = False
    verify_attempts: int = 6
    workers: int | None = None

    @classmethod
    def for_execution(cls, **overrides) -> "PlanOptions":
        """Options for a plan that is to be executed: one mean contact per finger (what rigid
        fingertips give), gravity set 6 (palm down, palm up and the four sideways
        directions) unless ``gravity`` or ``gravity_set`` is given, grip ranking."""
        kw = dict(contact_model="mean", rank="grip", execution=True, friction_margin=EXECUTION_FRICTION_MARGIN,
                  verify=True)
        if overrides.get("gravity") is None and overrides.get("gravity_set") is None:
            kw["gravity_set"] = 6
        kw.update({k: v for k, v in overrides.items() if v is not None or k not in kw})
        return cls(**kw)

    def __post_init__(self):
        if self.gravity is not None:
            try:
                g = tuple(self.gravity)
            except TypeError:
                raise PlannerError(f"gravity must be 3 numbers (palm frame, m/s^2), got {self.gravity!r}") from None
            if len(g) != 3:
                raise PlannerError(f"gravity must be 3 numbers (palm frame, m/s^2), got {self.gravity!r}")
            object.__setattr__(self, "gravity", g)  # as floats once their range is checked, below
        if not (isinstance(self.friction_margin, (int, float)) and 0 < self.friction_margin <= 1):
            raise PlannerError(f"friction_margin must be in (0, 1], got {self.friction_margin!r}")
        if self.gravity_set is not None:
            from planner.gravity import GRAVITY_SET_SIZES

            if self.gravity is not None:
                raise PlannerError("give either a gravity vector or a gravity set, not both")
            if isinstance(self.gravity_set, bool) or self.gravity_set not in GRAVITY_SET_SIZES:
                raise PlannerError(f"gravity set size must be one of {', '.join(map(str, GRAVITY_SET_SIZES))}, "
                                   f"got {self.gravity_set!r}")
        if self.rank not in RANKS:
            raise UnknownNameError("rank", self.rank, RANKS)
        if self.rank == "grip" and self.gravity is None and self.gravity_set is None:
            raise PlannerError("grip ranking needs a gravity: give --gravity GX GY GZ or --gravity-set N "
                               "(PlanOptions gravity or gravity_set)")
        if self.execution and (self.contact_model != "mean" or self.rank != "grip"):
            raise PlannerError(f"execution mode plans with the 'mean' contact model and grip ranking, got contact "
                               f"model {self.contact_model!r} and rank {self.rank!r}")
        if self.strategy not in STRATEGIES:
            raise UnknownNameError("strategy", self.strategy, STRATEGIES)
        if self.contact_model not in CONTACT_MODELS:
            raise UnknownNameError("contact model", self.contact_model, CONTACT_MODELS)
        for name, (low, high, open_low) in PLAN_OPTION_LIMITS.items():
            value = getattr(self, name)
            optional = value is None and name in ("max_lifted", "gravity", "max_finger_force_n", "workers")
            for v in () if optional else value if isinstance(value, tuple) else (value,):
                if not in_range(v, low, high, open_low):
                    kind = "an integer" if isinstance(low, int) else "a number"
                    raise InputError(f"PlanOptions.{name} must be {kind} in {option_range(low, high, open_low)}, got {v!r}")
        if self.gravity is not None:
            object.__setattr__(self, "gravity", tuple(float(v) for v in self.gravity))


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


#: Progress of a long plan (search rounds, finger paths, verification replays): `logging`
#: INFO records; the CLI shows them on a terminal (``-q`` hides them).
log = logging.getLogger("planner")


def check_same_setup(initial, final) -> None:
    """Refuse two grasps that do not share hand, object, object pose and friction.

    Args:
        initial, final: `planner.grasp.GraspSpec` of the two grasps.
    """
    a, b = initial, final
    checks = [
        ("hand", a.hand_ref, b.hand_ref),
        ("object.shape", a.object.shape, b.object.shape),
        ("object.size", a.object.size, b.object.size),
        ("object.mesh", a.object.mesh_path, b.object.mesh_path),
        ("object.position", a.object.position, b.object.position),
        ("object.quat_xyzw", a.object.quat_xyzw, b.object.quat_xyzw),
        ("object.mass_kg", a.object.mass_kg, b.object.mass_kg),  # None (volume x density) differs from a number
        ("friction", (a.friction.mu, a.friction.gamma, a.friction.edges), (b.friction.mu, b.friction.gamma, b.friction.edges)),
    ]
    for key, va, vb in checks:
        same = va == vb if isinstance(va, str) or va is None else np.allclose(np.asarray(va, float), np.asarray(vb, float), atol=1e-9)
        if not same:
            raise SpecError(b.path, key, f"differs from the initial grasp ({a.path}): {va} vs {vb}; both grasps must share hand, object, object pose and friction")


# ------------------------------------------------------------------ slots


def _finger_q(hand, finger: str, q: np.ndarray) -> np.ndarray:
    return np.asarray(q, float)[list(hand.fingers[finger].q_index)]


#: Random in-limit postures per finger from which contact candidates are drawn.
POOL_POSTURES = 4000
#: Candidates closed onto the object per finger (spread over the reachable surface).
POOL_SIZE = 32
#: Seed of the postures (the pool is one per hand, object and finger, whatever the plan's seed).
POOL_SEED = 15
#: A posture is a candidate when its pad is this far outside the surface at most...
POOL_STANDOFF_M = 0.012
#: ... and its pad faces the surface: cosine of the pad normal with the inward normal.
POOL_FACING_COS = 0.3
#: Surface samples the pad distances are measured against.
POOL_SURFACE_SAMPLES = 6000
#: Intermediate contacts of one finger lie at least this far from its other contacts.
MIN_SLOT_SPACING_M = 0.01
#: ... unless their mean normals differ by this much at least (`_near`).
MIN_SLOT_ANGLE_DEG = 10.0
#: Local candidates (`local_contacts`): postures facing the surface at most this far from
#: one of the finger's own contacts...
LOCAL_RADIUS_M = 0.025
#: ... this many of them, spread, closed onto the object.
LOCAL_SIZE = 6

_POOLS: dict[tuple, tuple] = {}


def _object_key(obj) -> tuple:
    return (obj.shape, tuple(np.round(obj.size, 9)), np.asarray(obj.T_palm_obj).round(9).tobytes(), obj.mesh_path)


def _pool_postures(hand, obj, finger: str) -> tuple[np.ndarray, np.ndarray]:
    """The finger's in-limit postures whose pad faces the surface from just outside it:
    (postures (m, n_joints), the surface points they face (m, 3), object frame), from
    ``POOL_POSTURES`` seeded random postures (forward kinematics only; distances from a
    ``POOL_SURFACE_SAMPLES`` surface sample). Cached per hand, object (with pose) and finger."""
    key = (str(hand.spec_path), hand.name, _object_key(obj), finger, "postures")
    if key in _POOLS:
        return _POOLS[key]
    f = hand.fingers[finger]
    idx = list(f.q_index)
    lo, hi = np.asarray(hand.lower, float)[idx], np.asarray(hand.upper, float)[idx]
    rng = np.random.default_rng([POOL_SEED, list(hand.fingers).index(finger)])
    postures = rng.uniform(lo, hi, size=(POOL_POSTURES, len(idx)))
    T = np.asarray(obj.T_palm_obj, float)
    p_link = np.append(np.asarray(f.pad_p_link, float), 1.0)
    n_link = np.asarray(f.pad_n_link, float)
    q = np.array(hand.q_open, dtype=float)
    pads = np.empty((len(postures), 4, 4))
    for k, qf in enumerate(postures):  # forward kinematics of every posture
        q[idx] = qf
        pads[k] = hand.link_pose(q, f.pad_link)
    p_obj = (pads[:, :3, :] @ p_link - T[:3, 3]) @ T[:3, :3]
    n_obj = (pads[:, :3, :3] @ n_link) @ T[:3, :3]
    # distance to the surface from a dense sample of it (the nearest sample's tangent
    # plane): vectorized, for every shape; the closing procedure makes the exact contact
    from scipy.spatial import cKDTree

    cloud, cloud_n = obj.sample_surface(POOL_SURFACE_SAMPLES, np.random.default_rng(0))
    _, nearest = cKDTree(cloud).query(p_obj)
    d = np.einsum("ij,ij->i", p_obj - cloud[nearest], cloud_n[nearest])
    facing = -np.einsum("ij,ij->i", n_obj, cloud_n[nearest])
    kept = np.flatnonzero((d >= 0.0) & (d <= POOL_STANDOFF_M) & (facing >= POOL_FACING_COS))
    surf = p_obj[kept] - d[kept, None] * cloud_n[nearest[kept]]
    _POOLS[key] = (postures[kept], surf)
    return _POOLS[key]


def _closed_contacts(hand, obj, finger: str, postures) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Each posture closed onto the object (`Hand.close_finger`), kept when the finger
    touches and neither penetrates the object nor hits the palm or its own links:
    (points, inward normals, the finger's joint values) per contact, in order."""
    from planner.contacts import collisions, contact_patches

    f = hand.fingers[finger]
    idx = list(f.q_index)
    out = []
    for qf in postures:
        q = np.array(hand.q_open, dtype=float)
        q[idx] = qf
        q = np.asarray(hand.close_finger(f, q, obj), dtype=float)
        patch = contact_patches(hand, q, obj, fingers=[finger]).get(finger)
        if patch is None or len(patch[0]) == 0 or collisions(hand, q, obj, fingers=(finger,)):
            continue
        out.append((np.asarray(patch[0]), np.asarray(patch[1]), q[idx]))
    return out


def reachable_contacts(hand, obj, finger: str) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray], ...]:
    """Contacts one finger can make on the object, reachable by construction.

    ``POOL_POSTURES`` seeded random postures of the finger (in its joint limits, the other
    fingers open) give its pad's reachable workspace; those whose pad lies within
    ``POOL_STANDOFF_M`` outside the surface and faces it are candidates (`_pool_postures`).
    ``POOL_SIZE`` of them, spread over the surface by farthest-point sampling of their
    closest surface points, are closed onto the object with the thesis's closing procedure
    (`Hand.close_finger`); a closed finger that touches and neither penetrates the object
    nor hits the palm or its own links is a contact. No IK is needed: every posture is
    inside the joint limits. Computed once per hand, object (with pose) and finger, then
    cached; deterministic.

    Returns:
        (points (n, 3), inward normals (n, 3), the finger's joint values) per contact, in
        farthest-point order.
    """
    key = (str(hand.spec_path), hand.name, _object_key(obj), finger)
    if key not in _POOLS:
        postures, surf = _pool_postures(hand, obj, finger)
        _POOLS[key] = tuple(_closed_contacts(hand, obj, finger, postures[_farthest_points(surf, POOL_SIZE)]))
    return _POOLS[key]


def local_contacts(hand, obj, finger: str, anchor: np.ndarray) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray], ...]:
    """Contacts of one finger a short step from one of its own contacts (``anchor``, its
    patch points): the postures of `_pool_postures` facing the surface between
    ``MIN_SLOT_SPACING_M`` and ``LOCAL_RADIUS_M`` from the anchor, ``LOCAL_SIZE`` of them
    spread by farthest-point sampling from the nearest, closed onto the object like
    `reachable_contacts`. The spread pool covers the whole reachable surface coarsely; these
    are the small steps a finger makes to let another one go (what sampling near the
    current contacts found before the pool). Cached per hand, object, finger and anchor."""
    anchor = np.asarray(anchor, float).reshape(-1, 3)
    key = (str(hand.spec_path), hand.name, _object_key(obj), finger, anchor.round(6).tobytes())
    if key not in _POOLS:
        postures, surf = _pool_postures(hand, obj, finger)
        d = np.min(np.linalg.norm(surf[:, None, :] - anchor[None, :, :], axis=2), axis=1) if len(surf) else np.zeros(0)
        ring = np.flatnonzero((d >= MIN_SLOT_SPACING_M) & (d <= LOCAL_RADIUS_M))
        ring = ring[np.argsort(d[ring], kind="stable")]
        chosen = ring[_farthest_points(surf[ring], LOCAL_SIZE)]
        _POOLS[key] = tuple(_closed_contacts(hand, obj, finger, postures[chosen]))
    return _POOLS[key]


def _farthest_points(points: np.ndarray, n: int) -> list[int]:
    """Indices of up to n points spread by farthest-point sampling, from the first point."""
    if len(points) == 0:
        return []
    chosen = [0]
    d = np.linalg.norm(points - points[0], axis=1)
    while len(chosen) < min(n, len(points)):
        j = int(np.argmax(d))
        if d[j] <= 0:
            break
        chosen.append(j)
        d = np.minimum(d, np.linalg.norm(points - points[j], axis=1))
    return chosen


MAX_CONTEXTS = 8
"""States a finger's intermediate contacts are scored against, at most (`_pick_intermediate`)."""


def _pick_intermediate(problem: GaitProblem, hand, obj, finger: str, n: int, contact_model: str, contexts=()) -> list[Slot]:
    """The n most useful unused contacts of a finger's reachable pool (and of the small
    steps from its own contacts, `local_contacts`, when the pool has fewer than n usable
    ones), as new slots.

    Useful: added to one of ``contexts`` (states where the finger is lifted, e.g. from
    `planner.graph.failure_analysis` "needs"), the candidate makes the best grasp (closure
    metric) without colliding with the fingers there. Without contexts: the fingers that
    keep their contact from the initial to the final grasp, and the other fingers'
    initial contacts. A candidate lies at least ``MIN_SLOT_SPACING_M`` from the finger's
    other contacts; one that collides in every context is not used.
    """
    from planner.closure import batch_grasp_closure

    have = list(problem.slots[finger])
    i = problem.fingers.index(finger)
    if not contexts:
        contexts = [tuple(s if j != i and s == t else LIFTED for j, (s, t) in enumerate(zip(problem.start, problem.goal))),
                    problem.start[:i] + (LIFTED,) + problem.start[i + 1:]]
    contexts = list(dict.fromkeys(contexts))[:MAX_CONTEXTS]

    def scored(cands: list[Slot]) -> np.ndarray:
        compatible = _pairwise_collision_check(hand, {**problem.slots, finger: tuple(have) + tuple(cands)})
        score = np.full(len(cands), -np.inf)
        for ctx in contexts:
            held = [(g, s) for j, (g, s) in enumerate(zip(problem.fingers, ctx)) if j != i and s != LIFTED]
            ok = [j for j in range(len(cands)) if all(compatible(finger, len(have) + j, g, s) for g, s in held)]
            base = {g: (problem.slots[g][s].points, problem.slots[g][s].normals) for g, s in held}
            closures = batch_grasp_closure([{**base, finger: (cands[j].points, cands[j].normals)} for j in ok],
                                           problem.friction)
            for j, c in zip(ok, closures):
                score[j] = max(score[j], c.metric)
        return score

    # the spread pool first; the small steps from its own contacts when it gives fewer than n
    cands = _candidates(problem, hand, obj, finger, contact_model, local=False)
    score = scored(cands)
    if np.isfinite(score).sum() < n:
        more = _candidates(problem, hand, obj, finger, contact_model)[len(cands):]
        cands, score = cands + more, np.r_[score, scored(more)]
    if not cands:
        return []
    out: list[Slot] = []
    for j in sorted(range(len(cands)), key=lambda j: (-score[j], j)):
        if len(out) >= n or score[j] == -np.inf:
            break
        if not any(_near(s, cands[j]) for s in out):
            out.append(replace(cands[j], label=f"int{len(have) - _fixed_slots(have) + len(out)}"))
    return out


def _candidates(problem: GaitProblem, hand, obj, finger: str, contact_model: str, spaced: bool = True,
                local: bool = True) -> list[Slot]:
    """A finger's candidate contacts not yet among its slots: its reachable pool and
    (``local``) the small steps from its initial and final contacts (`local_contacts`), in
    that order, as the closure test sees them (``contact_model``), labelled "candidate";
    ``spaced``: only those that are not `_near` one of its slots."""
    have = problem.slots[finger]
    pool = list(reachable_contacts(hand, obj, finger))
    for s in have[: _fixed_slots(have)] if local else ():
        pool += local_contacts(hand, obj, finger, s.points)
    out = []
    for points, normals, qf in pool:
        slot = _modelled(Slot(finger, "candidate", points, normals, qf), contact_model)
        if not spaced or not any(_near(s, slot) for s in have):
            out.append(slot)
    return out


#: Partial grasps kept per finger by `_holding_grasp`'s beam search.
HOLDING_BEAM = 12


def _holding_grasp(problem: GaitProblem, hand, obj, lifted: str, contact_model: str) -> dict[str, Slot]:
    """New contacts with which the fingers other than ``lifted`` hold the object without
    it, when no single new contact does (e.g. the thumb must move and the four fingers
    opposite it must first spread around the object).

    A beam search over the other fingers, in hand order: each is lifted, kept on one of its
    slots or put on one of its candidates (`_candidates`, near its slots too: a small
    change may be what closes the grasp), without colliding with the
    fingers chosen before (lifted ones at the open posture); the ``HOLDING_BEAM`` partial
    grasps with the best closure metric go on. The best complete grasp that is force
    closure (and within the grip budget, for a problem with loads) is returned: finger ->
    its slot (one of its own, or a new contact labelled as the next intermediate slot) for
    every finger touching in it; {} when there is none.
    """
    from planner.closure import batch_grasp_closure

    others = [f for f in problem.fingers if f != lifted]
    options = {f: list(problem.slots[f]) + _candidates(problem, hand, obj, f, contact_model, spaced=False) for f in others}
    check = _pairwise_collision_check(hand, {**problem.slots, **{f: tuple(v) for f, v in options.items()}})
    memo: dict[tuple, bool] = {}

    def compatible(f, j, g, t) -> bool:
        key = (f, j, g, t) if (f, j) <= (g, t) else (g, t, f, j)
        if key not in memo:
            memo[key] = check(f, j, g, t)
        return memo[key]

    beam: list[dict[str, int]] = [{lifted: LIFTED}]
    closures: list = []
    for f in others:
        grown = [{**a, f: j} for a in beam for j in [LIFTED] + list(range(len(options[f])))]
        touching = [k for k, a in enumerate(grown) if any(t != LIFTED for t in a.values())]
        found = batch_grasp_closure([{g: (options[g][t].points, options[g][t].normals) for g, t in grown[k].items()
                                      if t != LIFTED} for k in touching], problem.friction)
        closures = [None] * len(grown)
        for k, c in zip(touching, found):
            closures[k] = c
        ranked = []  # best metric first; collisions checked only until the beam is full
        for k in sorted(range(len(grown)), key=lambda k: (-closures[k].metric if closures[k] else np.inf, k)):
            if len(ranked) >= HOLDING_BEAM:
                break
            if all(compatible(f, grown[k][f], g, t) for g, t in grown[k].items() if g != f):
                ranked.append(k)
        beam, closures = [grown[k] for k in ranked], [closures[k] for k in ranked]
    for a, c in zip(beam, closures):
        if c is None or not c.is_force_closure:
            break
        if problem.load_gravity is not None:  # the slots a problem with the torque model holds
            for g, t in a.items():
                if t != LIFTED:
                    options[g][t] = with_statics(hand, obj, options[g][t])
        touching = {g: options[g][t] for g, t in a.items() if t != LIFTED}
        patches = {g: (s.points, s.normals) for g, s in touching.items()}
        statics = {g: s.statics for g, s in touching.items() if s.statics is not None}
        if problem.load_refusal(patches, statics) is not None:
            continue
        have = problem.slots
        return {g: options[g][t] if t < len(have[g]) else replace(options[g][t], label=f"int{len(have[g]) - _fixed_slots(have[g])}")
                for g, t in a.items() if t != LIFTED}
    return {}


def _near(a: Slot, b: Slot) -> bool:
    """Two contacts of a finger that are one: closer than ``MIN_SLOT_SPACING_M`` with mean
    normals less than ``MIN_SLOT_ANGLE_DEG`` apart (near a box's edge a finger curled
    differently touches another face at the same place: another contact)."""
    if np.min(np.linalg.norm(a.points[:, None, :] - b.points[None, :, :], axis=2)) >= MIN_SLOT_SPACING_M:
        return False
    na, nb = a.normals.mean(axis=0), b.normals.mean(axis=0)
    cos = float(na @ nb) / max(float(np.linalg.norm(na) * np.linalg.norm(nb)), 1e-12)
    return cos > math.cos(math.radians(MIN_SLOT_ANGLE_DEG))


def _fixed_slots(slots) -> int:
    """How many of a finger's slots are its initial/final contacts."""
    return sum(s.label in ("initial", "final") for s in slots)


def build_problem(initial, final, options: PlanOptions) -> GaitProblem:
    """Contact slots of every finger and the start/goal nodes of the graph.

    Args:
        initial, final: `planner.grasp.RealizedGrasp` of the same hand and object.
    """
    hand = initial.hand
    fingers = tuple(hand.fingers)
    slots: dict[str, tuple[Slot, ...]] = {}
    start, goal = [], []
    for f in fingers:
        fs: list[Slot] = []
        s_idx = g_idx = LIFTED
        if f in initial.patches:
            fs.append(Slot(f, "initial", *initial.patches[f], _finger_q(hand, f, initial.q)))
            s_idx = 0
        if f in final.patches:
            qf = _finger_q(hand, f, final.q)
            if fs and np.max(np.abs(fs[0].q - qf)) <= options.same_slot_tol_rad:
                g_idx = 0
            else:
                fs.append(Slot(f, "final", *final.patches[f], qf))
                g_idx = len(fs) - 1
        slots[f] = tuple(_modelled(s, options.contact_model) for s in fs)
        start.append(s_idx)
        goal.append(g_idx)
    directions = gravity_directions_of(options, hand)
    loads = names = gravities = None
    if directions:  # the weight at the object origin, in the object frame, per direction
        R = np.asarray(initial.obj.T_palm_obj, dtype=float)[:3, :3]
        names = tuple(name for name, _ in directions)
        gravities = np.array([R.T @ np.asarray(g, dtype=float) for _, g in directions])
        loads = np.array([np.r_[initial.obj.mass_kg * g, np.zeros(3)] for g in gravities])
        slots = {f: tuple(with_statics(hand, initial.obj, s) for s in ss) for f, ss in slots.items()}
    compatible = _pairwise_collision_check(initial.hand, slots)
    cap = None if options.max_finger_force_n is None else float(options.max_finger_force_n)
    problem = GaitProblem(fingers, slots, tuple(start), tuple(goal), initial.friction, compatible, options.max_lifted,
                          max_grip_force_n=cap, loads=loads, load_names=names or (),
                          grip_friction_margin=float(options.friction_margin), load_gravity=gravities,
                          hold_factor=float(options.hold_factor))
    if options.intermediate:
        problem, _ = add_intermediate(problem, initial, {f: options.intermediate for f in fingers}, options)
    return problem


def add_intermediate(problem: GaitProblem, initial, wanted: Mapping[str, int], options: PlanOptions,
                     contexts: Mapping[str, list] | None = None, deadline: float | None = None
                     ) -> tuple[GaitProblem, dict[str, int]]:
    """The problem with up to ``wanted[finger]`` more intermediate contacts per finger
    (`_pick_intermediate`, scored against ``contexts[finger]`` when given), appended after
    its slots (`add_slots`). Fingers are skipped once ``deadline`` (perf_counter) has passed.
    Returns the problem and how many were added per finger (fingers with none left out)."""
    new = {}
    for f, n in wanted.items():
        if deadline is not None and time.perf_counter() > deadline:
            break
        new[f] = _pick_intermediate(problem, initial.hand, initial.obj, f, n, options.contact_model,
                                    (contexts or {}).get(f, ()))
    return add_slots(problem, initial, new)


def add_slots(problem: GaitProblem, initial, new: Mapping[str, Slot | list[Slot]]) -> tuple[GaitProblem, dict[str, int]]:
    """The problem with the ``new`` slots (one or a list per finger) appended after each
    finger's slots: existing slot indices are kept, so the caches of an earlier search stay
    valid. Returns the problem and how many were added per finger (fingers with none left
    out)."""
    slots, added = dict(problem.slots), {}
    for f, more in new.items():
        more = [more] if isinstance(more, Slot) else list(more)
        if problem.load_gravity is not None:
            more = [with_statics(initial.hand, initial.obj, s) for s in more]
        if more:
            slots[f] = tuple(slots[f]) + tuple(more)
            added[f] = len(more)
    if not added:
        return problem, added
    return replace(problem, slots=slots, compatible=_pairwise_collision_check(initial.hand, slots)), added


def gravity_directions_of(options: PlanOptions, hand) -> list[tuple[str, tuple[float, float, float]]]:
    """The named gravity vectors (palm frame, m/s^2) a plan is made for: ``[("gravity",
    options.gravity)]``, the set of `planner.gravity.gravity_directions` for
    ``options.gravity_set`` (from ``hand.palm_normal``), or [] (force closure only)."""
    if options.gravity is not None:
        return [("gravity", tuple(float(v) for v in options.gravity))]
    if options.gravity_set is not None:
        from planner.gravity import gravity_directions

        # [:n]: planner.gravity returns palm down *and* palm up for n = 1 (its docstring says
        # palm down only); the first n entries are the documented set for every size.
        return gravity_directions(hand.palm_normal, options.gravity_set)[: options.gravity_set]
    return []


def with_statics(hand, obj, slot: Slot) -> Slot:
    """The slot with its `planner.grip.FingerStatics` (Jacobians at its points, gravity
    torques and joint limits of its finger at its configuration): what the torque model of
    a problem with loads needs."""
    if slot.statics is not None:
        return slot
    q = np.array(hand.q_open, dtype=float)
    q[list(hand.fingers[slot.finger].q_index)] = slot.q
    return replace(slot, statics=finger_statics(hand, slot.finger, q, slot.points, obj.T_palm_obj))


def _modelled(slot: Slot, contact_model: str) -> Slot:
    """The slot with its patch as the closure test sees it under ``contact_model``."""
    if contact_model == "patch":
        return slot
    points, normals = apply_contact_model({slot.finger: (slot.points, slot.normals)}, contact_model)[slot.finger]
    return replace(slot, points=points, normals=normals)


def _pairwise_collision_check(hand, slots: Mapping[str, tuple[Slot, ...]]) -> Callable[[str, int, str, int], bool]:
    """compatible(fa, sa, fb, sb): finger a at slot sa and b at sb do not collide."""
    from planner.contacts import collisions

    link_finger = {}
    for f, finger in hand.fingers.items():
        for link in finger.contact_links:
            link_finger[link] = f

    def q_of(assign: dict[str, int]) -> np.ndarray:
        q = np.array(hand.q_open, dtype=float)
        for f, s in assign.items():
            if s != LIFTED:
                q[list(hand.fingers[f].q_index)] = slots[f][s].q
        return q

    def compatible(fa: str, sa: int, fb: str, sb: int) -> bool:
        q = q_of({fa: sa, fb: sb})
        for a, b, _ in collisions(hand, q, None, fingers=(fa, fb)):
            if {link_finger.get(a), link_finger.get(b)} == {fa, fb}:
                return False
        return True

    return compatible


def node_q(hand, problem: GaitProblem, node) -> np.ndarray:
    """Whole-hand q of a node: slot joint values, lifted fingers at the open posture."""
    q = np.array(hand.q_open, dtype=float)
    for f, s in zip(problem.fingers, node):
        if s != LIFTED:
            q[list(hand.fingers[f].q_index)] = problem.slots[f][s].q
    return q


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
    from planner.motion import available_planners, plan_gait_step

    if options.motion_planner not in available_planners():
        raise UnknownNameError("motion planner", options.motion_planner, available_planners())

    def gait(hand, obj, q_a, q_b, finger):
        return plan_gait_step(
            hand, obj, q_a, q_b, finger,
            planner=options.motion_planner, timeout_s=options.motion_timeout_s, seed=options.seed,
            verbose=verbose,
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
    """Paths of every gait of a sequence; raises MotionError naming the failed edge."""
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


def _rejected_words(rejected) -> str:
    """Sequences the simulator rejected, in words: order, direction, step and verdict each."""
    return "; ".join(f"{' '.join(x['order'])}: {x['direction']} at step {x['step']}: {x['verdict']}" for x in rejected)


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


class _EdgeFailed(Exception):
    """A gait whose finger paths could not be planned: the graph edge to drop, the finger and
    the slots it lifted off (``lift_from``) and landed on (``land_on``), None if it did not."""

    def __init__(self, edge, finger, why, lift_from=None, land_on=None):
        self.edge, self.finger, self.why = edge, finger, why
        self.lift_from, self.land_on = lift_from, land_on
        super().__init__(why)


def _forbid_stuck_contacts(lazy: LazyGraph, hand, obj, bad: _EdgeFailed, stuck: dict) -> None:
    """After a failed gait: a contact of it the finger cannot back off whatever the other
    fingers do (`planner.motion.retreat_blocked`, cached in ``stuck`` per finger and slot)
    is never lifted off nor landed on again (one test instead of a re-plan per state); the
    initial or final grasp's contact of a finger that must move ends the search at once.

    Raises:
        NoSequenceError: the finger must leave its initial contact or reach its final one.
    """
    from planner.motion import retreat_blocked

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


def _anytime_search(problem: GaitProblem, initial, options: PlanOptions, t0: float,
                    prior: LazyGraph | None = None) -> tuple[LazyGraph, dict]:
    """Lazy ranked search, then (anytime mode: ``options.intermediate`` 0 and a time limit)
    rounds of intermediate contacts for the fingers that block progress
    (`planner.graph.failure_analysis`), until a sequence is found or the time limit passes.

    ``prior``: a search whose sequences all failed later (finger paths, verification): one
    more round starts from its graph, keeping the moves and states it removed, bounded by
    the round (one) rather than the clock, so the plan does not depend on the time the
    paths and replays took.

    Returns the last `LazyGraph` and what to record: rounds, contacts added per finger,
    states expanded, whether the ranking is exact, ``found`` (the sequences) and ``tried``
    (a sentence for the failure message).
    """
    deadline = t0 + options.time_limit_s if options.time_limit_s > 0 and prior is None else None
    auto = options.intermediate == 0 and options.time_limit_s > 0 and options.max_rounds > 0
    evaluator, added, rounds, expanded, unheld, held = None, {}, 0, 0, {}, set()
    lazy, found, out_of_time = prior, [], False
    removed = set(prior.removed) if prior is not None else set()
    removed_states = set(prior.removed_states) if prior is not None else set()
    forbidden = set(prior.forbidden) if prior is not None else set()
    if prior is not None:
        evaluator = prior.ev
    while True:
        if lazy is None:
            lazy = LazyGraph(problem, options.rank, evaluator=evaluator, deadline=deadline)
            lazy.removed |= removed
            lazy.removed_states |= removed_states
            lazy.forbidden |= forbidden
            evaluator = lazy.ev
            found = lazy.best(options.alternatives)
            expanded += lazy.G.graph["expanded"]
            out_of_time = lazy.timed_out or (deadline is not None and time.perf_counter() > deadline)
            if found or not auto or out_of_time or _goal_invalid(lazy) or (prior is not None and rounds >= 1) \
                    or rounds >= options.max_rounds:
                break
        # contacts for the fingers that could unblock progress, scored against the states
        # they should complete; every second round (and when those give none) one more for
        # every finger, scored as --intermediate N scores them (after m such rounds every
        # finger has had the m contacts of --intermediate m, or contacts at their places);
        # a finger the other fingers cannot hold the object without, in its second such
        # round (or when nothing else is left), gets a grasp of the others without it:
        # several new contacts at once (`_holding_grasp`)
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
                grasp = _holding_grasp(problem, initial.hand, initial.obj, f, options.contact_model)
                problem, more = add_slots(problem, initial, {g: s for g, s in grasp.items() if s not in problem.slots[g]})
                _count(new, more)
        if not new:
            break
        rounds += 1
        _count(added, new)
        lazy = None
    spent = time.perf_counter() - t0
    what = ", ".join(f"{f} {n}" for f, n in added.items())
    if not auto:
        tried = (f"{options.intermediate} intermediate contacts per finger were tried" if options.intermediate else
                 "no intermediate contacts were tried (no --intermediate N, and --max-rounds or --time-limit 0)")
    elif _goal_invalid(lazy):
        tried = "no intermediate contacts were tried: they cannot make the final grasp valid"
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
    """Plan a finger-gaiting sequence from one realized grasp to another.

    Args:
        initial, final: `planner.grasp.RealizedGrasp` (same hand, object, pose, friction), or
            grasp files (paths) or `GraspSpec`s, realized here.
        options: planner parameters.
        inputs: what to record under the plan's ``inputs`` (paths and sha256).
        verbose: let the motion planner print its log.

    Returns:
        `PlanResult` with the plan, the graph and the ranked sequences.

    Raises:
        NoSequenceError: no sequence exists (or none whose moves can be executed);
            the message says why.
    """
    from planner.grasp import RealizedGrasp

    if not isinstance(initial, RealizedGrasp) or not isinstance(final, RealizedGrasp):
        # paths or GraspSpecs: realized here, their files recorded as the CLI records them
        from planner.grasp import realized_grasp

        (initial, rec_i), (final, rec_f) = realized_grasp(initial), realized_grasp(final)
        if inputs is None:
            inputs = {k: v for k, v in (("initial", rec_i), ("final", rec_f)) if v is not None}
    check_same_setup(initial.spec, final.spec)
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
    verifying = options.verify and bool(directions) and options.strategy == "graph"
    verified, rejected, verify_s, workers, plan = None, [], 0.0, None, None
    if verifying:
        from planner.sim.verify import default_workers, verify_plan

        workers = options.workers or default_workers()
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
        lazy, search_info = _anytime_search(problem, initial, options, t0)
        problem, G = lazy.problem, lazy.G
        candidates = search_info.pop("found")
        log.info("search: %d sequence(s) found, %d round(s) of intermediate contacts, %.1f s",
                 len(candidates), search_info["rounds"], time.perf_counter() - t0)
        resumed = 0
        for _ in range(50):
            if not candidates and resumed < RESUME_ROUNDS and options.intermediate == 0 and options.time_limit_s > 0 \
                    and (failed or rejected):
                # every sequence of this graph failed later: one more round of intermediate
                # contacts, keeping what was removed
                resumed += 1
                lazy, more_info = _anytime_search(problem, initial, options, t0, prior=lazy)
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
                if rejected:
                    err = NoSequenceError(f"{err}; sequences that failed in the simulator ({len(rejected)}): "
                                          f"{_rejected_words(rejected[:2])}", err.report)
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
            log.info("verifying in pybullet: attempt %d, %d direction(s) in %d process(es)", len(rejected) + 1,
                     len(directions), min(workers, len(directions)))
            check = verify_plan(plan, hand, directions, workers=workers)
            verify_s += check.wall_time_s
            log.info("verification %s (%.1f s)", "passed" if check.passed else "failed: " + check.first_failure()[0],
                     check.wall_time_s)
            if check.passed:
                verified = check
                break
            name, step, verdict, at_state = check.first_failure()
            seq = candidates[0]
            rejected.append({"order": list(seq.order(problem)), "direction": name, "step": step, "verdict": verdict})
            if verbose:
                print(f"verify: sequence {_rejected_words(rejected[-1:])}")
            if step < 0:
                raise NoSequenceError(f"the initial grasp {initial.spec.name!r} does not hold in the simulator ({name}: "
                                      f"{verdict}); no sequence starting from it can pass (--no-verify returns one anyway)")
            if len(rejected) >= options.verify_attempts:
                raise NoSequenceError(
                    f"no sequence held in the simulator in {len(rejected)} attempt(s) (--verify-attempts; "
                    f"{verify_s:.1f} s of replays): {_rejected_words(rejected[:3])}; --no-verify returns the best "
                    "sequence unverified")
            # the re-search is bounded by the graph, not by the clock the replays spent: a
            # deadline passed during them would stop it where the last search stood (and make
            # the plan depend on the machine's load and the number of workers)
            lazy.deadline, lazy.timed_out = None, False
            edge = _step_edges(seq, motions)[step]
            # the state reached failed in the simulator: every move into it goes (but the
            # final grasp's: only this move into it, another landing may reach it)
            if at_state and edge[1] != problem.goal:
                lazy.remove_state(edge[1])
            else:
                lazy.remove_edge(*edge)
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
    if verifying:
        record = {**verified.record(), "attempts": len(rejected) + 1, "rejected": rejected}
        plan = replace(plan, summary={**plan.summary, "verification": record})
    return PlanResult(plan, G, best, tuple(candidates[1:]), time.perf_counter() - t0, tuple(failed),
                      verify_s if verifying else None)


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
    directions = gravity_directions_of(options, hand)
    parameters["gravity_directions"] = [{"name": n, "gravity": list(g)} for n, g in directions] or None
    parameters["grip_cone_sides"] = GRIP_CONE_SIDES if directions else None
    return Plan(
        hand={"name": hand.name, "spec": spec.hand_ref},
        object=spec.object.to_dict(),
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
