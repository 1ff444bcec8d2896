"""Candidates of grasp synthesis: a sampled pre-shape (and object pose), the fingers closed onto it.

`sample_candidate` draws the hand pre-shapes of one attempt of `planner.synthesis.synthesize`
and, when the object pose is not fixed, puts the object where the chosen fingers' closing
motions would all touch it; `closes_onto` closes the fingers with the thesis's procedure
(`planner.hand.Hand.close_finger`) and keeps a candidate whose every finger touches. The
check, the ranking and the files are `planner.synthesis`.
"""

from __future__ import annotations

import coal
import numpy as np

from planner.contacts import collisions, contact_patches
from planner.objects import GraspObject

#: A sampled object pose keeps this clearance from the palm (m).
PALM_CLEARANCE_M = 0.002
#: Each finger's centre curve (`sample_candidate`) must pass within this many inner radii
#: of the object centre.
SWEEP_REACH = 2.0
#: Random pre-shapes drawn per attempt; the best scored (`_score`: centre curves meeting at a
#: common point, or at the fixed object centre, with opposing pads) is tried.
PRESHAPES_PER_ATTEMPT = 6
#: The same with the object pose fixed: a random pre-shape rarely passes near a given centre,
#: and a draw costs only its sweeps' forward kinematics (Allegro 15 mm ball, thumb-index-middle,
#: 5 grasps: 112 attempts with 6 draws, 13 with 40).
FIXED_PRESHAPES_PER_ATTEMPT = 40
#: Weight of the pads' opposition in a pre-shape's score (`_score`), against the gap in inner radii.
OPPOSITION_WEIGHT = 1.0
#: A sampled object centre is jittered by N(0, JITTER x inner radius) per axis.
JITTER = 0.3
#: The object centre sits this many inner radii in front of the pads (`sample_candidate`).
CENTRE_OFFSET = 1.0
#: Sampled poses (jitter and orientation) tried per attempt until no finger starts inside.
POSE_TRIES = 4
#: Fraction of their range the closing joints of a pre-shape start closed by.
_PRESHAPE_CLOSE = (0.0, 0.3)


def _random_quat(rng) -> list[float]:
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    return [float(v) for v in q]


def _sweep(hand, finger, q, alphas, radius: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Where the finger's pad goes along its closing motion from q (closing joints at
    ``start + alpha (upper - start)``, as `Hand.close_finger` moves them): (len(alphas), 3)
    palm-frame points ``radius`` in front of the pad (along its outward normal: the centre a
    ball of that radius touching the pad there would have; the pad itself for 0) and the
    pad's unit outward normals."""
    cidx = np.array([hand.joint_names.index(j) for j in finger.close_joints])
    start = q[cidx]
    p_link = np.asarray(finger.pad_p_link, dtype=float)
    n_link = np.asarray(finger.pad_n_link if finger.pad_n_link is not None else (0.0, 0.0, 0.0), dtype=float)
    pts, nrm = [], []
    for a in alphas:
        qa = q.copy()
        qa[cidx] = start + a * (hand.upper[cidx] - start)
        T = hand.link_pose(qa, finger.pad_link)
        n = T[:3, :3] @ n_link
        pts.append(T[:3, :3] @ p_link + T[:3, 3] + radius * n)
        nrm.append(n)
    return np.array(pts), np.array(nrm)


def object_of(block) -> GraspObject:
    """The object of a synthesis object block (the ``object:`` file form; no pose: the palm
    frame's origin), or the object itself."""
    if isinstance(block, GraspObject):
        return block
    return GraspObject.from_data({"position": [0.0, 0.0, 0.0], "quat_xyzw": [0.0, 0.0, 0.0, 1.0], **block})


def _palm_distance(hand, q, obj: GraspObject) -> float:
    """Signed distance (m) between the palm's links and the object."""
    T = obj.T_palm_obj
    tf = coal.Transform3s(np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3]))
    req = coal.DistanceRequest()
    best = np.inf
    for link, finger, geom, tf_link in hand.collision_objects(q):
        if finger is None:
            best = min(best, coal.distance(geom, tf_link, obj.geometry, tf, req, coal.DistanceResult()))
    return float(best)


