"""Reposing: the hand moves the object with every holding contact fixed on it.

A reposing move keeps each touching link's contact point where it is on the object
(sticking) while the object follows a short straight path in SE(3) (position along the line,
orientation along the shortest rotation). Waypoints are spaced at most ``STEP_M`` and
``STEP_RAD`` apart; at each one every holding finger follows by damped least squares over
its free coordinates (coupled joints included, `planner.hand.Finger.step`; a coordinate a
joint limit stops held there and the others solved again, `_bounded_step`), each contact
link's contact point (fixed in the link) reaching the object point it holds. Then the
waypoint is measured like a grasp (`planner.realization.measure`, the object at the
waypoint's pose) and judged by the planner's own state test (`state_reason`: fingers
not colliding, force closure under the plan's contact model and, with gravity, the load
held in every planned direction within the joints' torque limits). Contacts are points
fixed in their links: rolling over a curved pad is not modelled, so a move that needs it
is refused rather than planned wrong.

The palm cannot move: it holds only at a waypoint where the object does not move relative
to it, i.e. at the ends. Leaving the palm is a move whose first waypoint takes the object
off it; resting on the palm is one whose last waypoint puts it there (`settle_pose`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from types import MappingProxyType

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from planner.errors import MotionError
from planner.model import PALM
from planner.realization import PENETRATION_TOL_M, RealizedGrasp, measure

#: Largest translation of the object between two waypoints, m.
STEP_M = 0.001
#: Largest rotation of the object between two waypoints, rad.
STEP_RAD = math.radians(2.0)
#: A finger follows its contacts when every contact point is within this of its target, m.
FOLLOW_TOL_M = 0.0002
#: Damped least-squares iterations per waypoint.
IK_ITERS = 30
#: Damping of the least-squares steps, m.
DAMPING = 1e-3
#: The replay controller's posture springs (`planner.sim.controller.POSTURE_SHARE`, kept
#: equal by a test) push a finger along its path with at most this fraction of the squeeze
#: ``F``: what drives the object in a reposing move (`drive_refusal`).
POSTURE_SHARE = 0.3
#: Weight of a finger's inner contacts against its outermost one in `_follow`: they pull
#: the joints toward keeping them too, without forbidding a solution that rolls them.
INNER_WEIGHT = 0.3
#: Weight of the outermost contact's twist (rad) against its position (m) in `_follow`: the
#: soft contact's torsion arm, a twist of 1 rad slipping its patch by about this much. The
#: twist is asked for, not required: the replay holds boxes turned 10 deg whose middle finger
#: twisted 12 deg against the object (2.4 deg of drift): the other contacts overcome it.
TWIST_WEIGHT_M = 0.004


class FollowError(MotionError):
    """A reposing move a finger cannot take part in (``finger``): it cannot keep its contact
    on the moving object, loses it, or one of its links goes into the object. Without that
    finger (lifted first) the move may work."""

    def __init__(self, message: str, finger: str):
        self.finger = finger
        super().__init__(message)


@dataclass(frozen=True)
class Reposing:
    """A reposing move: whole-hand joint values and object poses per waypoint.

    Attributes:
        q_path: (m, nq) joint values, first the start grasp's.
        poses: (m, 4, 4) object poses in the palm frame.
        fingers: the fingers that hold (and move) during it.
        start, end: the grasp measured at the first and the last waypoint.
    """

    q_path: np.ndarray
    poses: np.ndarray
    fingers: tuple[str, ...]
    start: RealizedGrasp
    end: RealizedGrasp

    @property
    def distance_mm(self) -> float:
        return 1000.0 * float(np.linalg.norm(self.poses[-1][:3, 3] - self.poses[0][:3, 3]))

    @property
    def angle_deg(self) -> float:
        return pose_distance(self.poses[0], self.poses[-1])[1]

    def reversed(self) -> "Reposing":
        return Reposing(self.q_path[::-1].copy(), self.poses[::-1].copy(), self.fingers, self.end, self.start)


def pose_distance(Ta, Tb) -> tuple[float, float]:
    """(mm, deg) between two poses (4, 4)."""
    Ta, Tb = np.asarray(Ta, float), np.asarray(Tb, float)
    mm = 1000.0 * float(np.linalg.norm(Tb[:3, 3] - Ta[:3, 3]))
    deg = math.degrees(float(np.linalg.norm(Rotation.from_matrix(Tb[:3, :3] @ Ta[:3, :3].T).as_rotvec())))
    return mm, deg


def object_path(Ta, Tb) -> np.ndarray:
    """Poses (m, 4, 4) from ``Ta`` to ``Tb``, at most `STEP_M` and `STEP_RAD` apart (m >= 2)."""
    Ta, Tb = np.asarray(Ta, float), np.asarray(Tb, float)
    mm, deg = pose_distance(Ta, Tb)
    n = max(1, int(math.ceil(max(mm / 1000.0 / STEP_M, math.radians(deg) / STEP_RAD) - 1e-9)))
    rots = Slerp([0.0, 1.0], Rotation.from_matrix(np.stack([Ta[:3, :3], Tb[:3, :3]])))(np.linspace(0.0, 1.0, n + 1))
    out = np.repeat(np.eye(4)[None], n + 1, axis=0)
    out[:, :3, :3] = rots.as_matrix()
    for k, s in enumerate(np.linspace(0.0, 1.0, n + 1)):
        out[k, :3, 3] = (1.0 - s) * Ta[:3, 3] + s * Tb[:3, 3]
    out[0], out[-1] = Ta, Tb
    return out


def at_pose(grasp: RealizedGrasp, T, q=None, palm: str | None = None) -> RealizedGrasp:
    """``grasp`` re-measured with the object at ``T`` (and the hand at ``q``, default its own):
    the spec's object moved, its palm mode ``palm`` (default the spec's)."""
    spec = replace(grasp.spec, object=grasp.obj.with_pose(np.asarray(T, float)), palm=palm or grasp.spec.palm)
    return measure(spec, grasp.hand, grasp.q if q is None else q)


def state_reason(grasp: RealizedGrasp, options) -> str | None:
    """Why ``grasp`` is not a valid state of a plan made with ``options`` (the search's own
    test, `planner.graph.Evaluator.blocked_reason`, on a problem of this grasp alone), or None."""
    from planner.graph import Evaluator  # deferred: networkx
    from planner.slots import build_problem

    problem = build_problem(grasp, grasp, replace(options, intermediate=0))
    ev = Evaluator(problem)
    ev.evaluate([problem.start])
    return ev.blocked_reason(problem.start)


def _holds(grasp: RealizedGrasp) -> dict[str, list[tuple]]:
    """finger -> [(link, p_link (link frame), p_obj (object frame), the link's orientation in
    the object frame (3, 3), the inward contact normal (object frame))] of its touching links, the
    outermost first (the last of the finger's ``contact_links`` that touches: its tip side).
    A finger holding with two phalanges has fewer joints than the six coordinates both
    contact points would fix (the iCub's fingers: two or three, coupled), so only the
    outermost contact must stick (`_follow`); the inner ones follow as well as the joints
    allow (weighted by `INNER_WEIGHT`), may roll or come off, and every waypoint is judged
    with the contacts it measures."""
    state = grasp.hand.state(grasp.q)
    T = np.asarray(grasp.obj.T_palm_obj, float)
    out: dict[str, list] = {}
    for c in grasp.contacts:
        if c.finger is None:
            continue
        p_palm = T[:3, :3] @ np.asarray(c.point, float) + T[:3, 3]
        T_link = state.link_pose(c.link)
        p_link = T_link[:3, :3].T @ (p_palm - T_link[:3, 3])
        R_rel = T[:3, :3].T @ T_link[:3, :3]  # the link's orientation in the object frame
        out.setdefault(c.finger, []).append((c.link, p_link, np.asarray(c.point, float), R_rel,
                                             np.asarray(c.normal, float)))
    for finger, items in out.items():  # the outermost first: the one that must stick
        order = grasp.hand.fingers[finger].contact_links
        out[finger] = sorted(items, key=lambda it: -(order.index(it[0]) if it[0] in order else -1))
    return out


def drive_refusal(grasp: RealizedGrasp, T_target) -> str | None:
    """Why the fingers cannot turn the object to ``T_target``, or None.

    A turn by angle theta about the move's screw axis (unit ``w``) twists every soft contact
    against its torsional friction: at most ``gamma F |n_i . w|`` each (``n_i`` its normal,
    ``F`` the squeeze). The fingers drive it by pushing along their paths, each with at most
    ``POSTURE_SHARE F`` at its distance ``d_i`` from the axis. The move is refused when
    ``POSTURE_SHARE sum d_i < gamma sum |n_i . w|``: a pinch turning its object about the line
    between its two pads (both twist, no lever) needs a third finger at least
    ``2 gamma / POSTURE_SHARE`` (27 mm at gamma 4 mm) off that line. A translation is always
    driven (every contact pushes along it)."""
    gamma = float(grasp.friction.gamma)
    Ta, Tb = np.asarray(grasp.obj.T_palm_obj, float), np.asarray(T_target, float)
    dT = Tb @ np.linalg.inv(Ta)
    rv = Rotation.from_matrix(dT[:3, :3]).as_rotvec()
    theta = float(np.linalg.norm(rv))
    if gamma <= 0.0 or theta < 1e-9:
        return None
    w = rv / theta
    # a point of the screw axis: (I - R) c = t, least squares (c is defined up to the axis)
    c = np.linalg.lstsq(np.eye(3) - dT[:3, :3], dT[:3, 3], rcond=None)[0]
    cs = [x for x in grasp.contacts if x.finger is not None]
    if not cs:
        return None
    p = np.array([Ta[:3, :3] @ x.point + Ta[:3, 3] for x in cs])
    n = np.array([Ta[:3, :3] @ x.normal for x in cs])
    drive = POSTURE_SHARE * float(np.sum(np.linalg.norm(np.cross(p - c, w), axis=1)))
    resist = gamma * float(np.sum(np.abs(n @ w)))
    if drive >= resist:
        return None
    return (f"turning the object {math.degrees(theta):.1f} deg about [{w[0]:+.2f} {w[1]:+.2f} {w[2]:+.2f}] twists its "
            f"contacts against their torsional friction ({resist * 1e3:.1f} mm x F) more than the fingers' levers can "
            f"drive ({drive * 1e3:.1f} mm x F, {POSTURE_SHARE:g} of the squeeze each): a finger farther from that "
            f"axis can")


def _follow(hand, finger, q, holds, T, lo, hi, twist: bool) -> tuple[np.ndarray, float, float]:
    """Damped least squares: the finger's contact points onto their object points at pose
    ``T`` (and, with ``twist``, the outermost contact link turning with the object about the
    contact normal, weighted so that 1 rad costs `TWIST_WEIGHT_M`); returns (q, residual of the
    outermost point m, its twist against the object about the normal rad)."""
    f = hand.fingers[finger]
    idx = list(f.q_index)
    targets = [T[:3, :3] @ h[2] + T[:3, 3] for h in holds]
    qf = q[idx].copy()
    worst, turn = math.inf, 0.0
    for _ in range(IK_ITERS):
        q[idx] = qf
        state = hand.state(q)
        err, rows = [], []
        for k, ((link, p_link, _, R_rel, n_obj), target) in enumerate(zip(holds, targets)):
            w = 1.0 if k == 0 else INNER_WEIGHT
            T_link = state.link_pose(link)
            J = np.asarray(state.frame_jacobian(link, p_link), float)
            err.append(w * (target - (T_link[:3, :3] @ p_link + T_link[:3, 3])))
            rows.append(w * f.reduce(J[:3][:, idx]))
            if k == 0:
                n = T[:3, :3] @ n_obj
                turn = float(n @ Rotation.from_matrix(T[:3, :3] @ R_rel @ T_link[:3, :3].T).as_rotvec())
                if twist:
                    err.append(np.array([TWIST_WEIGHT_M * turn]))
                    rows.append(TWIST_WEIGHT_M * f.reduce(n @ J[3:][:, idx])[None, :])
        worst = float(np.linalg.norm(err[0]))  # the outermost contact must stick
        if worst <= FOLLOW_TOL_M:
            break
        qf = _bounded_step(f, qf, np.vstack(rows), np.concatenate(err), lo[idx], hi[idx])
    q[idx] = qf
    return q, worst, abs(turn)


def _bounded_step(f, qf, J, e, lo, hi) -> np.ndarray:
    """One damped least-squares step of finger ``f`` from ``qf`` (its joints) toward the error
    ``e`` (J: its Jacobian over the free coordinates), within the joint limits ``lo``, ``hi``.

    A free coordinate whose step a limit cuts takes the step to its limit and is held there,
    and the step is solved again over the others for the error left (an active set):
    clipping the unconstrained step would lose the part the cut coordinate was to give and
    leave the others short of it, so that a finger with a joint at its limit stalled where its
    other joints can still make the motion."""
    n = J.shape[1]
    active = np.ones(n, dtype=bool)
    moved = f.reduce(np.eye(len(qf)))  # (n_joints, n_free): a free coordinate's effect on the joints
    base = f.step(qf, np.zeros(n), lo, hi)  # (qf within its limits, coupled)
    free = list(f.free)
    dz = np.zeros(n)
    for _ in range(n):
        Ja = J[:, active]
        r = e - J[:, ~active] @ dz[~active]  # the error the held coordinates leave
        dz[active] = Ja.T @ np.linalg.solve(Ja @ Ja.T + DAMPING**2 * np.eye(len(e)), r)
        qn = f.step(qf, dz, lo, hi)
        want = moved @ dz  # the joints' change the step asked for
        cut = np.abs((qn - base) - want) > 1e-12 + 1e-6 * np.abs(want)  # joints a limit cut
        held = active & (np.abs(moved[cut]).sum(axis=0) > 0.0)
        if not held.any():
            break
        dz[held] = (qn - base)[free][held]  # as far as the limit lets it
        active &= ~held
        if not active.any():
            break
    return f.step(qf, dz, lo, hi)


def repose(grasp: RealizedGrasp, T_target, options, *, palm_at_end: bool = True, still: tuple[str, ...] = ()
           ) -> Reposing:
    """Move the object of ``grasp`` to ``T_target`` with every holding contact fixed on it.

    Args:
        grasp: the grasp at the start (its touching fingers hold throughout).
        T_target: the object's pose at the end (4, 4), palm frame.
        options: the plan's `planner.options.PlanOptions` (contact model, gravity, hold factor).
        palm_at_end: the palm may hold at the end pose (where the object touches it); the
            spec's ``palm: free`` always keeps it out.
        still: touching fingers that do not follow: they keep their joints while the others
            carry the object away from them (a finger that cannot back off its contact is
            released so; reversed, the object is carried onto it).

    Returns:
        The `Reposing`.

    Raises:
        MotionError: a finger cannot follow its contacts, a waypoint collides or is no valid
            state; the message names the waypoint (mm, deg along the path) and why.
    """
    hand = grasp.hand
    lo, hi = np.asarray(hand.lower, float), np.asarray(hand.upper, float)
    holds = {f: h for f, h in _holds(grasp).items() if f not in still}
    if not holds:
        raise MotionError("no finger touches the object: nothing can move it")
    why = drive_refusal(grasp, T_target)
    if why is not None:
        raise MotionError(why)
    poses = object_path(grasp.obj.T_palm_obj, T_target)
    twist = float(grasp.friction.gamma) > 0.0  # soft contacts: torsional friction
    q = np.array(grasp.q, dtype=float)
    qs, start, end = [q.copy()], grasp, grasp
    m = len(poses)
    for k in range(1, m):
        T = poses[k]
        for finger, h in holds.items():
            q, worst, _ = _follow(hand, finger, q, h, T, lo, hi, twist)
            if worst > 2 * FOLLOW_TOL_M:
                at = [j for j, i in zip(hand.fingers[finger].joints, hand.fingers[finger].q_index)
                      if min(q[i] - lo[i], hi[i] - q[i]) < 1e-3]
                raise FollowError(_where(poses, k) + f"{finger} cannot keep its contact on the object (off by "
                                  f"{worst * 1e3:.2f} mm" + (f"; at their limits: {', '.join(at)}" if at else "") + ")",
                                  finger)
        end = waypoint(grasp, T, q, holds, still, options, _where(poses, k), last=k == m - 1, palm_at_end=palm_at_end)
        qs.append(q.copy())
    return Reposing(np.array(qs), poses, tuple(holds), start, end)


def waypoint(grasp: RealizedGrasp, T, q, holds, still, options, where: str, *, last: bool,
             palm_at_end: bool) -> RealizedGrasp:
    """A reposing waypoint measured (the object at ``T``, the hand at ``q``) and judged: every
    holding finger still touches, no link deeper than `PENETRATION_TOL_M` in the object or
    another link, a valid state of the plan (`state_reason`). The grasp there, or FollowError
    (naming a holding finger that lost the object or went into it) / MotionError, prefixed by
    ``where``. The palm holds only where the object rests on it: at the end (``last``), if it
    touches there and ``palm_at_end``."""
    hand = grasp.hand
    g = at_pose(grasp, T, q, palm=grasp.spec.palm if last and palm_at_end else "free")
    if still:  # a finger the object is carried away from holds nothing (it may graze it at first)
        g = replace(g, patches=MappingProxyType({f: v for f, v in g.patches.items() if f not in still}))
    lost = sorted(set(holds) - set(g.patches))
    if lost:
        raise FollowError(where + f"{', '.join(lost)} loses the object", lost[0])
    deep = [(a, b, d) for a, b, d in g.collisions if d > PENETRATION_TOL_M]
    if deep:
        a, b, d = max(deep, key=lambda x: x[2])
        words = where + f"collision {a} - {b} {d * 1e3:.2f} mm deep"
        owner = next((f for f in holds for x in (a, b) if x in hand.fingers[f].contact_links), None)
        if owner is not None:  # a holding finger in the object's way: without it the move may work
            raise FollowError(words, owner)
        raise MotionError(words)
    why = state_reason(g, options)
    if why is not None:
        raise MotionError(where + why)
    return g


def _where(poses, k: int) -> str:
    mm, deg = pose_distance(poses[0], poses[k])
    return f"reposing, {mm:.1f} mm / {deg:.1f} deg along the object's path (waypoint {k}/{len(poses) - 1}): "


def settle_pose(grasp: RealizedGrasp, touch_m: float) -> tuple[np.ndarray, float] | None:
    """The object's pose moved straight toward the palm until it is ``touch_m`` from it (a
    translation along the line between the nearest palm and object points), and the gap it
    closes, m; None when the hand has no palm geometry or the object already rests on it."""
    if PALM in grasp.patches:
        return None
    hand, obj = grasp.hand, grasp.obj
    dist = hand.state(grasp.q).link_object(obj, hand.collision.finger_links(None))
    if not dist:
        return None
    ld = min(dist.values(), key=lambda x: x.distance_m)
    d = np.asarray(ld.p_obj_palm, float) - np.asarray(ld.p_link_palm, float)
    gap = float(ld.distance_m)
    if not np.linalg.norm(d) > 1e-9 or gap <= touch_m:
        return None
    T = np.array(obj.T_palm_obj, dtype=float)
    T[:3, 3] -= (gap - touch_m) * d / np.linalg.norm(d)
    return T, gap - touch_m


