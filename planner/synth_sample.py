"""Candidates of grasp synthesis: a sampled pre-shape (and object pose), the fingers closed onto it.

`sample_candidate` draws the hand pre-shapes of one attempt of `planner.synthesis.synthesize`
and, when the object pose is not fixed, puts the object where the chosen fingers' closing
motions would all touch it (clear of the palm, or with ``palm`` against it: a palm-supported
or power grasp); `closes_onto` closes the fingers with the thesis's procedure
(`planner.hand.Hand.close_finger`) and keeps a candidate whose every finger (and with
``palm`` the palm) touches. The check, the ranking and the files are `planner.synthesis`.
"""

from __future__ import annotations

import coal
import numpy as np

from planner.collision import object_sphere
from planner.contacts import TOUCH_TOL_M, collisions, contact_patches
from planner.ik import closing_ends, couple_finger
from planner.model import PALM
from planner.objects import GraspObject
from planner.retreat import DEFAULT_LIFT_M, retreat_blocked

#: A sampled object pose keeps this clearance from the palm (m).
PALM_CLEARANCE_M = 0.002
#: With ``palm`` a sampled object pose is moved along the palm normal until its signed
#: distance to the palm is this (m): half the touch tolerance (`TOUCH_TOL_M`, within which
#: the palm counts as touching). Not 0: the object must not penetrate the palm (coal's
#: signed distance would decide between touching and colliding, and the replay's object
#: would start pushed out of it). Not the tolerance itself: the palm's patch also takes the
#: object-surface points around the nearest one (`planner.contacts.RING_RADII_M`, up to
#: 3 mm) that are within the tolerance, and on a curved object they lie farther from the
#: palm (0.3 mm on a 15 mm ball, 0.45 mm on a 10 mm one): half a millimetre of gap keeps
#: them in, so the palm pushes over an area and resists torsion, not at a single point; it
#: also leaves the placement's `PALM_GAP_TOL_M` far inside the band.
PALM_TOUCH_GAP_M = 0.5 * TOUCH_TOL_M
#: The palm placement stops when the gap is this close to `PALM_TOUCH_GAP_M` (m).
PALM_GAP_TOL_M = 5e-5
#: Steps of the palm placement (each moves the object along the palm normal by the gap's
#: error: one step when its nearest point faces the palm); an object beside or behind the
#: palm does not get there: "object not against the palm".
PALM_PLACE_STEPS = 8
#: Points per side of the grid on the palm's grasping face that pulls the fingers' meeting
#: point onto the palm (`sample_candidate` with ``palm``).
PALM_GRID = 7
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
#: With the pose fixed, pre-shapes of each finger closed onto the object per attempt
#: (`_fixed_candidate`; each costs a closing and a contact patch, ~2 ms).
FIXED_CLOSED_PER_FINGER = 6
#: Rounds of the coordinate descent choosing one closed draw per finger with the pose fixed
#: (`_fixed_candidate`); each round lets every finger answer the others' choice once.
FIXED_DESCENT_ROUNDS = 3
#: Weight of the pads' opposition in a pre-shape's score (`_score`), against the gap in inner radii.
OPPOSITION_WEIGHT = 1.0
#: A sampled object centre is jittered by N(0, JITTER x inner radius) per axis.
JITTER = 0.3
#: The object centre sits this many inner radii in front of the pads (`sample_candidate`).
CENTRE_OFFSET = 1.0
#: Sampled poses (jitter and orientation) tried per attempt until no finger starts inside.
POSE_TRIES = 4
#: Pushes of a sampled object out of the opened fingers (`_push_out`) per pose try.
PUSH_OUT_STEPS = 3
#: Gap a push leaves between the object and the link that was inside it (m): the closing
#: procedure's touch resolution is 0.1 % of a joint range, far below this.
PUSH_OUT_GAP_M = 0.0005
#: Gap to the opened fingers of the pose a pose try prefers when an opened finger touches the
#: object (m): a back-off's lift (`planner.retreat.DEFAULT_LIFT_M`, what `retreat_blocked`
#: asks of the contact link), so that a finger's open posture is lifted off the object.
#: Pushed only 0.5 mm clear, the open iCub thumb lay against a 30 mm ball and closed 1-2 % of
#: its range onto it, pressed sideways at 85-100 % opposition: 34 of 37 "cannot back off"
#: rejections in 160 attempts (seed 0).
LIFTED_GAP_M = DEFAULT_LIFT_M
#: Fraction of their range the closing joints of a pre-shape start closed by.
_PRESHAPE_CLOSE = (0.0, 0.3)


class Rejection(str):
    """Why a candidate was dropped: the text `planner.synthesis.SynthResult.rejected` counts
    (equal to it as a str), with the fingers it is about (``fingers``: those whose sweep
    missed, that missed or started inside the object, that cannot back off; empty when the
    reason is the whole grasp's), so that ``synth`` can say which finger fails."""

    fingers: tuple[str, ...]

    def __new__(cls, text: str, fingers=()):
        self = super().__new__(cls, text)
        self.fingers = tuple(fingers)
        return self

    def __reduce__(self):  # (worker processes send it back pickled)
        return (Rejection, (str(self), self.fingers))


