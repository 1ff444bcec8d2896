"""Lift and land: a finger backing off a contact along its normal (no OMPL).

A lift retreats the contact point a few mm along the outward normal with damped
least-squares steps of its Jacobian (first keeping the link's orientation, then the point
only), else pushes every link near the object away along its own normal, else opens the
finger; a land is a lift from the target contact, reversed (`planner.motion.plan_gait_step`).
`retreat_blocked` says whether a contact can be left at all, whatever the other fingers do
(used by synthesis and the planner to drop such contacts before any path is planned).
"""

from __future__ import annotations

import math

import numpy as np

from planner.errors import InputError, MotionError
from planner.finger_scene import DEFAULT_CLEARANCE_M, DEFAULT_TOUCH_TOL_M, FingerScene, densify, finger_of

DEFAULT_LIFT_M = 0.005
"""Retreat of the contact point along the outward normal in a lift (and approach in a land)."""
MAX_LIFT_M = 0.03
"""A lift gives up when the finger is not clear of the object after this retreat."""
_ROTATION_WEIGHT_M = 0.03
"""Rigid retreat: a link rotation error of 1 rad weighs as much as this translation error."""
_LIFT_LAG_M = 0.002
"""A retreat step whose contact point trails its target by more than this is stuck (it slides)."""
_REPEL_MARGIN_M = 0.003
STEP_M = 0.0005
"""Retreat of the contact point per damped least-squares step (`retreat`'s default)."""
"""`_retreat_repel` pushes away every link within the clearance plus this of the object."""


# ------------------------------------------------------------------ lift and land


def _inward_normal(scene: FingerScene, p_object_palm: np.ndarray) -> np.ndarray:
    """Inward contact normal (palm frame) at the object point nearest to the finger."""
    T_palm_obj = scene.T_palm_obj
    R = T_palm_obj[:3, :3]
    p_obj = R.T @ (p_object_palm - T_palm_obj[:3, 3])
    _, n_out_obj, _ = scene.obj.closest_surface(p_obj)
    n_in = -(R @ np.asarray(n_out_obj, dtype=float))
    return n_in / np.linalg.norm(n_in)


