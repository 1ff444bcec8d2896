"""Contact slots: the contacts each finger may take in a plan (the states' building blocks).

`build_problem` makes the `planner.graph.GaitProblem` of two realized grasps: every
finger's initial and final contacts and, on request (``intermediate`` N), N intermediate
contacts per finger from its reachable contacts (`reachable_contacts`: in-limit postures
closed onto the object, cached per hand and object; `local_contacts`: small steps from a
finger's own contacts). `add_intermediate` and `add_slots` grow a problem by more slots
(the rounds of the anytime search in `planner.regrasp`), `holding_grasp` finds several
new contacts at once; finger-finger collisions are checked pairwise with coal
(`pairwise_collision_check`), and with a gravity every slot carries its joint statics
(`with_statics`).
"""

from __future__ import annotations

import math
import time
from dataclasses import replace
from typing import Callable, Mapping

import numpy as np
from scipy.spatial import cKDTree

from planner.closure import apply_contact_model, batch_grasp_closure
from planner.collision import HAND_OVERLAP_TOL_M
from planner.contacts import collisions, contact_patches
from planner.errors import PlannerError
from planner.graph import LIFTED, GaitProblem, Slot
from planner.grip import finger_statics
from planner.model import PALM, Patch
from planner.options import PlanOptions, gravity_directions_of


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
#: ... unless their mean normals differ by this much at least (`near`).
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
    """The finger's in-limit (and coupled) postures whose pad faces the surface from just outside it:
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
    # the finger's free coordinates drawn (its drivers and uncoupled joints), the followers set
    # by the coupling (`planner.hand.Finger.couple`): the hand's limits keep them in range
    free = list(f.free)
    postures = np.zeros((POOL_POSTURES, len(idx)))
    postures[:, free] = rng.uniform(lo[free], hi[free], size=(POOL_POSTURES, len(free)))
    postures = f.couple(postures)
    T = np.asarray(obj.T_palm_obj, float)
    p_link = np.append(np.asarray(f.pad_p_link, float), 1.0)
    n_link = np.asarray(f.pad_n_link, float)
    q = np.array(hand.q_open, dtype=float)
    pads = np.empty((len(postures), 4, 4))
    kin = hand.kinematics(q)  # one pinocchio.Data, moved to every posture (FK only)
    pad = kin.kinematic_model.frame_id(f.pad_link)
    for k, qf in enumerate(postures):
        q[idx] = qf
        pads[k] = kin.update(q).frame_pose(pad)
    p_obj = (pads[:, :3, :] @ p_link - T[:3, 3]) @ T[:3, :3]
    n_obj = (pads[:, :3, :3] @ n_link) @ T[:3, :3]
    # distance to the surface from a dense sample of it (the nearest sample's tangent
    # plane): vectorized, for every shape; the closing procedure makes the exact contact
    cloud, cloud_n = obj.sample_surface(POOL_SURFACE_SAMPLES, np.random.default_rng(0))
    _, nearest = cKDTree(cloud).query(p_obj)
    d = np.einsum("ij,ij->i", p_obj - cloud[nearest], cloud_n[nearest])
    facing = -np.einsum("ij,ij->i", n_obj, cloud_n[nearest])
    kept = np.flatnonzero((d >= 0.0) & (d <= POOL_STANDOFF_M) & (facing >= POOL_FACING_COS))
    surf = p_obj[kept] - d[kept, None] * cloud_n[nearest[kept]]
    _POOLS[key] = (postures[kept], surf)
    return _POOLS[key]


def _closed_contacts(hand, obj, finger: str, postures) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, tuple]]:
    """Each posture closed onto the object (`Hand.close_finger`), kept when the finger
    touches and neither penetrates the object nor hits the palm or its own links:
    (points, inward normals, the finger's joint values, the link of every point) per
    contact, in order."""
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
        out.append((np.asarray(patch[0]), np.asarray(patch[1]), q[idx], patch.links))
    return out


def reachable_contacts(hand, obj, finger: str) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray, tuple], ...]:
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
        (points (n, 3), inward normals (n, 3), the finger's joint values, the link of every
        point) per contact, in farthest-point order.
    """
    key = (str(hand.spec_path), hand.name, _object_key(obj), finger)
    if key not in _POOLS:
        postures, surf = _pool_postures(hand, obj, finger)
        _POOLS[key] = tuple(_closed_contacts(hand, obj, finger, postures[_farthest_points(surf, POOL_SIZE)]))
    return _POOLS[key]


def local_contacts(hand, obj, finger: str, anchor: np.ndarray) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray, tuple], ...]:
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
    `planner.explain.failure_analysis` "needs"), the candidate makes the best grasp (closure
    metric) without colliding with the fingers there. Without contexts: the fingers that
    keep their contact from the initial to the final grasp, and the other fingers'
    initial contacts. A candidate lies at least ``MIN_SLOT_SPACING_M`` from the finger's
    other contacts; one that collides in every context is not used.
    """
    have = list(problem.slots[finger])
    i = problem.fingers.index(finger)
    if not contexts:
        contexts = [tuple(s if j != i and s == t else LIFTED for j, (s, t) in enumerate(zip(problem.start, problem.goal))),
                    problem.start[:i] + (LIFTED,) + problem.start[i + 1:]]
    contexts = list(dict.fromkeys(contexts))[:MAX_CONTEXTS]

    def scored(cands: list[Slot]) -> np.ndarray:
        compatible = pairwise_collision_check(hand, {**problem.slots, finger: tuple(have) + tuple(cands)})
        score = np.full(len(cands), -np.inf)
        for ctx in contexts:
            held = [(g, s) for j, (g, s) in enumerate(zip(problem.fingers, ctx)) if j != i and s != LIFTED]
            ok = [j for j in range(len(cands)) if all(compatible(finger, len(have) + j, g, s) for g, s in held)]
            base = {**{g: (problem.slots[g][s].points, problem.slots[g][s].normals) for g, s in held}, **problem.support}
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
        if not any(near(s, cands[j]) for s in out):
            out.append(replace(cands[j], label=f"int{len(have) - _fixed_slots(have) + len(out)}"))
    return out


def _candidates(problem: GaitProblem, hand, obj, finger: str, contact_model: str, spaced: bool = True,
                local: bool = True) -> list[Slot]:
    """A finger's candidate contacts not yet among its slots: its reachable pool and
    (``local``) the small steps from its initial and final contacts (`local_contacts`), in
    that order, as the closure test sees them (``contact_model``), labelled "candidate";
    ``spaced``: only those that are not `near` one of its slots."""
    have = problem.slots[finger]
    pool = list(reachable_contacts(hand, obj, finger))
    for s in have[: _fixed_slots(have)] if local else ():
        pool += local_contacts(hand, obj, finger, s.points)
    out = []
    for points, normals, qf, links in pool:
        slot = _modelled(Slot(finger, "candidate", points, normals, qf, links=links), contact_model)
        if not spaced or not any(near(s, slot) for s in have):
            out.append(slot)
    return out


#: Partial grasps kept per finger by `holding_grasp`'s beam search.
HOLDING_BEAM = 12


def holding_grasp(problem: GaitProblem, hand, obj, lifted: str, contact_model: str) -> dict[str, Slot]:
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
    others = [f for f in problem.fingers if f != lifted]
    options = {f: list(problem.slots[f]) + _candidates(problem, hand, obj, f, contact_model, spaced=False) for f in others}
    check = pairwise_collision_check(hand, {**problem.slots, **{f: tuple(v) for f, v in options.items()}})
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
        found = batch_grasp_closure([{**{g: (options[g][t].points, options[g][t].normals) for g, t in grown[k].items()
                                         if t != LIFTED}, **problem.support} for k in touching], problem.friction)
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
        patches = {**{g: s.patch for g, s in touching.items()}, **problem.support}
        statics = {g: s.statics for g, s in touching.items() if s.statics is not None}
        if problem.load_refusal(patches, statics) is not None:
            continue
        have = problem.slots
        return {g: options[g][t] if t < len(have[g]) else replace(options[g][t], label=f"int{len(have[g]) - _fixed_slots(have[g])}")
                for g, t in a.items() if t != LIFTED}
    return {}


def near(a: Slot, b: Slot) -> bool:
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
        initial, final: `planner.realization.RealizedGrasp` of the same hand and object.
    """
    hand = initial.hand
    fingers = tuple(hand.fingers)
    slots: dict[str, tuple[Slot, ...]] = {}
    start, goal = [], []
    for f in fingers:
        fs: list[Slot] = []
        s_idx = g_idx = LIFTED
        if f in initial.patches:
            fs.append(Slot(f, "initial", *initial.patches[f], _finger_q(hand, f, initial.q), links=initial.patches[f].links))
            s_idx = 0
        if f in final.patches:
            qf = _finger_q(hand, f, final.q)
            if fs and np.max(np.abs(fs[0].q - qf)) <= options.same_slot_tol_rad:
                g_idx = 0
            else:
                fs.append(Slot(f, "final", *final.patches[f], qf, links=final.patches[f].links))
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
    compatible = pairwise_collision_check(initial.hand, slots)
    cap = None if options.max_finger_force_n is None else float(options.max_finger_force_n)
    # the palm holds where both grasps have it (they share the object's pose, so a palm
    # contact is the same in both): a fixed contact of every state, never lifted
    support = {}
    if (PALM in initial.patches) != (PALM in final.patches):
        holds, free = (initial, final) if PALM in initial.patches else (final, initial)
        raise PlannerError(f"{free.spec.path}: palm: {free.spec.palm} keeps the palm out of this grasp, but it holds in "
                           f"{holds.spec.path} (palm: {holds.spec.palm}); with one object pose the palm touches in both: "
                           f"give both files the same palm mode")
    if PALM in initial.patches and PALM in final.patches:
        support[PALM] = apply_contact_model({PALM: initial.patches[PALM]}, options.contact_model)[PALM]
    problem = GaitProblem(fingers, slots, tuple(start), tuple(goal), initial.friction, compatible, options.max_lifted,
                          support=support, palm_hint=None if support else palm_hint(initial, options.contact_model),
                          max_grip_force_n=cap, loads=loads, load_names=names or (),
                          grip_friction_margin=float(options.friction_margin), load_gravity=gravities,
                          hold_factor=float(options.hold_factor))
    if options.intermediate:
        problem, _ = add_intermediate(problem, initial, {f: options.intermediate for f in fingers}, options)
    return problem