def _random_quat(rng) -> list[float]:
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    return [float(v) for v in q]


def _sweep(hand, finger, q, alphas, radius: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Where the finger's pad goes along its closing motion from q (closing joints at
    ``start + alpha (end - start)``, ``end`` the limit each closes toward, as
    `Hand.close_finger` moves them): (len(alphas), 3)
    palm-frame points ``radius`` in front of the pad (along its outward normal: the centre a
    ball of that radius touching the pad there would have; the pad itself for 0) and the
    pad's unit outward normals."""
    cidx, end = closing_ends(hand, finger)  # a follower moves by its coupling
    start = q[cidx]
    p_link = np.asarray(finger.pad_p_link, dtype=float)
    n_link = np.asarray(finger.pad_n_link if finger.pad_n_link is not None else (0.0, 0.0, 0.0), dtype=float)
    pts, nrm = [], []
    kin = hand.kinematics(q)  # one pinocchio.Data, moved along the closing motion (FK only)
    pad = kin.kinematic_model.frame_id(finger.pad_link)
    for a in alphas:
        qa = q.copy()
        qa[cidx] = start + a * (end - start)
        T = kin.update(couple_finger(finger, qa)).frame_pose(pad)
        n = T[:3, :3] @ n_link
        pts.append(T[:3, :3] @ p_link + T[:3, 3] + radius * n)
        nrm.append(n)
    return np.array(pts), np.array(nrm)


def _sweeps(hand, fingers, q, alphas, radius: float = 0.0) -> list[tuple[np.ndarray, np.ndarray]]:
    """`_sweep` of every finger in ``fingers`` from q, with one forward kinematics per alpha
    for all of them: each finger's pads move by its own joints only (its chain from the
    palm), so a pose computed with the other fingers moved too is the same to the bit.
    Fingers that share a joint: `_sweep` one by one."""
    idx = [list(f.q_index) for f in fingers]
    if len({i for ix in idx for i in ix}) < sum(len(ix) for ix in idx):
        return [_sweep(hand, f, q, alphas, radius) for f in fingers]
    ends = [closing_ends(hand, f) for f in fingers]  # a follower moves by its coupling
    starts = [q[cidx] for cidx, _ in ends]
    spans = [end - start for (_, end), start in zip(ends, starts)]
    p_link = [np.asarray(f.pad_p_link, dtype=float) for f in fingers]
    n_link = [np.asarray(f.pad_n_link if f.pad_n_link is not None else (0.0, 0.0, 0.0), dtype=float) for f in fingers]
    kin = hand.kinematics(q)  # one pinocchio.Data, moved along the closing motions (FK only)
    pads = [kin.kinematic_model.frame_id(f.pad_link) for f in fingers]
    pts = [[] for _ in fingers]
    nrm = [[] for _ in fingers]
    for a in alphas:
        qa = q.copy()
        for f, (cidx, _), start, span in zip(fingers, ends, starts, spans):
            qa[cidx] = start + a * span
            couple_finger(f, qa)
        kin.update(qa)
        for k, pad in enumerate(pads):
            T = kin.frame_pose(pad)
            n = T[:3, :3] @ n_link[k]
            pts[k].append(T[:3, :3] @ p_link[k] + T[:3, 3] + radius * n)
            nrm[k].append(n)
    return [(np.array(p), np.array(n)) for p, n in zip(pts, nrm)]


def object_of(block) -> GraspObject:
    """The object of a synthesis object block (the ``object:`` file form; no pose: the palm
    frame's origin), or the object itself."""
    if isinstance(block, GraspObject):
        return block
    return GraspObject.from_data({"position": [0.0, 0.0, 0.0], "quat_xyzw": [0.0, 0.0, 0.0, 1.0], **block})


def _palm_shapes(hand, q=None) -> list:
    """(coal shape, its Transform3s in the palm frame) of every palm link (they do not move with q)."""
    q = np.asarray(hand.q_open if q is None else q, dtype=float)
    return [(geom, tf) for _, finger, geom, tf in hand.state(q).collision_objects() if finger is None]


def _palm_gap(palm, obj: GraspObject) -> float:
    """Signed distance (m) between the palm's shapes (`_palm_shapes`) and the object."""
    T = obj.T_palm_obj
    tf = coal.Transform3s(np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3]))
    req = coal.DistanceRequest()
    best = np.inf
    for geom, tf_link in palm:
        best = min(best, coal.distance(geom, tf_link, obj.geometry, tf, req, coal.DistanceResult()))
    return float(best)


def _palm_face(hand, palm, offset: float, k: int = PALM_GRID) -> np.ndarray:
    """(k*k, 3) palm-frame points on the palm's grasping face, ``offset`` in front of it: the
    face of the palm links' bounding box (axes: ``palm_normal`` and two across it) farthest
    along the normal, a k x k grid over it. Where the centre of a ball of radius ``offset``
    resting on a flat palm would be."""
    n = np.asarray(hand.palm_normal, dtype=float)
    a = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(n, a)
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    B = np.array([u, v, n])                                     # rows: the box axes
    pts = []
    for geom, tf in palm:
        geom.computeLocalAABB()
        lo, hi = np.asarray(geom.aabb_local.min_), np.asarray(geom.aabb_local.max_)
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        pts.append(corners @ np.asarray(tf.getRotation()).T + np.asarray(tf.getTranslation()))
    c = np.vstack(pts) @ B.T                                    # corners in (u, v, n)
    lo, hi = c.min(axis=0), c.max(axis=0)
    gu, gv = np.meshgrid(np.linspace(lo[0], hi[0], k), np.linspace(lo[1], hi[1], k), indexing="ij")
    return gu.reshape(-1, 1) * u + gv.reshape(-1, 1) * v + (hi[2] + offset) * n