def _retreat_dls(
    scene: FingerScene,
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

    def point(st):
        T = st.finger_link_poses(scene.finger.name)[k_link]
        return T[:3, :3] @ p_link + T[:3, 3]

    # one hand state per configuration: its Jacobian, the point and the clearance read it
    st = scene.state(a)
    p0 = point(st)
    rows = 6 if rotation_weight_m > 0 else 3
    W = np.array([1.0, 1.0, 1.0] + [rotation_weight_m] * 3)[:rows, None]
    path = [a.copy()]
    q = a.copy()
    s = 0.0
    damp = None
    while s < MAX_LIFT_M:
        s += step_m
        target = p0 - s * n_in
        for _ in range(3):
            J = np.asarray(st.frame_jacobian(link, p_link), dtype=float)[:rows][:, scene.idx]
            J = scene.finger.reduce(J)  # over the finger's free coordinates (coupled joints)
            if damp is None:
                damp = damping**2 * np.eye(J.shape[1])
            err = np.zeros(rows)
            err[:3] = target - point(st)  # orientation target: no rotation (zero rows)
            Jw = W * J
            ew = W[:, 0] * err
            dq = np.linalg.solve(Jw.T @ Jw + damp, Jw.T @ ew)
            q = scene.finger.step(q, dq, lo, hi)
            st = scene.state(q)
        if float(np.dot(p0 - point(st), n_in)) < s - _LIFT_LAG_M or not scene.is_clear(st, touch_margin):
            return None
        path.append(q.copy())
        if s >= lift_m - 1e-12 and scene.is_clear(st, clearance_m):
            return path
    return None


def _retreat_repel(
    scene: FingerScene,
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
    name = scene.finger.name
    st = scene.state(q)  # one hand state per configuration (distances, link poses, Jacobians)
    near = st.object_distances(scene.obj, name)
    best, since_best = -math.inf, 0
    for _ in range(int(MAX_LIFT_M / step_m)):
        rows = []
        poses = st.finger_link_poses(name)
        for d, link, p_link_palm, p_object_palm in near:
            if d >= clearance_m + _REPEL_MARGIN_M and link != contact_link:
                continue
            n_out = -_inward_normal(scene, p_object_palm)
            T = poses[scene.moving_links.index(link)]
            p_link = T[:3, :3].T @ (np.asarray(p_link_palm, dtype=float) - T[:3, 3])
            J = scene.finger.reduce(np.asarray(st.frame_jacobian(link, p_link), dtype=float)[:3][:, scene.idx])
            rows.append(n_out @ J)
        A = np.array(rows)
        dq = A.T @ np.linalg.solve(A @ A.T + damping**2 * np.eye(len(A)), np.full(len(A), step_m))
        q = scene.finger.step(q, dq, lo, hi)
        st = scene.state(q)
        if not scene.is_clear(st, touch_margin):
            return None
        path.append(q.copy())
        near = st.object_distances(scene.obj, name)
        distances = {}  # each link's distance, as far as it is asked to keep clearance_m (FingerScene.required)
        for d, link, _, _ in near:
            need = scene.required(link, clearance_m)
            distances[link] = min(d if need == clearance_m else d - need + clearance_m, distances.get(link, math.inf))
        lifted = min(d for d, link, _, _ in near if link == contact_link) >= scene.required(contact_link, lift_m)
        if lifted and min(distances.values()) >= clearance_m:
            return path
        progress = min(distances.values())
        if progress > best + 1e-5:
            best, since_best = progress, 0
        else:
            since_best += 1
            if since_best >= 5:  # joint limits: no link gets farther any more
                return None
    return None


def retreat(
    scene: FingerScene,
    a: np.ndarray,
    n_in_palm,
    *,
    lift_m: float,
    clearance_m: float,
    resolution_rad: float,
    what: str,
    step_m: float = STEP_M,
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
    link, n_in, p_link, touch_margin = _lift_start(scene, a, n_in_palm)
    for rotation_weight_m in (_ROTATION_WEIGHT_M, 0.0):
        path = _retreat_dls(
            scene, a, n_in, link, p_link, rotation_weight_m=rotation_weight_m,
            touch_margin=touch_margin, lift_m=lift_m, clearance_m=clearance_m, step_m=step_m,
        )
        if path is not None:
            return densify(np.array(path), resolution_rad)
    path = _retreat_repel(
        scene, a, link, touch_margin=touch_margin, lift_m=lift_m, clearance_m=clearance_m, step_m=step_m,
    )
    if path is not None:
        return densify(np.array(path), resolution_rad)
    path = _open_finger(scene, a, link, touch_margin=touch_margin, lift_m=lift_m, clearance_m=clearance_m,
                        resolution_rad=resolution_rad)
    if path is not None:
        return path
    raise _stuck(scene, link, lift_m, what)


def _lift_start(scene: FingerScene, a: np.ndarray, n_in_palm) -> tuple:
    """What every way of backing off starts from: the contact link (the finger's link nearest
    to the object at ``a``), the unit inward normal (``n_in_palm``, or the object's at the
    nearest point), the contact point on the link (link frame) and the touch margin (never
    deeper than the contact)."""
    name = scene.finger.name
    d0, link, p_palm, p_object_palm = scene.object_distance(a)
    n_in = _inward_normal(scene, p_object_palm) if n_in_palm is None else np.asarray(n_in_palm, float)
    norm = np.linalg.norm(n_in)
    if n_in.shape != (3,) or not np.isfinite(norm) or norm < 1e-9:
        raise InputError(f"contact normal of finger {name} must be a non-zero 3-vector; got {n_in_palm!r}")
    n_in = n_in / norm
    touch_margin = min(-scene.touch_tol_m, d0 - 1e-6)  # never deeper than the contact
    return link, n_in, scene.point_on_link(a, link, p_palm), touch_margin


def _open_finger(scene: FingerScene, a: np.ndarray, link: str, *, touch_margin: float, lift_m: float,
                 clearance_m: float, resolution_rad: float) -> np.ndarray | None:
    """`retreat`'s fallback: open the finger along a joint-space line, first only the closing
    (flexion) joints, keeping abduction/opposition, then toward the whole open posture; the
    dense path up to the first configuration lifted and clear, or None."""
    hand, name = scene.hand, scene.finger.name
    lo = np.asarray(hand.lower, dtype=float)[scene.idx]
    hi = np.asarray(hand.upper, dtype=float)[scene.idx]
    q_open = np.clip(np.asarray(hand.q_open, dtype=float)[scene.idx], lo, hi)
    closing = np.isin(np.asarray(scene.finger.joints), np.asarray(scene.finger.close_joints or scene.finger.joints))
    for target in (scene.finger.couple(np.where(closing, q_open, a)), q_open):
        line = densify(np.array([a, target]), resolution_rad)
        for k, q in enumerate(line[1:], start=1):
            st = scene.state(q)  # one hand state per configuration: clearance and distances read it
            if not scene.is_clear(st, touch_margin):
                break
            if scene.is_lifted(st, link, lift_m, clearance_m):
                return line[: k + 1]
    return None


def _stuck(scene: FingerScene, link: str, lift_m: float, what: str) -> MotionError:
    return MotionError(
        f"finger {scene.finger.name}: cannot {what} (contact on {link}): neither a {lift_m * 1000:.1f} mm "
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

    The lift of `plan_gait_step` (`retreat`, the same margins) from the finger's contact
    configuration ``q_finger`` with every other finger at its open posture: a contact whose
    finger is held against the object by its own joint limits (a thumb pressed sideways at
    full opposition) cannot be left, nor landed on (a landing is a lift reversed), in any
    state. Returns the reason, naming the finger, the link and the joints at a limit.
    """
    f = finger_of(hand, finger)
    q_ref = np.array(hand.q_open, dtype=float)
    q_ref[list(f.q_index)] = q_finger
    scene = FingerScene(hand, obj, q_ref, finger, touch_tol_m)
    a = np.asarray(q_finger, dtype=float)
    # whether `retreat` finds a path: any of its ways will do, the cheapest first (opening
    # the finger is free for most contacts and costs the least; the retreats then in its order)
    link, n_in, p_link, touch_margin = _lift_start(scene, a, None)
    kw = dict(touch_margin=touch_margin, lift_m=lift_m, clearance_m=clearance_m)
    if (_open_finger(scene, a, link, resolution_rad=resolution_rad, **kw) is not None
            or any(_retreat_dls(scene, a, n_in, link, p_link, rotation_weight_m=w, step_m=STEP_M, **kw) is not None
                   for w in (_ROTATION_WEIGHT_M, 0.0))
            or _retreat_repel(scene, a, link, step_m=STEP_M, **kw) is not None):
        return None
    err = _stuck(scene, link, lift_m, "back off this contact")
    lo = np.asarray(hand.lower, dtype=float)[scene.idx]
    hi = np.asarray(hand.upper, dtype=float)[scene.idx]
    tol = max(resolution_rad, 0.05 * float(np.max(hi - lo)))
    at = [f"{j} {a[k]:.2f} rad (limit {lo[k] if a[k] - lo[k] < hi[k] - a[k] else hi[k]:.2f})"
          for k, j in enumerate(f.joints) if min(a[k] - lo[k], hi[k] - a[k]) <= tol]
    # links nearer the object than a lifted finger keeps them (`FingerScene.required`) even
    # with the finger open: no way of backing off lifts them
    need = {link: scene.required(link, scene.touch_tol_m) for link in scene.open_distances()}
    stay = sorted((d, link) for link, d in scene.open_distances().items() if d < need[link])
    near = "; ".join(f"{link} {'is' if d >= 0 else 'goes'} {abs(d) * 1e3:.2f} mm {'from' if d >= 0 else 'inside'} the object "
                     f"(a lifted finger keeps it {need[link] * 1e3:.1f} mm from it)" for d, link in stay)
    return (f"{err}, even with every other finger open" + (f"; near their limits: {', '.join(at)}" if at else "")
            + (f"; at the finger's open posture too, {near}: move the object away from it" if stay else ""))