def _meeting_point(sweeps, iterations: int = 8) -> np.ndarray:
    """The point where the sweeps come closest together (approximately minimax): from every
    sample of every sweep, alternate "nearest sample of each sweep" and "their centroid" a few
    times; the start whose largest distance to a sweep ends smallest wins. Cost linear in the
    number of fingers (the exhaustive search over one sample per finger was 10^fingers)."""
    S = np.asarray(sweeps)                                     # (fingers, samples, 3)
    c = S.reshape(-1, 3).copy()                                # (starts, 3)
    for _ in range(iterations):
        d = np.linalg.norm(c[:, None, None, :] - S[None], axis=3)   # (starts, fingers, samples)
        nearest = S[np.arange(len(S))[None, :], np.argmin(d, axis=2)]  # (starts, fingers, 3)
        c = nearest.mean(axis=1)
    worst = np.max(np.min(np.linalg.norm(c[:, None, None, :] - S[None], axis=3), axis=2), axis=1)
    return c[int(np.argmin(worst))]


def _opposition(normals) -> float:
    """Length of the mean of the fingers' unit pad normals: 0 when they oppose each other
    (they can squeeze the object between them), 1 when they all push the same way."""
    return float(np.linalg.norm(np.mean(normals, axis=0)))


def sample_candidate(hand, fingers, obj: GraspObject, fixed, rng, obj_radius,
                     palm_clearance_m: float = PALM_CLEARANCE_M):
    """(the object at its pose, {finger: pre-shape}, "") of one attempt, or (object, None, why).

    Pre-shape: the joints that do not close (abduction, opposition) uniform in their range,
    the closing joints a little into theirs. Each finger's closing motion (the thesis's
    procedure, `Hand.close_finger`) sweeps its pad along a curve; the point ``obj_radius`` in
    front of the pad (along its outward normal) sweeps the "centre curve": where the centre
    of a ball of that radius touching the pad would be. Without a fixed pose the object
    centre is put where the fingers' centre curves come closest together (`_meeting_point`),
    jittered, with a random orientation. Of `PRESHAPES_PER_ATTEMPT` draws
    (`FIXED_PRESHAPES_PER_ATTEMPT` with the pose fixed) the one kept has
    the best score: the largest distance from the centre to a centre curve (in inner radii)
    plus `OPPOSITION_WEIGHT` times how much the pads at their nearest points push the same
    way (`_opposition`: a ball between fingers that all close from one side is pushed, not
    held). A draw whose fingers collide with each other (or the palm) where their centre
    curves pass nearest the centre is not kept. Attempts whose centre curves do not pass
    within `SWEEP_REACH` inner radii of the centre are dropped before any closing.
    """
    alphas = np.linspace(0.0, 1.0, 10)
    names = [f.name for f in fingers]
    best = None
    for _ in range(FIXED_PRESHAPES_PER_ATTEMPT if fixed else PRESHAPES_PER_ATTEMPT):  # keep the best scored
        q = np.array(hand.q_open, dtype=float)
        for f in fingers:
            idx = np.array(f.q_index)
            lo, hi = hand.lower[idx], hand.upper[idx]
            closing = np.array([j in f.close_joints for j in f.joints])
            start = np.clip(q[idx], lo, hi)
            frac = rng.uniform(*_PRESHAPE_CLOSE, size=len(idx))
            q[idx] = np.where(closing, start + frac * (hi - start), rng.uniform(lo, hi))
        swept = [_sweep(hand, f, q, alphas, CENTRE_OFFSET * obj_radius) for f in fingers]
        centre = np.asarray(obj.position, dtype=float) if fixed else _meeting_point([c for c, _ in swept])
        score = _score(swept, centre, obj_radius)
        if best is not None and (False, score) >= (best[0], best[1]):  # cannot beat the best
            continue
        # the fingers where they would touch: a pre-shape whose fingers collide there ranks last
        q_touch = q.copy()
        for f, (c, _) in zip(fingers, swept):
            cidx = np.array([hand.joint_names.index(j) for j in f.close_joints])
            a = alphas[int(np.argmin(np.linalg.norm(c - centre, axis=1)))]
            q_touch[cidx] = q[cidx] + a * (hand.upper[cidx] - q[cidx])
        collide = len(fingers) > 1 and bool(collisions(hand, q_touch, None, fingers=names))
        if best is None or (collide, score) < (best[0], best[1]):
            best = (collide, score, q, swept, centre)
    _, _, q, swept, centre = best
    placed = obj
    if not fixed:
        # a few jittered centres and orientations: the first that no finger (closing joints
        # open, as the closing procedure starts) is inside of
        q_free = q.copy()
        for f in fingers:
            cidx = [hand.joint_names.index(j) for j in f.close_joints]
            q_free[cidx] = np.clip(np.asarray(hand.q_open)[cidx], hand.lower[cidx], hand.upper[cidx])
        mid = centre
        for _ in range(POSE_TRIES):
            centre = mid + rng.normal(scale=JITTER * obj_radius, size=3)
            quat = [0.0, 0.0, 0.0, 1.0] if obj.shape == "sphere" else _random_quat(rng)
            placed = obj.replaced(quat_xyzw=quat, position=[float(v) for v in centre])
            # out of the palm: push the object along the palm normal until it clears the palm
            d = _palm_distance(hand, q, placed)
            if d < palm_clearance_m:
                centre = centre + (palm_clearance_m - d) * np.asarray(hand.palm_normal)
                placed = obj.replaced(quat_xyzw=quat, position=[float(v) for v in centre])
            if all(hand.state(q_free).finger_object_distance(placed, f.name) >= 0.0 for f in fingers):
                break
    if max(float(np.min(np.linalg.norm(c - centre, axis=1))) for c, _ in swept) > SWEEP_REACH * obj_radius:
        return placed, None, "sweeps miss the object"
    return placed, {f.name: q[list(f.q_index)].copy() for f in fingers}, ""