def place_against_palm(hand, palm, obj: GraspObject, centre, quat, gap: float = PALM_TOUCH_GAP_M):
    """The object at orientation ``quat``, its centre moved from ``centre`` along the hand's
    ``palm_normal`` (either way) until its signed distance to the palm is ``gap`` (within
    `PALM_GAP_TOL_M`), or None when `PALM_PLACE_STEPS` steps do not get it there (it lies
    beside or behind the palm's grasping face)."""
    n = np.asarray(hand.palm_normal, dtype=float)
    centre = np.asarray(centre, dtype=float)
    for _ in range(PALM_PLACE_STEPS):
        placed = obj.replaced(quat_xyzw=quat, position=[float(v) for v in centre])
        d = _palm_gap(palm, placed)
        if abs(d - gap) <= PALM_GAP_TOL_M:
            return placed
        centre = centre - (d - gap) * n
    return None


def _meeting_point(sweeps, iterations: int = 8) -> np.ndarray:
    """The point where the sweeps come closest together (approximately minimax): from every
    sample of every sweep, alternate "nearest sample of each sweep" and "their centroid" a few
    times; the start whose largest distance to a sweep ends smallest wins. Cost linear in the
    number of fingers (the exhaustive search over one sample per finger was 10^fingers)."""
    if len({len(s) for s in sweeps}) > 1:  # sweeps of different lengths (a palm grid among them)
        return _meeting_point_ragged(sweeps, iterations)
    S = np.asarray(sweeps)                                     # (fingers, samples, 3)
    c = S.reshape(-1, 3).copy()                                # (starts, 3)
    Sx, Sy, Sz = S[None, :, :, 0], S[None, :, :, 1], S[None, :, :, 2]
    for _ in range(iterations):
        k = np.argmin(_dists(c, Sx, Sy, Sz), axis=2)            # (starts, fingers): nearest samples
        # their centroid: summed finger by finger and divided, as numpy's mean over that axis does
        acc = S[0][k[:, 0]]
        for f in range(1, len(S)):
            acc = acc + S[f][k[:, f]]
        c = acc / len(S)
    worst = np.max(np.min(_dists(c, Sx, Sy, Sz), axis=2), axis=1)
    return c[int(np.argmin(worst))]


def _dists(c: np.ndarray, Sx, Sy, Sz) -> np.ndarray:
    """``_norm3(c[:, None, None, :] - S[None])`` one coordinate at a time (the same numbers,
    without broadcasting over the short last axis): c (m, 3), S's coordinates (1, F, n)."""
    dx = c[:, 0, None, None] - Sx
    dy = c[:, 1, None, None] - Sy
    dz = c[:, 2, None, None] - Sz
    return np.sqrt(dx * dx + dy * dy + dz * dz)


def _norm3(x: np.ndarray) -> np.ndarray:
    """``np.linalg.norm(x, axis=-1)`` of 3-vectors to the bit (the squares summed in numpy's
    order, ((x0^2 + x1^2) + x2^2)), at half its cost."""
    sq = x * x
    return np.sqrt(sq[..., 0] + sq[..., 1] + sq[..., 2])


def _meeting_point_ragged(sweeps, iterations: int = 8) -> np.ndarray:
    """`_meeting_point` of point sets of different sizes (one loop per set)."""
    S = [np.asarray(s, dtype=float) for s in sweeps]
    c = np.vstack(S)
    for _ in range(iterations):
        c = np.mean([s[np.argmin(_norm3(c[:, None, :] - s[None]), axis=1)] for s in S], axis=0)
    worst = np.max([np.min(_norm3(c[:, None, :] - s[None]), axis=1) for s in S], axis=0)
    return c[int(np.argmin(worst))]


def _opposition(normals) -> float:
    """Length of the mean of the fingers' unit pad normals: 0 when they oppose each other
    (they can squeeze the object between them), 1 when they all push the same way."""
    return float(np.linalg.norm(np.mean(normals, axis=0)))


