"""The grip model: what a hand's joints can hold, shared by the planner and the replay.

Force closure says *some* contact forces resist any load. Whether a real hand can produce
them depends on its joints: a finger pushes on the object with a force ``f_c`` at each of
its contacts only if its joints deliver

    tau = g(q) + sum_c J_c(q)^T [f_c ; m_c],          |tau_j| <= tau_max_j for every joint,

where ``g(q)`` holds the finger's own links up against gravity, ``J_c`` is the contact
point's Jacobian over the finger's joints (linear rows for the force, angular rows for the
soft-finger torsion ``m_c = +/- gamma (f_c . n_c) n_c``) and ``tau_max`` the joints'
effort limits (the URDF's ``<limit effort>``, or the hand.yaml's ``effort:``;
`planner.hand.Hand.effort`). Contact forces lie in the soft-finger friction cones (the
16-sided inscribed polygon of `planner.closure.min_grip_force`, with ``mu`` and ``gamma``
scaled by a friction margin) and must balance the load on the object.

Two linear programs (HiGHS) over those constraints:

* `hold_capacity`: the largest multiple ``alpha`` of a load (e.g. the object's weight) the
  joints can hold, and the joint that limits it. A grasp state is valid for execution when
  ``alpha >= HOLD_FACTOR`` in every gravity direction it is planned for.
* `torque_demand`: to hold ``factor`` times the load, the smallest fraction ``u`` of every
  joint's limit that suffices (``u <= 1``: it can), and the joint at ``u tau_max``: what a
  refusal names ("index_2 needs 0.81 N m, limit 0.5 N m").

The replay's controller (`planner.sim.controller`) solves the same constraints at the
simulator's contacts (`torque_rows`, `FRICTION_MARGIN`): one force model.

Numbers, derived rather than tuned:

* ``HOLD_FACTOR = 2``: the hand must hold twice the object's weight. The controller's squeeze
  is the force with which friction alone would hold the weight twice over
  (`planner.sim.controller.SAFETY`, the same constant): a state the joints cannot hold at
  that load cannot be squeezed as the controller squeezes.
* ``FRICTION_MARGIN = 0.75``: forces stay within 3/4 of the friction cone (``mu`` and
  ``gamma``): the simulator's contact points and normals differ from the plan's by the
  links' curvature and the object's small motions; the controller tries the same fraction.
* Joints without an effort limit (none in the URDF, none in hand.yaml) are unbounded: such a
  hand is limited only by friction and an optional per-finger force cap.

This module is pure numpy/scipy over arrays; `finger_statics` is the one function that
reads a hand (its Jacobians and gravity torques), so the graph search stays hand-agnostic.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from planner.closure import GRIP_CONE_SIDES, Friction, contact_wrenches
from planner.errors import InputError, PlannerError

#: Multiple of the object's weight a state must hold (module docstring).
HOLD_FACTOR = 2.0
#: Fraction of ``mu`` and ``gamma`` the grip forces may use (module docstring).
FRICTION_MARGIN = 0.75
#: Capacities are reported up to this multiple of the load (a grasp whose joints the load
#: barely loads, e.g. a finger pushing along its own length, would otherwise be unbounded).
FACTOR_MAX = 1000.0


@dataclass(frozen=True, eq=False)
class FingerStatics:
    """What one finger's joints do at one realized contact (a graph slot), object frame.

    Attributes:
        finger: finger name.
        joints: the finger's joint names, in its joint order.
        jacobians: (n_points, 6, n_joints): per contact point, rows 0-2 the point's linear
            velocity and rows 3-5 the link's angular velocity per joint rate, object frame
            (so ``J^T [f ; m]`` are the joint torques of a force ``f`` and moment ``m`` the
            finger applies there, both in the object frame).
        gravity: (n_joints, 3): joint torques that hold the finger's links per unit gravity
            vector in the object frame (``tau_g = gravity @ g_obj``), N m / (m/s^2).
        effort: (n_joints,) joint torque limits, N m (inf: none).
    """

    finger: str
    joints: tuple[str, ...]
    jacobians: np.ndarray
    gravity: np.ndarray
    effort: np.ndarray

    def __post_init__(self):
        for name in ("jacobians", "gravity", "effort"):
            a = np.array(getattr(self, name), dtype=float)
            a.setflags(write=False)
            object.__setattr__(self, name, a)
        nj = len(self.joints)
        if self.jacobians.ndim != 3 or self.jacobians.shape[1:] != (6, nj):
            raise InputError(f"statics of {self.finger}: jacobians must be (n, 6, {nj}), got {self.jacobians.shape}")
        if self.gravity.shape != (nj, 3) or self.effort.shape != (nj,):
            raise InputError(f"statics of {self.finger}: gravity must be ({nj}, 3) and effort ({nj},)")
        if np.any(np.isnan(self.effort)) or np.any(self.effort <= 0):
            raise InputError(f"statics of {self.finger}: effort limits must be > 0 (inf: none)")


@dataclass(frozen=True)
class Limit:
    """The joint (or force cap) that bounds a grip: ``finger`` and ``joint`` (None for the
    per-finger force cap), the torque it delivers there (N m; N for the cap) and its limit."""

    finger: str
    joint: str | None
    value: float
    limit: float

    def words(self) -> str:
        if self.joint is None:
            return f"{self.finger} presses {self.value:.3g} N (cap {self.limit:.3g} N)"
        return f"{self.finger} joint {self.joint} at {self.value:.3g} N m (limit {self.limit:.3g} N m)"


@dataclass(frozen=True)
class Capacity:
    """`hold_capacity`'s answer: ``factor`` (the largest multiple of the load held; 0 when
    not even the hand's own weight or no multiple is held) and ``limit`` (what bounds it;
    None when the friction cones bound it before any joint, or at ``FACTOR_MAX``)."""

    factor: float
    limit: Limit | None

    def words(self, factor_needed: float | None = None) -> str:
        held = f"holds {self.factor:.3g}x" if self.factor < FACTOR_MAX else f"holds over {FACTOR_MAX:g}x"
        need = "" if factor_needed is None else f" (needs {factor_needed:g}x)"
        by = "" if self.limit is None else f", limited by {self.limit.words()}"
        return f"{held} the load{need}{by}"


@dataclass(frozen=True)
class Demand:
    """`torque_demand`'s answer: ``ratio`` (the smallest fraction of every joint's limit that
    holds the load; inf when no forces in the cones hold it) and the joint at that fraction
    (``limit.value`` = the torque needed)."""

    ratio: float
    limit: Limit | None

    def words(self) -> str:
        if not math.isfinite(self.ratio):
            return "no contact forces inside the friction cones hold it"
        if self.limit is None:
            return "no joint is loaded"
        lim = self.limit
        if lim.joint is None:
            return f"{lim.finger} must press {lim.value:.3g} N (cap {lim.limit:.3g} N)"
        return f"{lim.finger} joint {lim.joint} needs {lim.value:.3g} N m (limit {lim.limit:.3g} N m)"


# --------------------------------------------------------------------------- statics of a hand


def finger_statics(hand, finger: str, q, points_obj, T_palm_obj, effort=None) -> FingerStatics:
    """A finger's contact Jacobians and gravity torques at a configuration, object frame.

    Args:
        hand: `planner.hand.Hand`.
        finger: finger name.
        q: (nq,) hand configuration (only the finger's joints matter).
        points_obj: (n, 3) the finger's contact points, object frame.
        T_palm_obj: (4, 4) object pose in the palm frame.
        effort: (n_joints,) limits to use instead of ``hand.effort``.

    Returns:
        `FingerStatics`; each point's Jacobian is that of the finger's contact link nearest
        to it (a mean contact lies between the touching links' points).
    """
    fg = hand.fingers[finger]
    T = np.asarray(T_palm_obj, dtype=float)
    R = T[:3, :3]
    pts_obj = np.asarray(points_obj, dtype=float).reshape(-1, 3)
    pts_palm = pts_obj @ R.T + T[:3, 3]
    state = hand.state(q)
    links = [l for l in fg.contact_links if l in hand.collision.link_geometries] or [fg.tip_frame]
    on = []
    for pt in pts_palm:
        if len(links) == 1:
            on.append(links[0])
            continue
        dist = [state.point_distance(pt, hand.collision.link_geometries[l]) for l in links]
        on.append(links[int(np.argmin(dist))])
    cols = list(fg.q_index)
    Js = hand.point_jacobians(q, list(zip(on, pts_palm)), angular=True)
    jac = np.array([np.vstack([R.T @ J[:3, cols], R.T @ J[3:, cols]]) for J in Js]).reshape(-1, 6, len(cols))
    G = np.stack([hand.gravity_torques(q, e)[cols] for e in np.eye(3)], axis=1)  # (nj, 3) per unit g_palm
    tau_max = np.asarray(hand.effort, dtype=float)[cols] if effort is None else np.asarray(effort, dtype=float)
    return FingerStatics(finger, tuple(fg.joints), jac, G @ R, tau_max)


# --------------------------------------------------------------------------- the programs


@dataclass(frozen=True)
class _Program:
    """Rows shared by both programs: wrench columns, joint-torque rows, force-cap rows."""

    W: np.ndarray          # (k, 6) rim wrenches (unit normal force each), object frame
    torque: np.ndarray     # (r, k) joint torque per unit of each rim wrench
    tau_g: np.ndarray      # (r,) the hand's own gravity torques
    tau_max: np.ndarray    # (r,) limits (finite ones only)
    names: tuple           # (finger, joint) per torque row
    cap_rows: np.ndarray   # (f, k) each finger's normal force per rim wrench
    fingers: tuple         # finger per cap row


def _program(patches: Mapping[str, tuple], statics: Mapping[str, FingerStatics], friction: Friction,
             gravity_obj, margin: float, cone_sides: int) -> _Program:
    if not isinstance(friction, Friction):
        raise InputError(f"friction must be a Friction, got {type(friction).__name__}")
    if not 0 < margin <= 1:
        raise InputError(f"friction margin must be in (0, 1], got {margin!r}")
    fr = Friction(friction.mu * margin, friction.gamma * margin, int(cone_sides))
    g = np.asarray(gravity_obj, dtype=float).reshape(3)
    blocks, torque, tau_g, tau_max, names, fingers = [], [], [], [], [], []
    per_point = 2 * fr.edges
    for finger, (points, normals) in patches.items():
        P = np.asarray(points, dtype=float).reshape(-1, 3)
        if not len(P):
            continue
        Wf = contact_wrenches(P, normals, fr)  # point-major, 2 * edges rows per point
        blocks.append(Wf)
        fingers.append(finger)
        st = statics.get(finger)
        if st is None:
            torque.append(None)
            continue
        if len(st.jacobians) != len(P):
            raise InputError(f"statics of {finger}: {len(st.jacobians)} Jacobians for {len(P)} contact points")
        pts = np.repeat(P, per_point, axis=0)
        f = Wf[:, :3]
        moment = Wf[:, 3:] - np.cross(pts, f)  # the torsion +/- gamma n applied at the contact
        J = np.repeat(st.jacobians, per_point, axis=0)  # (rows, 6, nj)
        T = np.einsum("rij,ri->jr", J[:, :3], f) + np.einsum("rij,ri->jr", J[:, 3:], moment)  # (nj, rows)
        torque.append((T, st.gravity @ g, st.effort, [(finger, j) for j in st.joints]))
    k = sum(len(b) for b in blocks)
    W = np.vstack(blocks) if blocks else np.zeros((0, 6))
    rows, offset = [], 0
    cap = np.zeros((len(blocks), k))
    for i, (b, t) in enumerate(zip(blocks, torque)):
        cap[i, offset:offset + len(b)] = 1.0
        if t is not None:
            T, tg, tm, nm = t
            finite = np.isfinite(tm)  # an unbounded joint gives no row
            full = np.zeros((len(T), k))
            full[:, offset:offset + len(b)] = T
            rows.append((full[finite], tg[finite], tm[finite], [n for n, ok in zip(nm, finite) if ok]))
        offset += len(b)
    if rows:
        torque_m = np.vstack([r[0] for r in rows])
        tg_all = np.concatenate([r[1] for r in rows])
        tm_all = np.concatenate([r[2] for r in rows])
        nm_all = tuple(n for r in rows for n in r[3])
    else:
        torque_m, tg_all, tm_all, nm_all = np.zeros((0, k)), np.zeros(0), np.zeros(0), ()
    return _Program(W, torque_m, tg_all, tm_all, nm_all, cap, tuple(fingers))


def _lever(W: np.ndarray) -> float:
    """Torque rows are divided by this (m) so that force and torque rows weigh alike."""
    return max(1e-3, float(np.abs(W[:, 3:]).max(initial=0.0)) / max(float(np.abs(W[:, :3]).max(initial=1.0)), 1e-12))


def _solve(c, A_ub, b_ub, A_eq, b_eq, bounds, what: str):
    from scipy.optimize import linprog

    problem = dict(A_ub=A_ub if len(A_ub) else None, b_ub=b_ub if len(A_ub) else None, A_eq=A_eq, b_eq=b_eq,
                   bounds=bounds)
    res = None
    for method in ("highs", "highs-ipm"):
        res = linprog(c, method=method, **problem)
        if res.status == 0:
            return res
        if res.status == 2 or (res.status == 4 and "unbounded or infeasible" in res.message):
            return None
    raise PlannerError(f"{what} LP failed (HiGHS status {res.status}: {res.message}); the answer is unknown")


def _binding(prog: _Program, lam: np.ndarray, force_cap_n: float | None) -> Limit | None:
    """The joint (or cap) closest to its limit at a solution."""
    best, best_ratio = None, 0.0
    if len(prog.tau_max):
        tau = prog.tau_g + prog.torque @ lam
        ratio = np.abs(tau) / prog.tau_max
        i = int(np.argmax(ratio))
        best, best_ratio = Limit(prog.names[i][0], prog.names[i][1], float(abs(tau[i])), float(prog.tau_max[i])), float(ratio[i])
    if force_cap_n is not None and len(prog.cap_rows):
        fn = prog.cap_rows @ lam
        i = int(np.argmax(fn))
        if fn[i] / force_cap_n > best_ratio:
            best, best_ratio = Limit(prog.fingers[i], None, float(fn[i]), float(force_cap_n)), float(fn[i] / force_cap_n)
    return best if best_ratio > 0.98 else None


def _checked_load(load) -> np.ndarray:
    try:
        w = np.asarray(load, dtype=float).reshape(6)
    except (TypeError, ValueError) as err:
        raise InputError(f"load must be 6 numbers [fx fy fz tx ty tz], got {load!r}") from err
    if not np.all(np.isfinite(w)):
        raise InputError(f"load must be finite, got {w.tolist()}")
    return w


def _cap_rows(prog: _Program, force_cap_n: float | None, extra_cols: int):
    if force_cap_n is None or not len(prog.cap_rows):
        return np.zeros((0, len(prog.W) + extra_cols)), np.zeros(0)
    return np.c_[prog.cap_rows, np.zeros((len(prog.cap_rows), extra_cols))], np.full(len(prog.cap_rows), float(force_cap_n))


def hold_capacity(patches: Mapping[str, tuple], statics: Mapping[str, FingerStatics], friction: Friction, load,
                  gravity_obj, *, margin: float = FRICTION_MARGIN, force_cap_n: float | None = None,
                  cone_sides: int = GRIP_CONE_SIDES) -> Capacity:
    """Largest multiple of a load the fingers hold within their joints' limits.

    Solves (HiGHS) ``max alpha`` over rim-wrench weights ``lambda >= 0`` (module docstring):

        sum_j lambda_j w_j + alpha load = 0,
        |tau_g + T lambda| <= tau_max               (every finite joint limit),
        sum_{j of finger i} lambda_j <= force_cap   (every finger, when a cap is given),
        0 <= alpha <= FACTOR_MAX,

    with ``w_j`` the soft-finger rim wrenches of ``friction`` scaled by ``margin`` on a
    ``cone_sides`` polygon, ``T`` the joint torques per unit rim wrench (`FingerStatics`)
    and ``tau_g`` the fingers' own gravity torques for ``gravity_obj``.

    Args:
        patches: finger -> (points (n, 3), normals (n, 3)), object frame, normals inward.
        statics: finger -> `FingerStatics` at the same points (a finger without one has no
            joint limits).
        friction: the grasp's friction (``edges`` unused: ``cone_sides``).
        load: (6,) external wrench on the object, object frame, torque about its origin.
        gravity_obj: (3,) gravity vector, object frame, m/s^2 (the hand's own weight).
        margin: fraction of ``mu`` and ``gamma`` the forces may use.
        force_cap_n: optional per-finger normal force cap, N.
        cone_sides: sides of the inscribed cone polygon.

    Returns:
        `Capacity` (factor 0: not even the fingers' own weight is held within the limits, or
        the contacts cannot push against the load at all).
    """
    w = _checked_load(load)
    prog = _program(patches, statics, friction, gravity_obj, margin, cone_sides)
    k = len(prog.W)
    if k == 0:
        return Capacity(0.0, None)
    L = _lever(prog.W)
    scale = max(float(np.abs(w).max()), 1e-12)
    A_eq = np.c_[prog.W.T, w / scale]
    A_eq[3:] /= L
    b_eq = np.zeros(6)
    A_ub = np.r_[np.c_[prog.torque, np.zeros(len(prog.torque))], np.c_[-prog.torque, np.zeros(len(prog.torque))]]
    b_ub = np.r_[prog.tau_max - prog.tau_g, prog.tau_max + prog.tau_g]
    A_cap, b_cap = _cap_rows(prog, force_cap_n, 1)
    A_ub, b_ub = np.r_[A_ub, A_cap], np.r_[b_ub, b_cap]
    c = np.zeros(k + 1)
    c[k] = -1.0
    alpha_max = FACTOR_MAX * scale
    res = _solve(c, A_ub, b_ub, A_eq, b_eq, [(0, None)] * k + [(0, alpha_max)], "grip capacity")
    if res is None:  # not even lambda = 0: a finger cannot hold itself up
        over = np.abs(prog.tau_g) - prog.tau_max
        i = int(np.argmax(over)) if len(over) else None
        lim = None if i is None else Limit(prog.names[i][0], prog.names[i][1], float(abs(prog.tau_g[i])), float(prog.tau_max[i]))
        return Capacity(0.0, lim)
    alpha = float(res.x[k]) / scale
    lam = res.x[:k]
    limit = None if alpha >= FACTOR_MAX * (1 - 1e-9) else _binding(prog, lam, force_cap_n)
    return Capacity(min(alpha, FACTOR_MAX), limit)


def torque_demand(patches: Mapping[str, tuple], statics: Mapping[str, FingerStatics], friction: Friction, load,
                  gravity_obj, *, factor: float = HOLD_FACTOR, margin: float = FRICTION_MARGIN,
                  force_cap_n: float | None = None, cone_sides: int = GRIP_CONE_SIDES) -> Demand:
    """Smallest fraction ``u`` of every joint's limit with which the fingers hold ``factor``
    times the load: ``min u`` s.t. the forces balance ``factor * load`` inside the cones and
    ``|tau_g + T lambda| <= u tau_max`` (arguments as `hold_capacity`). ``u <= 1``: the
    joints can. The joint at ``u tau_max`` is named with the torque it needs."""
    w = _checked_load(load) * float(factor)
    prog = _program(patches, statics, friction, gravity_obj, margin, cone_sides)
    k = len(prog.W)
    if k == 0:
        return Demand(math.inf, None)
    L = _lever(prog.W)
    A_eq = np.c_[prog.W.T, np.zeros(6)]
    A_eq[3:] /= L
    b_eq = -w.copy()
    b_eq[3:] /= L
    tm = prog.tau_max
    A_ub = np.r_[np.c_[prog.torque, -tm], np.c_[-prog.torque, -tm]]
    b_ub = np.r_[-prog.tau_g, prog.tau_g]
    A_cap, b_cap = _cap_rows(prog, force_cap_n, 1)
    A_ub, b_ub = np.r_[A_ub, A_cap], np.r_[b_ub, b_cap]
    c = np.zeros(k + 1)
    c[k] = 1.0
    res = _solve(c, A_ub, b_ub, A_eq, b_eq, [(0, None)] * (k + 1), "torque demand")
    if res is None:
        return Demand(math.inf, None)
    u = float(res.x[k])
    lam = res.x[:k]
    lim = None
    if len(tm):
        tau = prog.tau_g + prog.torque @ lam
        i = int(np.argmax(np.abs(tau) / tm))
        lim = Limit(prog.names[i][0], prog.names[i][1], float(abs(tau[i])), float(tm[i]))
    return Demand(u, lim)


def torque_rows(jacobians: Sequence[np.ndarray], effort: Sequence[float], tau_g) -> tuple[np.ndarray, np.ndarray]:
    """Joint-limit rows ``A f <= b`` over a finger's stacked contact forces (the controller's
    form of the constraint): ``|tau_g + sum_c J_c^T f_c| <= effort`` with ``J_c`` (3, n_joints)
    linear Jacobians and ``f_c`` (3,) the forces the finger applies, in one frame.

    Returns:
        A (2 n_joints, 3 n_contacts), b (2 n_joints,); rows of unbounded joints are dropped.
    """
    JT = np.hstack([np.asarray(J, dtype=float).T for J in jacobians]) if len(jacobians) else np.zeros((len(effort), 0))
    tm = np.asarray(effort, dtype=float)
    g = np.asarray(tau_g, dtype=float)
    ok = np.isfinite(tm)
    return np.r_[JT[ok], -JT[ok]], np.r_[tm[ok] - g[ok], tm[ok] + g[ok]]


# --------------------------------------------------------------------------- a whole grasp


@dataclass(frozen=True)
class DirectionHold:
    """How a grasp holds its object under one gravity direction: ``name``, ``gravity``
    (palm frame, m/s^2), `Capacity` and, at ``HOLD_FACTOR``, the `Demand`."""

    name: str
    gravity: tuple[float, float, float]
    capacity: Capacity
    demand: Demand

    @property
    def holds(self) -> bool:
        return self.capacity.factor >= HOLD_FACTOR

    def words(self) -> str:
        if self.holds:
            return f"{self.name}: {self.capacity.words()}"
        return f"{self.name}: {self.capacity.words(HOLD_FACTOR)}; at {HOLD_FACTOR:g}x, {self.demand.words()}"


def grasp_statics(hand, q, patches: Mapping[str, tuple], T_palm_obj) -> dict[str, FingerStatics]:
    """`finger_statics` of every touching finger of a grasp (``patches`` as the model sees
    them, e.g. after `planner.closure.apply_contact_model`)."""
    return {f: finger_statics(hand, f, q, pts, T_palm_obj) for f, (pts, _) in patches.items() if len(pts)}


def grasp_hold(hand, q, patches: Mapping[str, tuple], T_palm_obj, mass_kg: float, friction: Friction,
               directions: Sequence[tuple[str, Sequence[float]]], *, force_cap_n: float | None = None,
               margin: float = FRICTION_MARGIN) -> list[DirectionHold]:
    """`hold_capacity` and `torque_demand` of a realized grasp for each named gravity
    direction (palm frame, m/s^2; `planner.gravity.gravity_directions`)."""
    R = np.asarray(T_palm_obj, dtype=float)[:3, :3]
    statics = grasp_statics(hand, q, patches, T_palm_obj)
    out = []
    for name, g in directions:
        g_obj = R.T @ np.asarray(g, dtype=float)
        load = np.r_[float(mass_kg) * g_obj, np.zeros(3)]
        cap = hold_capacity(patches, statics, friction, load, g_obj, margin=margin, force_cap_n=force_cap_n)
        dem = torque_demand(patches, statics, friction, load, g_obj, margin=margin, force_cap_n=force_cap_n)
        out.append(DirectionHold(name, tuple(float(v) for v in g), cap, dem))
    return out