def _score(swept, centre, obj_radius) -> float:
    """Lower is better: the largest distance from ``centre`` to a finger's centre curve, in
    inner radii, plus `OPPOSITION_WEIGHT` x `_opposition` of the pad normals there."""
    gaps, normals = [], []
    for c, n in swept:
        d = np.linalg.norm(c - centre, axis=1)
        k = int(np.argmin(d))
        gaps.append(float(d[k]))
        normals.append(n[k])
    return max(gaps) / obj_radius + (OPPOSITION_WEIGHT * _opposition(normals) if len(swept) > 1 else 0.0)


def inner_radius(obj: GraspObject) -> float:
    """Half the smallest extent of the object (m): how close a pad sweep must pass to its centre."""
    return 0.5 * float(np.min(obj.extents))


def closes_onto(hand, fingers, obj, preshape) -> dict | None:
    """Cheap pre-filter: close the fingers; (patches, "") when every one touches, else (None, why)."""
    q = np.array(hand.q_open, dtype=float)
    for f in fingers:
        q[list(f.q_index)] = preshape[f.name]
    for f in fingers:
        if hand.state(q).finger_object_distance(obj, f.name) < 0.0:
            # the closing procedure starts from a finger free of the object: open its closing joints
            cidx = [hand.joint_names.index(j) for j in f.close_joints]
            q[cidx] = np.clip(np.asarray(hand.q_open)[cidx], hand.lower[cidx], hand.upper[cidx])
            if hand.state(q).finger_object_distance(obj, f.name) < 0.0:
                return None, "a finger starts inside the object"
            preshape[f.name] = q[list(f.q_index)].copy()
        q = np.asarray(hand.close_finger(f, q, obj), dtype=float)
    patches = contact_patches(hand, q, obj, fingers=[f.name for f in fingers])
    if len(patches) < len(fingers):
        return None, "a finger misses the object"
    return patches, ""