def sample_candidate(hand, fingers, obj: GraspObject, fixed, rng, obj_radius,
                     palm_clearance_m: float = PALM_CLEARANCE_M, palm: bool = False, mu: float = 1.0):
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
    curves pass nearest the centre is not kept. Each jittered pose (up to `POSE_TRIES`, until
    no opened finger is inside the object) is pushed out of the opened fingers
    (`_push_out`), and, when an opened finger then touches it (`_open_touch`), rather
    `LIFTED_GAP_M` clear of them if their centre curves still reach it and they do not collide
    where they would touch it there. Attempts whose centre curves
    do not pass within `SWEEP_REACH` inner radii of the centre are dropped before any closing.

    With ``palm`` (a palm-supported or power grasp) the object goes AGAINST the palm instead
    of ``palm_clearance_m`` clear of it: the palm's grasping face (`_palm_face`, the centres
    of a ball of the inner radius resting on it) is one more curve in the meeting point, the
    draws are scored at that point moved onto the face, with the palm pushing along its
    normal among the pads (`_opposition`); the sampled centre (jittered as above; a box or
    cylinder resting on one of its faces or its side, `_resting_quat`) is then moved along
    the palm normal, either way, until the object is `PALM_TOUCH_GAP_M` from the palm
    (`place_against_palm`), and kept when no finger, chosen or not, starts inside it. The
    palm-specific reasons: "object not against the palm" (the centre lies beside or behind
    the palm: moving along the normal does not bring it there), "an unused finger is inside
    the object on the palm", "sweeps miss the object on the palm". With a fixed pose nothing
    moves (`planner.synthesis.synthesize` checks that the object touches the palm).
    """
    alphas = np.linspace(0.0, 1.0, 10)
    names = [f.name for f in fingers]
    n_palm = np.asarray(hand.palm_normal, dtype=float) if palm else None
    if palm and not fixed:
        # the side the object rests on, first: how high its centre sits above the palm
        R_rest = _resting_rotation(rng, obj, n_palm)
        height = _half_height(obj, R_rest, n_palm) if R_rest is not None else CENTRE_OFFSET * obj_radius
        shapes = _palm_shapes(hand)
        face = _palm_face(hand, shapes, height + PALM_TOUCH_GAP_M)
        face_level = float(face[0] @ n_palm)
    if fixed:
        return _fixed_candidate(hand, fingers, obj, rng, obj_radius, alphas, palm, mu)
    draws = []
    for _ in range(PRESHAPES_PER_ATTEMPT):
        q = np.array(hand.q_open, dtype=float)
        for f in fingers:
            idx = np.array(f.q_index)
            lo, hi = hand.lower[idx], hand.upper[idx]
            closing = np.array([j in f.close_joints for j in f.joints])
            start = np.clip(q[idx], lo, hi)
            frac = rng.uniform(*_PRESHAPE_CLOSE, size=len(idx))
            q[idx] = np.where(closing, start + frac * (_closing_end(hand, f) - start), rng.uniform(lo, hi))
            couple_finger(f, q)  # the drivers drawn, the followers by the coupling
        swept = _sweeps(hand, fingers, q, alphas, CENTRE_OFFSET * obj_radius)
        if palm:  # the fingers' meeting point, with the palm's face as one more curve, on the face
            centre = _meeting_point([c for c, _ in swept] + [face])
            centre = centre + (face_level - centre @ n_palm) * n_palm  # onto the face
        else:
            centre = _meeting_point([c for c, _ in swept])
        draws.append((_score(swept, centre, obj_radius, n_palm if palm else None), q, swept, centre))
    # the best scored draw whose fingers do not collide where they would touch, else the best
    # scored (the least (collides, score), the first of equals): tried in score order, the
    # collision test stops at the first free one
    order = sorted(range(len(draws)), key=lambda k: draws[k][0])  # stable: the first of equals
    pick = order[0]
    if len(fingers) > 1:
        for k in order:
            _, q, swept, centre = draws[k]
            if not _collide_touching(hand, fingers, q, swept, alphas, centre):
                pick = k
                break
    _, q, swept, centre = draws[pick]
    placed = obj
    if not fixed:
        # a few jittered centres and orientations: the first that no finger (closing joints
        # open, as the closing procedure starts) is inside of
        q_free = q.copy()
        for f in fingers:
            cidx = [hand.joint_names.index(j) for j in f.close_joints]
            q_free[cidx] = np.clip(np.asarray(hand.q_open)[cidx], hand.lower[cidx], hand.upper[cidx])
            couple_finger(f, q_free)
        mid = centre
        if palm:
            state = hand.state(q_free)
            placed = None
            for _ in range(POSE_TRIES):
                quat = _resting_quat(rng, obj, R_rest, n_palm)
                cand = place_against_palm(hand, shapes, obj, mid + rng.normal(scale=JITTER * obj_radius, size=3), quat)
                if cand is None:
                    continue
                placed, centre = cand, np.asarray(cand.position, dtype=float)
                if not any(state.finger_penetrates(placed, f, object_sphere(placed)) for f in hand.fingers):
                    break
            if placed is None:
                return obj, None, "object not against the palm"
            if any(state.finger_penetrates(placed, f, object_sphere(placed)) for f in hand.fingers if f not in names):
                return placed, None, "an unused finger is inside the object on the palm"
        else:
            at_q, free = hand.state(q), hand.state(q_free)  # one state each, read by every try
            for _ in range(POSE_TRIES):
                centre = mid + rng.normal(scale=JITTER * obj_radius, size=3)
                quat = [0.0, 0.0, 0.0, 1.0] if obj.shape == "sphere" else _random_quat(rng)
                placed = obj.replaced(quat_xyzw=quat, position=[float(v) for v in centre])
                # out of the palm: push the object along the palm normal until it clears the palm
                placed = _clear_of_palm(at_q, placed, palm_clearance_m, hand.palm_normal)
                near = _push_out(hand, free, placed, fingers, palm_clearance_m)
                if _open_touch(hand, free, near, fingers):
                    # an opened finger touches it: it could not open off its contact. Rather the
                    # object a lift away from the opened fingers, when their sweeps still reach it
                    # without colliding where they touch it
                    lifted = _push_out(hand, free, placed, fingers, palm_clearance_m, gap=LIFTED_GAP_M,
                                       below=LIFTED_GAP_M)
                    near = lifted if _reach(swept, lifted, obj_radius) and (len(fingers) < 2 or not _collide_touching(
                        hand, fingers, q, swept, alphas, lifted.position)) else near
                placed = near
                if not any(free.finger_penetrates(placed, f.name, object_sphere(placed)) for f in fingers):
                    break
            centre = np.asarray(placed.position, dtype=float)
    far = [f.name for f, (c, _) in zip(fingers, swept)
           if float(np.min(_norm3(c - centre))) > SWEEP_REACH * obj_radius]
    if far:
        return placed, None, Rejection("sweeps miss the object" + (" on the palm" if palm else ""), far)
    return placed, {f.name: q[list(f.q_index)].copy() for f in fingers}, ""


def _collide_touching(hand, fingers, q, swept, alphas, centre) -> bool:
    """Whether the fingers collide with each other (or the palm) where they would touch a
    ball centred at ``centre``: each finger's closing joints at the sample of its centre curve
    nearest to it (``swept``: `_sweeps` from the pre-shape q at ``alphas``)."""
    centre = np.asarray(centre, dtype=float)
    q_touch = q.copy()
    for f, (c, _) in zip(fingers, swept):
        cidx, end = closing_ends(hand, f)
        a = alphas[int(np.argmin(_norm3(c - centre)))]
        q_touch[cidx] = q[cidx] + a * (end - q[cidx])
        couple_finger(f, q_touch)
    return hand.state(q_touch).self_collides({f.name for f in fingers})  # (`collisions` without an object)


def _open_touch(hand, state, placed: GraspObject, fingers) -> bool:
    """Whether a link of the opened fingers (``state``: closing joints open) is within the
    touch tolerance of the object (`TOUCH_TOL_M`, as `planner.contacts.touching_links`; the
    back-off's too, `planner.finger_scene.DEFAULT_TOUCH_TOL_M`): that finger's open posture
    touches the object, so opening the finger cannot back it off its contact."""
    links = [lk for f in fingers for lk in hand.fingers[f.name].links]
    return any(ld.distance_m <= TOUCH_TOL_M for ld in state.link_object(placed, links).values())


def _reach(swept, placed: GraspObject, obj_radius: float) -> bool:
    """Whether every finger's centre curve passes within `SWEEP_REACH` inner radii of the object
    centre (`sample_candidate`'s "sweeps miss the object" test)."""
    centre = np.asarray(placed.position, dtype=float)
    return all(float(np.min(_norm3(c - centre))) <= SWEEP_REACH * obj_radius for c, _ in swept)


def _push_out(hand, state, placed: GraspObject, fingers, palm_clearance_m: float, gap: float = PUSH_OUT_GAP_M,
              below: float = 0.0) -> GraspObject:
    """The object moved out of the opened fingers (``state``: the hand with the closing joints
    open, where the closing procedure starts): up to `PUSH_OUT_STEPS` times, the link nearest to
    it, when nearer than ``below`` (by default: inside it), pushes it away from the link's
    witness point until that link is ``gap`` from it (then out of the palm, as placed); the
    object itself when no link is that near. A meeting point of the centre curves can lie where
    an open finger is (the iCub's thumb on a 30 mm ball: 21 of 29 attempts); the closing would
    start inside the object."""
    links = [lk for f in fingers for lk in hand.fingers[f.name].links]
    n = np.asarray(hand.palm_normal, dtype=float)
    for _ in range(PUSH_OUT_STEPS):
        worst = min(state.link_object(placed, links).values(), key=lambda ld: ld.distance_m, default=None)
        if worst is None or worst.distance_m >= below:
            return placed
        centre = np.asarray(placed.position, dtype=float)
        u = centre - np.asarray(worst.p_link_palm, dtype=float)
        u /= max(float(np.linalg.norm(u)), 1e-12)
        centre = centre + (gap - worst.distance_m) * u
        placed = _clear_of_palm(state, placed.replaced(position=[float(v) for v in centre]), palm_clearance_m, n)
    return placed


def _clear_of_palm(state, placed: GraspObject, clearance_m: float, palm_normal) -> GraspObject:
    """``placed`` moved along ``palm_normal`` until it is ``clearance_m`` from the palm (within
    `PALM_GAP_TOL_M`; up to `PALM_PLACE_STEPS` steps, each by the missing gap). One step gains
    only the missing gap times the cosine between the normal and the direction from the
    palm's nearest point (Alex/Psyonic: a 30 mm ball 2 mm from the palm by one step was 1.09
    mm from its thumb base, and the fingers' compliance let the palm carry it palm up).
    A hand without palm geometry: unchanged."""
    n = np.asarray(palm_normal, dtype=float)
    for _ in range(PALM_PLACE_STEPS):
        d = state.palm_object_distance(placed)
        if d is None or d >= clearance_m - PALM_GAP_TOL_M:
            break
        placed = placed.replaced(position=[float(v) for v in np.asarray(placed.position, dtype=float) + (clearance_m - d) * n])
    return placed


_BACK_OFF: dict = {}
#: Answers `cannot_back_off` remembers (per process; the oldest half dropped beyond this).
BACK_OFF_CACHE = 4096


def cannot_back_off(hand, obj: GraspObject, q_finger, finger: str) -> bool:
    """`planner.retreat.retreat_blocked` (a finger held against the object by its own joint
    limits), remembered for the same hand, object pose and finger joints: the fixed-pose
    sampler asks it of the closed draw it picks, and `planner.synthesis` again of the same
    closed finger once the candidate is realized (the same closing procedure, the same q)."""
    key = (id(hand), finger, np.asarray(q_finger, dtype=float).tobytes(), obj.shape, tuple(obj.size),
           tuple(obj.position), tuple(obj.quat_xyzw))
    hit = _BACK_OFF.get(key)
    if hit is None:
        if len(_BACK_OFF) >= BACK_OFF_CACHE:
            for k in list(_BACK_OFF)[: BACK_OFF_CACHE // 2]:
                del _BACK_OFF[k]
        hit = _BACK_OFF[key] = bool(retreat_blocked(hand, obj, q_finger, finger))
    return hit


def _closing_end(hand, finger) -> np.ndarray:
    """(n_joints,) the limit each of the finger's joints closes toward: its upper one, the
    lower one for a joint closing downward (`planner.hand.Finger.closes_toward`); a pre-shape
    draws its closing joints part of the way from open toward it."""
    idx = list(finger.q_index)
    down = np.array([j in finger.close_lower for j in finger.joints])
    return np.where(down, hand.lower[idx], hand.upper[idx])


def _finger_draw(hand, finger, q, rng) -> None:
    """One random pre-shape of ``finger`` written into q: the joints that do not close uniform
    in their range, the closing joints `_PRESHAPE_CLOSE` of the way from open to their limit."""
    idx = np.array(finger.q_index)
    lo, hi = hand.lower[idx], hand.upper[idx]
    closing = np.array([j in finger.close_joints for j in finger.joints])
    start = np.clip(np.asarray(hand.q_open, dtype=float)[idx], lo, hi)
    frac = rng.uniform(*_PRESHAPE_CLOSE, size=len(idx))
    q[idx] = np.where(closing, start + frac * (_closing_end(hand, finger) - start), rng.uniform(lo, hi))
    couple_finger(finger, q)  # the drivers drawn, the followers by the coupling


def _fixed_candidate(hand, fingers, obj: GraspObject, rng, obj_radius, alphas, palm: bool, mu: float = 1.0):
    """`sample_candidate` with the object pose fixed: each finger's pre-shape is drawn, and
    closed onto the object, on its own, then one closed draw per finger is chosen.

    Why: a finger's closing motion depends on its own joints only (`Hand.close_finger` moves
    one finger against the object), but a whole-hand draw needs every finger to pass near the
    object in the same draw: with k fingers each near with probability p, p^k (four fingers
    at a grasp's own pose: 352 of 360 attempts had a sweep missing the object).

    Per finger: `FIXED_PRESHAPES_PER_ATTEMPT` random pre-shapes (`_finger_draw`); those whose
    centre curve (`_sweep`) passes within `SWEEP_REACH` inner radii of the object centre are
    closed (the first `FIXED_CLOSED_PER_FINGER` of them, as `closes_onto` does: from open
    closing joints when the pre-shape starts inside), and a draw is kept when the finger then
    touches (`contact_patches`): its closed joints and its patch's mean unit normal. Choice: a
    random touching draw per finger, then, while the mean of the chosen fingers' normals (and
    the palm's push with ``palm``) is longer than ``mu`` (equal pushes cannot balance with
    friction ``mu`` then), coordinate descent toward the shortest mean (`_opposition`: forces
    that cancel can squeeze the object), at most `FIXED_DESCENT_ROUNDS` rounds; a finger that
    cannot back off its contact (`cannot_back_off`) takes its next-best draw; a finger whose
    closed links collide with another chosen finger or the palm takes its next-best draw that
    does not (`_untangle`). When they cannot be untangled, the same from the random draws
    without the limit: the best balance."""
    centre = np.asarray(obj.position, dtype=float)
    base = np.array(hand.q_open, dtype=float)
    N, Q, C = [], [], []  # per finger: patch normals (k, 3), pre-shapes, closed joints of its touching draws
    for f in fingers:
        idx = list(f.q_index)
        cidx = [hand.joint_names.index(j) for j in f.close_joints]
        nn, qs, cs = [], [], []
        near = 0
        for _ in range(FIXED_PRESHAPES_PER_ATTEMPT):
            q = base.copy()
            _finger_draw(hand, f, q, rng)
            c, _ = _sweep(hand, f, q, alphas, CENTRE_OFFSET * obj_radius)
            if float(np.min(_norm3(c - centre))) > SWEEP_REACH * obj_radius:
                continue
            near += 1
            if near > FIXED_CLOSED_PER_FINGER:
                break
            if hand.state(q).finger_penetrates(obj, f.name, object_sphere(obj)):
                q[cidx] = np.clip(base[cidx], hand.lower[cidx], hand.upper[cidx])
                couple_finger(f, q)
                if hand.state(q).finger_penetrates(obj, f.name, object_sphere(obj)):
                    continue
            pre = q[idx].copy()
            q = np.asarray(hand.close_finger(f, q, obj), dtype=float)
            patch = contact_patches(hand, q, obj, fingers=[f.name]).get(f.name)
            if patch is None:
                continue
            m = np.mean(np.asarray(patch[1], dtype=float), axis=0)
            nn.append(m / max(float(np.linalg.norm(m)), 1e-12))
            qs.append(pre)
            cs.append(q[idx].copy())
        if not nn:
            return obj, None, Rejection(("a finger misses the object" if near else "sweeps miss the object") + (
                " on the palm" if palm else ""), [f.name])
        N.append(np.array(nn))
        Q.append(qs)
        C.append(cs)
    extra = np.asarray(hand.palm_normal, dtype=float) if palm else np.zeros(3)
    m = len(fingers) + int(palm)
    F = len(fingers)
    pick = [int(rng.integers(len(c))) for c in C]  # a random touching draw per finger
    blocked = [set() for _ in fingers]  # draws whose finger could not back off its contact

    def scores(i):
        rest = extra + sum((N[j][pick[j]] for j in range(F) if j != i), np.zeros(3))
        out = _norm3((rest + N[i]) / m) if m > 1 else np.zeros(len(N[i]))
        out[list(blocked[i])] = np.inf
        return out

    # With equal normal forces, equilibrium needs the friction to cancel the normals'
    # resultant: |sum n| <= mu m (each tangential force at most mu times its normal one).
    # First the random draws, descending only while they cannot balance (diversity: the best
    # balance alone gives the same grasp attempt after attempt); when their fingers cannot be
    # untangled, the best balance (spread fingers collide less).
    for limit in (mu * m, 0.0):
        for _ in range(FIXED_DESCENT_ROUNDS if m > 1 else 0):
            for i in rng.permutation(F):
                if np.linalg.norm(extra + sum(N[j][pick[j]] for j in range(F))) <= limit:
                    break
                pick[i] = int(np.argmin(scores(i)))
        for i, f in enumerate(fingers):
            # a finger held against the object by its own joint limits can never let go
            # (`planner.synthesis` rejects it): its next-best draw, checked the same way
            while cannot_back_off(hand, obj, C[i][pick[i]], f.name):
                blocked[i].add(pick[i])
                if len(blocked[i]) == len(C[i]):
                    return obj, None, Rejection("a finger cannot back off its contact", [f.name])
                pick[i] = int(np.argmin(scores(i)))
        if F < 2 or _untangle(hand, fingers, pick, C, scores):
            return obj, {f.name: Q[i][k].copy() for i, (f, k) in enumerate(zip(fingers, pick))}, ""
    return obj, None, "fingers overlap each other or the palm"


def _untangle(hand, fingers, pick, C, scores) -> bool:
    """Replace, in ``pick``, the draw of a finger whose closed links (``C``: per finger, the
    closed joints of each draw) collide with another chosen finger or the palm by its
    best-scored (``scores(i)``) draw that does not, keeping the others; fingers from the last.
    False when some still collide."""
    link_finger = {lk: f.name for f in fingers for lk in hand.fingers[f.name].links}

    def colliding(sel) -> set:
        q = np.array(hand.q_open, dtype=float)
        for i, f in enumerate(fingers):
            q[list(f.q_index)] = C[i][sel[i]]
        hit = set()
        for a, b, _ in collisions(hand, q, None, fingers=[f.name for f in fingers]):
            hit.update(link_finger[x] for x in (a, b) if x in link_finger)
        return hit

    hit = colliding(pick)
    for i, f in reversed(list(enumerate(fingers))):
        if not hit:
            return True
        if f.name not in hit:
            continue
        sc = scores(i)
        for k in [int(k) for k in np.argsort(sc, kind="stable") if k != pick[i] and np.isfinite(sc[k])]:
            trial = list(pick)
            trial[i] = k
            now = colliding(trial)
            if f.name not in now:
                pick[i], hit = k, now
                break
    return not hit


def _rotation_onto(a, b) -> np.ndarray:
    """The smallest rotation matrix taking unit vector ``a`` onto unit vector ``b``."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    v, c = np.cross(a, b), float(a @ b)
    if c < -1.0 + 1e-12:  # opposite: half a turn about any axis across a
        e = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        k = np.cross(a, e)
        k /= np.linalg.norm(k)
        return 2.0 * np.outer(k, k) - np.eye(3)
    K = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return np.eye(3) + K + K @ K / (1.0 + c)


def _resting_rotation(rng, obj: GraspObject, normal) -> np.ndarray | None:
    """How an object lies on the palm: the rotation (palm frame from object frame) that puts
    a box on one of its six faces, a cylinder on its side (2/3 of the draws, the axis along
    a random direction across the palm normal) or on an end (the face's outward normal
    against the palm normal); the identity for a sphere; None (any orientation) for a mesh."""
    if obj.shape == "sphere":
        return np.eye(3)
    if obj.shape == "box":
        axis = np.eye(3)[rng.integers(3)] * rng.choice([-1.0, 1.0])
    elif obj.shape == "cylinder":
        if rng.uniform() < 2.0 / 3.0:  # on its side: the outward normal of a side line, across the axis
            th = rng.uniform(0.0, 2.0 * np.pi)
            axis = np.array([np.cos(th), np.sin(th), 0.0])
        else:
            axis = np.array([0.0, 0.0, rng.choice([-1.0, 1.0])])
    else:
        return None
    return _rotation_onto(axis, -np.asarray(normal, dtype=float))


def _half_height(obj: GraspObject, R, normal) -> float:
    """How far the object (rotated by R) reaches from its centre toward the palm, along
    minus the palm normal: the centre's height above a flat palm it rests on."""
    d = np.asarray(R).T @ -np.asarray(normal, dtype=float)     # the direction, object frame
    if obj.shape == "sphere":
        return float(obj.size[0])
    if obj.shape == "box":
        return float(0.5 * np.abs(d) @ np.asarray(obj.size, dtype=float))
    r, length = obj.size                                        # cylinder, axis z
    return float(r * np.sqrt(max(0.0, 1.0 - d[2] ** 2)) + 0.5 * length * abs(d[2]))


def _resting_quat(rng, obj: GraspObject, R_rest, normal) -> list[float]:
    """The orientation of one pose try on the palm: ``R_rest`` (`_resting_rotation`) turned
    about the palm normal by a random angle (a sphere's identity; any orientation for None)."""
    from scipy.spatial.transform import Rotation

    if R_rest is None:
        return _random_quat(rng)
    if obj.shape == "sphere":
        return [0.0, 0.0, 0.0, 1.0]
    n = np.asarray(normal, dtype=float)
    R = Rotation.from_rotvec(rng.uniform(0.0, 2.0 * np.pi) * n).as_matrix() @ R_rest
    return [float(v) for v in Rotation.from_matrix(R).as_quat()]


def _score(swept, centre, obj_radius, palm_normal=None) -> float:
    """Lower is better: the largest distance from ``centre`` to a finger's centre curve, in
    inner radii, plus `OPPOSITION_WEIGHT` x `_opposition` of the pad normals there (and of
    the palm's push, along ``palm_normal``, when given)."""
    gaps, normals = [], []
    for c, n in swept:
        d = _norm3(c - centre)
        k = int(np.argmin(d))
        gaps.append(float(d[k]))
        normals.append(n[k])
    if palm_normal is not None:
        normals.append(np.asarray(palm_normal, dtype=float))
    return max(gaps) / obj_radius + (OPPOSITION_WEIGHT * _opposition(normals) if len(normals) > 1 else 0.0)


def inner_radius(obj: GraspObject) -> float:
    """Half the smallest extent of the object (m): how close a pad sweep must pass to its centre."""
    return 0.5 * float(np.min(obj.extents))


def closes_onto(hand, fingers, obj, preshape, palm: bool = False):
    """Cheap pre-filter: close the fingers; (q, "") when every one (and with ``palm`` the
    palm) touches the object (a contact link within `TOUCH_TOL_M`: where
    `planner.contacts.contact_patches` finds a patch), else (None, why).

    The fingers close one by one in the hand's finger order from ``q_open``, each from its
    pre-shape, as `planner.realization.realize` closes the posture fingers of the file made
    from ``preshape``: the same q, so `Hand.close_finger` answers realize from memory. A
    finger that starts inside the object starts from open closing joints (``preshape``
    updated)."""
    q = np.array(hand.q_open, dtype=float)
    base = q.copy()
    for f in fingers:  # (each finger's start depends on its own joints only)
        q[list(f.q_index)] = preshape[f.name]
        if hand.state(q).finger_penetrates(obj, f.name, object_sphere(obj)):
            # the closing procedure starts from a finger free of the object: open its closing joints
            cidx = [hand.joint_names.index(j) for j in f.close_joints]
            q[cidx] = np.clip(np.asarray(hand.q_open)[cidx], hand.lower[cidx], hand.upper[cidx])
            couple_finger(f, q)
            if hand.state(q).finger_penetrates(obj, f.name, object_sphere(obj)):
                return None, Rejection("a finger starts inside the object", [f.name])
            preshape[f.name] = q[list(f.q_index)].copy()
    chosen = {f.name for f in fingers}
    q = base
    for name, f in hand.fingers.items():
        if name in chosen:
            q[list(f.q_index)] = preshape[name]
            q = np.asarray(hand.close_finger(f, q, obj), dtype=float)
    state = hand.state(q)
    missing = [f.name for f in fingers
               if not any(ld.distance_m <= TOUCH_TOL_M for ld in state.link_object(obj, f.contact_links).values())]
    if missing:
        return None, Rejection("a finger misses the object", missing)
    if palm and not any(ld.distance_m <= TOUCH_TOL_M
                        for ld in state.link_object(obj, hand.collision.finger_links(None)).values()):
        return None, "object not against the palm"
    return q, ""