def palm_hint(grasp, contact_model: str) -> tuple | None:
    """The contact the palm would make if the object rested on it, and the gap: ``(Patch, gap_m)``
    (object frame; the point of the object nearest the palm, the inward normal along the
    palm-to-object direction), or None when the hand has no palm geometry."""
    hand, obj = grasp.hand, grasp.obj
    dist = hand.state(grasp.q).link_object(obj, hand.collision.finger_links(None))
    if not dist:
        return None
    link, ld = min(dist.items(), key=lambda kv: kv[1].distance_m)
    d = np.asarray(ld.p_obj_palm, float) - np.asarray(ld.p_link_palm, float)
    if not np.linalg.norm(d) > 1e-9:
        return None
    T = np.asarray(obj.T_palm_obj, dtype=float)
    R = T[:3, :3]
    p_obj = R.T @ (np.asarray(ld.p_obj_palm, float) - T[:3, 3])
    n_obj = R.T @ (d / np.linalg.norm(d))
    patch = Patch(p_obj[None, :], n_obj[None, :], (link,))
    return apply_contact_model({PALM: patch}, contact_model)[PALM], float(ld.distance_m)


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
    return replace(problem, slots=slots, compatible=pairwise_collision_check(initial.hand, slots)), added


def with_statics(hand, obj, slot: Slot) -> Slot:
    """The slot with its `planner.grip.FingerStatics` (Jacobians at its points, gravity
    torques and joint limits of its finger at its configuration): what the torque model of
    a problem with loads needs."""
    if slot.statics is not None:
        return slot
    q = np.array(hand.q_open, dtype=float)
    q[list(hand.fingers[slot.finger].q_index)] = slot.q
    return replace(slot, statics=finger_statics(hand, slot.finger, q, slot.points, obj.T_palm_obj, links=slot.links))


