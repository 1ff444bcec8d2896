"""Placing a finger: inverse kinematics (`ik_solve`) and the closing procedure
(`close_finger`, thesis eqs. 8-9).

Both move only one finger's joints of a `planner.hand.Hand` and update one
`planner.kinematics.Kinematics` per call explicitly (the closing procedure reads it through
`planner.collision.HandState.on`). `Hand.ik`, `Hand.ik_solve` and `Hand.close_finger` call
them. All points and normals are in the palm frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from planner.collision import HandState, object_sphere
from planner.errors import InputError, KinematicsError
from planner.kinematics import Kinematics, checked_q

IK_TOL_M = 5e-4          # accepted fingertip error
_IK_GOAL_M = 1e-6        # error at which the iterations stop


@dataclass(frozen=True)
class IKResult:
    """Outcome of `Hand.ik_solve`.

    Attributes:
        q: (nq,) configuration (only the finger's joints changed).
        position_error_m: distance from the placed point to the target.
        normal_error_rad: angle between the pad's outward normal and the requested contact
            normal, or None when no normal was requested (or the pad has none).
        normal_dropped: the target was reached only with the normal task switched off.
    """

    q: np.ndarray
    position_error_m: float
    normal_error_rad: float | None = None
    normal_dropped: bool = False


class UnreachableError(KinematicsError):
    """An IK target out of reach, with the closest reachable point (palm frame).

    Attributes:
        target_palm, closest_palm: (3,) the target and the closest point the link reached.
        direction_palm: (3,) unit vector from the target toward that point: move the target this way.
        distance_m: how far (m).
    """

    def __init__(self, message, *, target_palm, closest_palm, direction_palm, distance_m):
        super().__init__(message)
        self.target_palm = np.asarray(target_palm, dtype=float)
        self.closest_palm = np.asarray(closest_palm, dtype=float)
        self.direction_palm = np.asarray(direction_palm, dtype=float)
        self.distance_m = float(distance_m)


def ik_solve(hand, finger, target_palm, q0, link: str | None = None, p_link=None, normal_palm=None,
             restarts: int = 8, max_iter: int = 150, seed: int = 0, n_link=None) -> IKResult:
    """Place a point of a finger link on a target; only that finger's joints move.

    Damped least squares with joint clamping, restarted from q0, the open posture, mid-range
    and seeded random starts. The pad normal alignment is a secondary task in the null space
    of the position task (best effort; the fingers have at most 4 joints). When no start
    reaches the target with the normal task on (it can drag the clamped joints away from the
    position), the starts are run again position-only: ``IKResult.normal_dropped`` says so.

    Args:
        hand: the `planner.hand.Hand`.
        finger: finger name or Finger.
        target_palm: (3,) target point in the palm frame.
        q0: (nq,) start; other fingers' joints are kept.
        link: link to place (default: the finger's pad link).
        p_link: (3,) point in the link frame (default: the pad point when ``link`` is the pad
            link, else the link origin).
        normal_palm: (3,) optional contact normal INTO the object in the palm frame: the link's
            outward pad normal is turned toward it.
        n_link: (3,) the link-frame direction turned toward ``normal_palm`` (default: the
            finger's pad normal; `planner.realization` leans it to pick the end of a capsule).
    Returns:
        `IKResult`: q (nq,) with the point within 0.5 mm (`IK_TOL_M`) of the target, the
        position and normal errors, whether the normal task was dropped.
    Raises:
        UnreachableError: no start reached the target within 0.5 mm inside the joint limits, even
            position-only; it carries the closest point reached and the direction to move the target.
    """
    f = hand.finger(finger)
    q0 = checked_q(hand.model.nq, q0)
    target = np.asarray(target_palm, dtype=float)
    if target.shape != (3,) or not np.all(np.isfinite(target)):
        raise InputError(f"target_palm must be 3 finite numbers, got {target_palm!r}")
    link = link or f.pad_link
    fid = hand.collision.kinematic_model.frame_id(link)
    if link == f.pad_link and p_link is None:
        p_link = np.array(f.pad_p_link)
    p_link = np.zeros(3) if p_link is None else np.asarray(p_link, dtype=float)
    if n_link is not None:
        n_link = np.asarray(n_link, dtype=float)
        n_link = n_link / np.linalg.norm(n_link)
    elif f.pad_n_link is not None:
        n_link = np.array(f.pad_n_link)
    else:
        n_link = None
    n_des = None
    if normal_palm is not None:
        n_des = np.asarray(normal_palm, dtype=float)
        if n_des.shape != (3,) or np.linalg.norm(n_des) < 1e-9:
            raise InputError(f"normal_palm must be a non-zero 3-vector, got {normal_palm!r}")
        n_des = n_des / np.linalg.norm(n_des)
        if n_link is None:
            n_des = None
    # the finger's free coordinates (its drivers and uncoupled joints): the solver moves
    # them, the followers are set from them (`planner.hand.Finger.couple`)
    idx = np.array(f.free_index)
    lo, hi = hand.lower[idx], hand.upper[idx]
    rng = np.random.default_rng(seed)
    starts = [q0[idx], np.array(f.q_open)[list(f.free)], 0.5 * (lo + hi)]
    starts += [rng.uniform(lo, hi) for _ in range(max(0, restarts - len(starts)))]
    kin = hand.kinematics(q0)  # the one kinematic state every iteration updates
    best = _ik_starts(kin, starts, q0, f, lo, hi, fid, p_link, target, n_link, n_des, max_iter)
    dropped = False
    if best[0] >= IK_TOL_M and n_des is not None:
        pos_only = _ik_starts(kin, starts, q0, f, lo, hi, fid, p_link, target, None, None, max_iter)
        dropped = pos_only[0] < IK_TOL_M
        if dropped or pos_only[0] < best[0]:
            best = pos_only
    err, nerr, q, p = best
    if err >= IK_TOL_M:
        gap = p - target
        dist = float(np.linalg.norm(gap))
        direction = gap / dist if dist > 0 else np.zeros(3)
        raise UnreachableError(
            f"finger {f.name!r}: target {np.round(target, 4).tolist()} m (palm frame) is out of "
            f"reach of {link}; closest approach {err * 1e3:.1f} mm after {len(starts)} starts "
            f"(pad normal task {'on, then off' if n_des is not None else 'off'}); move the target "
            f"{dist * 1e3:.1f} mm along {np.round(direction, 3).tolist()} (palm frame)",
            target_palm=target, closest_palm=p, direction_palm=direction, distance_m=dist)
    if n_des is not None and dropped:
        nerr = float(np.arccos(np.clip((kin.update(q).frame_jacobian(fid, p_link)[2] @ n_link) @ n_des, -1.0, 1.0)))
    return IKResult(q=q, position_error_m=float(err), normal_error_rad=float(nerr) if n_des is not None else None,
                    normal_dropped=dropped)


def close_finger(hand, finger, q, obj, steps: int = 20, backoff: float = 1e-3) -> np.ndarray:
    """Close a finger onto the object, thesis eqs. (8)-(9).

    Every closing joint moves from its value in ``q`` toward its closing limit (the upper one,
    or the lower one for a joint the hand.yaml's ``close_toward`` says so of:
    `planner.hand.Finger.closes_toward`) by the same fraction alpha of its remaining range:
    alpha_n = alpha_{n-1} +/- (1/2)^n, n = 1..steps (+ while the finger is free, - while it
    penetrates the object), then the closing joints are opened (toward their other limit) by
    ``backoff`` (0.1 %) of their range until the finger is free of penetration. The
    finger then touches the object within about 0.1 % of its range, or is fully closed if it
    never met it. A finger that already penetrates at ``q`` (e.g. placed by IK) is only opened
    by 0.1 % steps until free.

    Args:
        hand: the `planner.hand.Hand`.
        finger: finger name or Finger.
        q: (nq,) start posture (the finger free of the object).
        obj: a planner.objects.GraspObject (pose T_palm_obj).
    A coupled finger closes its drivers (those of its closing joints, or of the followers among
    them); the followers move by the coupling (`planner.hand.Finger.couple`).

    Returns:
        q: (nq,) with only the finger's closing joints (and their followers) changed.
    """
    f = hand.finger(finger)
    q = couple_finger(f, checked_q(hand.model.nq, q).copy())
    cidx = np.array(closing_drivers(hand, f))
    down = closing_signs(hand, f) < 0  # closing toward the lower limit
    lo, hi = hand.lower[cidx], hand.upper[cidx]
    start = q[cidx].copy()
    # (for a joint closing upward exactly the expressions of the upper-only procedure: the
    # bundled hands' plans are unchanged to the last digit)
    span = np.where(down, np.minimum(lo - start, 0.0), np.maximum(hi - start, 0.0))

    def at(alpha):
        qa = q.copy()
        qa[cidx] = start + alpha * span
        return couple_finger(f, qa)

    kin = hand.kinematics(q)  # the one kinematic state every step updates
    sphere = object_sphere(obj)

    def penetration(qa):  # None when free, else (geometry, depth m) (`HandState.finger_penetration`)
        return HandState.on(hand.collision, kin.update(qa)).finger_penetration(obj, f.name, sphere)

    def colliding(alpha):
        return penetration(at(alpha)) is not None

    step = backoff * (hand.upper[cidx] - hand.lower[cidx])
    reach = opening_reach(hand, f, cidx, step)

    def still_inside(found) -> int:
        """Opening steps after this one certain to leave the finger inside: a convex
        geometry ``depth`` deep moves at most ``reach`` per step (penetration depth is
        1-Lipschitz in the largest displacement), so it stays in for fewer than
        depth / reach steps (less a slack on coal's depth). The scan that checks every step
        stops at the same step."""
        i, depth = found
        v = None if reach is None else reach.get(i)
        safe = depth * (1.0 - DEPTH_SLACK[0]) - DEPTH_SLACK[1]
        if v is None or safe <= 0.0:
            return 0
        return OPENING_STEPS_MAX if v <= 0.0 else max(0, int(math.ceil(safe / v)) - 1)

    left = 0  # opening steps `still_inside` proved inside, not yet taken

    def inside(qa) -> bool:  # an opening finger still penetrates: proved before, or checked now
        nonlocal left
        if left:
            left -= 1
            return True
        found = penetration(qa)
        if found is None:
            return False
        left = still_inside(found)
        return True

    if colliding(0.0):
        # already penetrating (e.g. an IK placement): open by 0.1 % steps until free
        qb = q.copy()
        for _ in range(int(np.ceil(1.0 / backoff))):
            if not inside(qb):
                return qb
            qb[cidx] = np.where(down, np.minimum(qb[cidx] + step, hi), np.maximum(qb[cidx] - step, lo))
            qb = couple_finger(f, qb)
        return qb
    alpha = 0.0
    for n in range(1, steps + 1):
        if colliding(alpha):
            alpha -= 0.5 ** n
        else:
            alpha = min(alpha + 0.5 ** n, 1.0)
    qc = at(alpha)
    while inside(qc) and np.any(np.where(down, qc[cidx] < start, qc[cidx] > start)):
        qc[cidx] = np.where(down, np.minimum(qc[cidx] + step, start), np.maximum(qc[cidx] - step, start))
        qc = couple_finger(f, qc)
    return qc


#: Slack on a penetration depth before it bounds how long an opening finger stays inside:
#: relative, and absolute (m); coal's depth of two convex shapes is exact to about 1e-6 m.
DEPTH_SLACK = (1e-3, 1e-5)
#: `still_inside` of a geometry that does not move: more steps than any opening takes.
OPENING_STEPS_MAX = 2 ** 30

_REVOLUTE = ("JointModelRX", "JointModelRY", "JointModelRZ", "JointModelRevoluteUnaligned")
_PRISMATIC = ("JointModelPX", "JointModelPY", "JointModelPZ", "JointModelPrismaticUnaligned")


def opening_reach(hand, f, cidx, step) -> dict[int, float] | None:
    """Geometry index -> how far (m) any point of it can move when the closing joints at
    positions ``cidx`` of q move by at most ``|step|`` each and their followers with them:
    the sum over the moved joints it hangs from of the joint's move times the farthest the
    geometry can lie from its axis (a revolute joint: the lengths of the rigid offsets from
    the joint to the geometry's bounding sphere, plus its radius, whatever the posture) or
    times 1 (a prismatic one). None when a moved joint is of another kind. Cached per finger
    and step."""
    key = (f.name, tuple(int(i) for i in cidx), np.asarray(step, float).tobytes())
    memo = hand.__dict__.setdefault("_opening_reach", {})
    if key in memo:
        return memo[key]
    moved = {int(i): abs(float(s)) for i, s in zip(cidx, step)}
    for fl, d, m, _ in f.coupled:  # a follower moves by the multiplier times its driver
        if f.q_index[d] in moved:
            moved[f.q_index[fl]] = abs(float(m)) * moved[f.q_index[d]]
    model = hand.collision.kinematic_model.model
    out: dict[int, float] | None = {}
    for i in hand.collision.finger_geometries(f.name):
        g = hand.collision.geometries[i]
        a, arm, v = int(g.joint_id), float(np.linalg.norm(g.center)), 0.0
        while a > 0:
            jm = model.joints[a]
            span = range(int(jm.idx_q), int(jm.idx_q) + int(jm.nq))  # its coordinates in q
            if any(k in moved for k in span):
                kind = jm.shortname()
                if jm.nq == 1 and kind in _REVOLUTE:
                    v += moved[span[0]] * (arm + g.radius_m)
                elif jm.nq == 1 and kind in _PRISMATIC:
                    v += moved[span[0]]
                else:
                    out = None
                    break
            arm += float(np.linalg.norm(model.jointPlacements[a].translation))
            a = int(model.parents[a])
        if out is None:
            break
        out[i] = v
    memo[key] = out
    return out


def couple_finger(f, q: np.ndarray) -> np.ndarray:
    """``q`` (nq,) with finger ``f``'s followers set from their drivers, in place (returned);
    nothing is done for a finger without couplings."""
    if f.coupled:
        idx = list(f.q_index)
        q[idx] = f.couple(q[idx])
    return q


def closing_drivers(hand, f) -> list[int]:
    """Positions in q of the joints the closing procedure moves for finger ``f``: its closing
    joints, a follower replaced by its driver (in joint order, each once;
    `planner.hand.Finger.driver_closing`)."""
    return [hand.joint_names.index(j) for j in f.driver_closing()]


def closing_signs(hand, f) -> np.ndarray:
    """The closing direction of each joint `closing_drivers` gives (same order): +1.0 toward
    its upper limit, -1.0 toward its lower one (`planner.hand.Finger.driver_closing`)."""
    return np.array(list(f.driver_closing().values()), dtype=float)


def closing_ends(hand, f) -> tuple[np.ndarray, np.ndarray]:
    """(`closing_drivers` as an array, the limit each closes toward): where the closing
    procedure's alpha = 1 puts them."""
    cidx = np.array(closing_drivers(hand, f))
    return cidx, np.where(closing_signs(hand, f) < 0, hand.lower[cidx], hand.upper[cidx])


def _ik_starts(kin: Kinematics, starts, q0, f, lo, hi, fid, p_link, target, n_link, n_des, max_iter):
    """Best (position error, normal error, q, point reached) over DLS runs from the starts
    (each a value of the finger's free coordinates)."""
    best = None
    idx = np.array(f.free_index)
    for s in starts:
        q = q0.copy()
        q[idx] = np.clip(s, lo, hi)
        q = couple_finger(f, q)
        q, err, nerr, p = _dls(kin, q, f, lo, hi, fid, p_link, target, n_link, n_des, max_iter)
        cand = (err, nerr, q, p)
        if err < IK_TOL_M and (best is None or best[0] >= IK_TOL_M or nerr < best[1] - 1e-6):
            best = cand
        elif best is None or (best[0] >= IK_TOL_M and err < best[0]):
            best = cand
        if best[0] < IK_TOL_M and (n_des is None or best[1] < 0.05):
            break
    return best


def _dls(kin: Kinematics, q, f, lo, hi, fid, p_link, target, n_link, n_des, max_iter):
    """Damped least squares over finger ``f``'s free coordinates from q (coupled): (q, position
    error, normal error, point reached); every iteration updates ``kin`` to its q. The
    Jacobian of a driver is ``J_d + m J_f`` summed over its followers (`Finger.reduce`)."""
    idx = np.array(f.free_index)
    cols = list(f.q_index) if f.coupled else None
    lam2 = 1e-6        # damping^2 (m^2)
    k_n = 0.5          # gain of the normal-alignment task (per iteration)
    err = np.inf
    prev = np.inf
    stall = 0
    for _ in range(max_iter):
        J, p, R = kin.update(q).frame_jacobian(fid, p_link)
        e = target - p
        err = float(np.linalg.norm(e))
        e_n = np.cross(R @ n_link, n_des) if n_des is not None else None
        if err < _IK_GOAL_M and (e_n is None or np.linalg.norm(e_n) < 1e-4):
            break
        # an uncoupled finger's rows as they always were (a copy laid out otherwise takes
        # another BLAS path and changes the last digits of every plan)
        Jf = f.reduce(J[:, cols]) if f.coupled else None
        Jp = Jf[:3] if f.coupled else J[:3, idx]
        A = Jp @ Jp.T + lam2 * np.eye(3)
        dq = Jp.T @ np.linalg.solve(A, e)
        if e_n is not None:
            Jn = Jf[3:] if f.coupled else J[3:, idx]
            Jp_pinv = Jp.T @ np.linalg.inv(A)
            N = np.eye(len(idx)) - Jp_pinv @ Jp
            JnN = Jn @ N
            dq += N @ (JnN.T @ np.linalg.solve(JnN @ JnN.T + 1e-3 * np.eye(3), k_n * e_n - Jn @ dq))
        step = np.max(np.abs(dq))
        if step > 0.3:
            dq *= 0.3 / step
        q_new = q.copy()
        q_new[idx] = np.clip(q[idx] + dq, lo, hi)
        q = couple_finger(f, q_new)
        if err > prev - 1e-7:
            stall += 1
            if stall > 15:
                break
        else:
            stall = 0
        prev = min(prev, err)
    J, p, R = kin.update(q).frame_jacobian(fid, p_link)
    err = float(np.linalg.norm(target - p))
    nerr = 0.0
    if n_des is not None:
        nerr = float(np.arccos(np.clip((R @ n_link) @ n_des, -1.0, 1.0)))
    return q, err, nerr, p
