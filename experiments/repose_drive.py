"""Reposing along the path the fingers can follow: the grasp Jacobian picks the object motion.

`planner.repose.repose` moves the object along the straight path in SE(3) and asks every
holding finger to follow its contact. A finger with fewer free coordinates than its contact
point has (the iCub's coupled fingers: two or three) can follow only some motions, and a
finger near a joint limit only those away from it: on most grasp pairs whose poses differ the
straight path loses a contact at its first waypoint. Here the object's motion is chosen, step
by step, among those every holding finger can follow:

    minimize  |W (nu - nu_goal)|^2 + LAMBDA |dq|^2    subject to  J_i dq_i = v_i(nu)  (each finger i)

``nu`` = (v, w) the object's twist (palm frame, about its origin), ``v_i(nu) = v + w x (c_i - t)``
the velocity of finger i's outermost contact point ``c_i`` carried with the object (sticking),
``J_i`` the finger's contact-point Jacobian over its free coordinates (couplings included), a
joint at a limit moving further into it removed. ``nu_goal`` points at the target pose, one
waypoint's length (`planner.repose.STEP_M` / `STEP_RAD`); ``W`` weighs 1 rad as
`planner.repose.STEP_M` / `STEP_RAD` m. The constraint is solved exactly (its null space), so
the chosen motion is one the fingers' joints produce to first order; each waypoint then corrects
the first-order drift with the same follower as the straight path (`planner.repose._follow`) and
is judged by the same waypoint test (`planner.repose.waypoint`). The path ends at the target
(within `planner.repose.STEP_M` it is joined straight) or stops when a step gains less than
`MIN_GAIN` of the remaining distance (the fingers cannot take the object closer): a
`planner.errors.MotionError` says how far it got. Work-bounded: at most `MAX_STEPS_FACTOR` times
the straight path's waypoints.

Not used by ``regrasp plan`` (measured, exp10 ``--reach`` and a trial inside
`planner.pose_search`'s legs plus a meeting-pose candidate): on the 24 exp10 pose pairs its
median reach is 0.09 of the way (the straight path's 0), it reaches the other pose in 1 of 48
moves (the straight path too), the two grasps driven toward each other meet on 2 pairs, and at
those meeting poses the gait search fails (a thumb nothing opposes without it): 0/24 planned as
before, 0/11 more of exp9's refusals, the refusals slower. It is the measurement for the next
step (gaits between drives).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from planner.errors import MotionError
from planner.repose import (FOLLOW_TOL_M, STEP_M, STEP_RAD, FollowError, Reposing, _follow, _holds, pose_distance,
                            waypoint)

#: Weight of the joints' motion against the object's (per rad, in m of object motion): a
#: tie-breaker among the motions that reach as far.
LAMBDA = 1e-4
#: A step whose motion toward the target gains less than this fraction of the step asked for
#: ends the path: the fingers cannot take the object closer.
MIN_GAIN = 0.2
#: At most this many times the straight path's waypoints.
MAX_STEPS_FACTOR = 4


def _skew(r) -> np.ndarray:
    return np.array([[0.0, -r[2], r[1]], [r[2], 0.0, -r[0]], [-r[1], r[0], 0.0]])


def _goal_twist(T, T_goal) -> tuple[np.ndarray, float]:
    """(the twist toward ``T_goal`` scaled to one waypoint, the remaining distance in waypoints)."""
    dp = T_goal[:3, 3] - T[:3, 3]
    dw = Rotation.from_matrix(T_goal[:3, :3] @ T[:3, :3].T).as_rotvec()
    left = max(np.linalg.norm(dp) / STEP_M, np.linalg.norm(dw) / STEP_RAD)
    return np.r_[dp, dw] / max(left, 1.0), float(left)


def _apply(T, nu) -> np.ndarray:
    out = np.array(T, dtype=float)
    out[:3, :3] = Rotation.from_rotvec(nu[3:]).as_matrix() @ T[:3, :3]
    out[:3, 3] = T[:3, 3] + nu[:3]
    return out


def _twist(hand, q, T, holds, lo, hi, nu_goal) -> np.ndarray:
    """The object twist closest to ``nu_goal`` (weighted) that every holding finger's outermost
    contact can follow to first order (the constraint's null space); a free coordinate at a
    joint limit that the solution would drive further into it is held, and the twist solved
    again."""
    state = hand.state(q)
    blocks = []  # (J over the free coordinates, contact point relative to the object origin, at lower, at upper)
    for finger, h in holds.items():
        f = hand.fingers[finger]
        idx = np.asarray(f.q_index)
        link, p_link, p_obj = h[0][0], h[0][1], h[0][2]
        J = f.reduce(np.asarray(state.frame_jacobian(link, p_link), float)[:3][:, list(idx)])
        ji = np.asarray(f.free_index)
        blocks.append((J, T[:3, :3] @ p_obj, q[ji] <= lo[ji] + 1e-6, q[ji] >= hi[ji] - 1e-6))
    held = [np.zeros(J.shape[1], bool) for J, *_ in blocks]
    for _ in range(2):
        nu, rates = _solve(blocks, held, nu_goal)
        more = False
        for i, ((_, _, at_lo, at_hi), r) in enumerate(zip(blocks, rates)):
            push = (at_lo & (r < 0)) | (at_hi & (r > 0))
            if np.any(push & ~held[i]):
                held[i] |= push
                more = True
        if not more:
            break
    return nu


def _solve(blocks, held, nu_goal):
    """(twist, the free coordinates' rates per finger) of `_twist`'s least squares with the
    ``held`` coordinates fixed."""
    W = np.r_[np.ones(3), np.full(3, STEP_M / STEP_RAD)]
    sizes = [J.shape[1] for J, *_ in blocks]
    n = 6 + sum(sizes)
    A = np.zeros((3 * len(blocks) + sum(int(np.sum(h)) for h in held), n))
    k, r = 6, 3 * len(blocks)
    for i, (J, c, _, _) in enumerate(blocks):
        A[3 * i:3 * i + 3, :3] = np.eye(3)
        A[3 * i:3 * i + 3, 3:6] = -_skew(c)  # w x c = -[c]x w (c relative to the object's origin)
        A[3 * i:3 * i + 3, k:k + J.shape[1]] = -J
        for j in np.flatnonzero(held[i]):
            A[r, k + j] = 1.0
            r += 1
        k += J.shape[1]
    _, s, Vt = np.linalg.svd(A)
    rank = int(np.sum(s > 1e-9 * max(1.0, s[0] if len(s) else 1.0)))
    N = Vt[rank:].T
    if N.shape[1] == 0:
        return np.zeros(6), [np.zeros(m) for m in sizes]
    B = np.zeros((n, n))
    B[:6, :6] = np.diag(W)
    B[6:, 6:] = math.sqrt(LAMBDA) * np.eye(n - 6)
    b = np.r_[W * nu_goal, np.zeros(n - 6)]
    x = N @ np.linalg.lstsq(B @ N, b, rcond=None)[0]
    rates, k = [], 6
    for m in sizes:
        rates.append(x[k:k + m])
        k += m
    return x[:6], rates


def drive(grasp, T_target, options, *, palm_at_end: bool = True, still: tuple[str, ...] = ()) -> Reposing:
    """Move the object of ``grasp`` toward ``T_target`` along the motion its holding fingers can
    follow (module docstring); the `Reposing`, ending exactly at ``T_target``.

    Raises:
        MotionError (`FollowError` naming the finger when one cannot keep its contact): the
            fingers cannot take the object there; the message says how far it got and why.
    """
    move, err = drive_toward(grasp, T_target, options, palm_at_end=palm_at_end, still=still)
    if err is not None:
        raise err
    return move


def drive_toward(grasp, T_target, options, *, palm_at_end: bool = True, still: tuple[str, ...] = ()
                 ) -> tuple[Reposing | None, MotionError | None]:
    """`drive` as far as it goes: (the move up to its last valid waypoint, None when it did not
    leave the start; why it stopped, None when it reached ``T_target``)."""
    poses, qs, ends = [], [], []
    try:
        move = _drive(grasp, T_target, options, palm_at_end, still, poses, qs, ends)
        return move, None
    except MotionError as err:
        if len(poses) < 2:
            return None, err
        holds = tuple(f for f in _holds(grasp) if f not in still)
        return Reposing(np.array(qs), np.array(poses), holds, grasp, ends[-1]), err


def _drive(grasp, T_target, options, palm_at_end, still, poses, qs, ends) -> Reposing:
    hand = grasp.hand
    lo, hi = np.asarray(hand.lower, float), np.asarray(hand.upper, float)
    holds = {f: h for f, h in _holds(grasp).items() if f not in still}
    if not holds:
        raise MotionError("no finger touches the object: nothing can move it")
    twist = float(grasp.friction.gamma) > 0.0
    T0, Tg = np.asarray(grasp.obj.T_palm_obj, float), np.asarray(T_target, float)
    _, left0 = _goal_twist(T0, Tg)
    T, q = T0.copy(), np.array(grasp.q, dtype=float)
    poses.append(T0.copy())
    qs.append(q.copy())
    ends.append(grasp)
    for _ in range(MAX_STEPS_FACTOR * max(1, int(math.ceil(left0)))):
        nu_goal, left = _goal_twist(T, Tg)
        if left <= 1.0 + 1e-9:
            T_next = Tg
        else:
            nu = _twist(hand, q, T, holds, lo, hi, nu_goal)
            gain = float(nu_goal @ np.r_[nu[:3], nu[3:] * (STEP_M / STEP_RAD) ** 2]) / float(
                nu_goal @ np.r_[nu_goal[:3], nu_goal[3:] * (STEP_M / STEP_RAD) ** 2])
            if gain < MIN_GAIN:
                mm, deg = pose_distance(T, Tg)
                raise MotionError(_got(T0, T, Tg) + f"the fingers cannot take the object closer ({mm:.1f} mm / "
                                  f"{deg:.1f} deg left)")
            # one waypoint at most: scaled so neither part exceeds a step
            scale = min(1.0, STEP_M / max(np.linalg.norm(nu[:3]), 1e-12), STEP_RAD / max(np.linalg.norm(nu[3:]), 1e-12))
            T_next = _apply(T, nu * scale)
        for finger, h in holds.items():
            q, worst, _ = _follow(hand, finger, q, h, T_next, lo, hi, twist)
            if worst > 2 * FOLLOW_TOL_M:
                raise FollowError(_got(T0, T_next, Tg) + f"{finger} cannot keep its contact on the object (off by "
                                  f"{worst * 1e3:.2f} mm)", finger)
        last = T_next is Tg
        ends.append(waypoint(grasp, T_next, q, holds, still, options, _got(T0, T_next, Tg), last=last,
                             palm_at_end=palm_at_end))
        poses.append(np.array(T_next, dtype=float))
        qs.append(q.copy())
        T = np.array(T_next, dtype=float)
        if last:
            return Reposing(np.array(qs), np.array(poses), tuple(holds), grasp, ends[-1])
    raise MotionError(_got(T0, T, Tg) + f"no path within {MAX_STEPS_FACTOR}x the straight path's waypoints")


def _got(T0, T, Tg) -> str:
    mm, deg = pose_distance(T0, T)
    mm_g, deg_g = pose_distance(T0, Tg)
    return f"reposing along the fingers' motion, {mm:.1f} mm / {deg:.1f} deg of {mm_g:.1f} mm / {deg_g:.1f} deg: "


#: `meeting`: rounds of alternating drives (each grasp toward the other's latest pose).
MEET_ROUNDS = 4


def _join(a: Reposing | None, b: Reposing) -> Reposing:
    """Two moves one after the other (``b`` starts where ``a`` ends) as one."""
    if a is None:
        return b
    return Reposing(np.vstack([a.q_path, b.q_path[1:]]), np.concatenate([a.poses, b.poses[1:]]), a.fingers, a.start,
                    b.end)


def meeting(initial, final, options) -> tuple[np.ndarray, Reposing | None, Reposing | None] | None:
    """A pose both grasps' holding fingers carry the object to: each grasp in turn is driven
    (`drive_toward`) toward the other's latest pose, at most `MEET_ROUNDS` rounds, until one
    reaches it. Returns (that pose, the initial grasp's move there, the final grasp's move
    there; None for a grasp that did not move), or None when the drives stall apart or a
    grasp's holding fingers change on the way."""
    moves = {"a": None, "b": None}
    now = {"a": initial, "b": final}
    for _ in range(MEET_ROUNDS):
        progress = False
        for me, other in (("a", "b"), ("b", "a")):
            g = now[me]
            mv, err = drive_toward(g, now[other].obj.T_palm_obj, options)
            if mv is not None:
                if moves[me] is not None and tuple(mv.fingers) != tuple(moves[me].fingers):
                    return None
                moves[me] = _join(moves[me], mv)
                now[me] = mv.end
                progress = True
            if err is None:
                return np.asarray(now[other].obj.T_palm_obj, float), moves["a"], moves["b"]
        if not progress:
            return None
    return None