def _modelled(slot: Slot, contact_model: str) -> Slot:
    """The slot with its patch as the closure test sees it under ``contact_model``."""
    if contact_model == "patch":
        return slot
    patch = apply_contact_model({slot.finger: slot.patch}, contact_model)[slot.finger]
    return replace(slot, points=patch.points, normals=patch.normals, links=patch.links)


def pairwise_collision_check(hand, slots: Mapping[str, tuple[Slot, ...]]) -> Callable[[str, int, str, int], bool]:
    """compatible(fa, sa, fb, sb): finger a at slot sa and b at sb do not collide."""
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

    model = hand.collision
    between: dict[tuple[str, str], tuple] = {}

    def compatible(fa: str, sa: int, fb: str, sb: int) -> bool:
        # the self-collisions of the hand at q (`planner.contacts.collisions` with fingers
        # (fa, fb)) in which a contact link of fa meets one of fb: only those geometry pairs
        # are measured, the same answer
        pairs = between.get((fa, fb))
        if pairs is None:
            pairs = between[(fa, fb)] = tuple(
                (i, j) for i, j in model.pairs
                if (model.geometries[i].finger in (fa, fb) or model.geometries[j].finger in (fa, fb))
                and {link_finger.get(model.geometries[i].link), link_finger.get(model.geometries[j].link)} == {fa, fb})
        if not pairs:
            return True
        return not any(d < -HAND_OVERLAP_TOL_M
                       for _, _, d in hand.state(q_of({fa: sa, fb: sb})).link_pair_distances(pairs))

    return compatible


def node_q(hand, problem: GaitProblem, node) -> np.ndarray:
    """Whole-hand q of a node: slot joint values, lifted fingers at the open posture."""
    q = np.array(hand.q_open, dtype=float)
    for f, s in zip(problem.fingers, node):
        if s != LIFTED:
            q[list(hand.fingers[f].q_index)] = problem.slots[f][s].q
    return q
