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
* Coupled joints (`planner.hand.Coupling`, ``q_f = m q_d + o``): a follower has no actuator
  of its own. The rows are the finger's actuated joints, its drivers: by virtual work
  (``dq_f = m dq_d``) the driver's actuator delivers ``tau_d + m tau_f``, and that is bounded
  by the driver's effort limit; the follower's own limit bounds nothing
  (`planner.hand.Finger.reduce` on the Jacobians and gravity torques, `finger_statics`).
* A finger with one actuated coordinate (one joint, or a driver and its followers: the
  Psyonic's coupled fingers) moves each contact point along one direction ``v`` (its Jacobian
  column); its motor sets one number, the generalized force ``J^T [f ; m]``, and the friction
  along its slide ``t = v - (v.n) n`` is a reaction whose value the motor does not set. The
  programs here let the friction take any value in the cone. Measured on Alex's Psyonic hand
  (docs/YOUR_HAND.md, section 2): after the fingers close, the simulator's friction sits at
  the cone's edge against the motor, and the normal force delivered is
  ``tau / (v.n + mu |v_t|)`` (MuJoCo, the thumb lifted, gravity off: the index commanded
  0.71 N and delivered 0.18 N; 0.28 N of 0.028 N m over 0.0988 m with the rows below, as
  predicted). `one_actuator_rows` states that closing-slide friction as linear rows
  (``grip_program(one_actuator=True)``, ``balance_forces(one_actuator=...)``). It is off:
  with it the planner refuses the Psyonic box pair (the thumb's lift holds 0x palm down),
  but also a Psyonic ball grasp the simulator holds in 6 directions: once loaded, static
  friction turns with the load. Which friction a one-actuator finger may count on is open.
  Two variants of the rows, also opt-in: ``one_actuator="none"`` (the friction along the slide
  carries none of the motor's load, ``f.t = 0``) and ``"no_wedge"`` (it lies between none and
  the closing edge, ``0 <= f.t``, as ``GripProgram.one_actuator_ub``; `slide_directions`): both
  hold the Psyonic box state 7 at over 500x, which the simulator drops. What the closing leaves
  is checked by `release_equilibrium`: at the release (no load yet) every one-actuator contact
  has its friction at the closing edge; when no such forces balance, the fingers push the object
  away (right on the 4 flat-faced box cases measured, 11 of 16 Psyonic grasps overall, wrong
  where a curved object finds a new equilibrium nearby: docs/YOUR_HAND.md, section 2).

This module is pure numpy/scipy over arrays; `finger_statics` is the one function that
reads a hand (its Jacobians and gravity torques), so the graph search stays hand-agnostic.
It is one concept, kept whole although slightly over 600 lines: the finger statics, the two
linear programs and their constants are one force model the planner and the replay share.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from planner.closure import GRIP_CONE_SIDES, checked_load, contact_wrenches
from planner.errors import InputError
from planner.lp import highs_lp, solve_highs
from planner.model import PALM, Friction, tangent_basis

#: Multiple of the object's weight a state must hold (module docstring).
HOLD_FACTOR = 2.0
#: Fraction of ``mu`` and ``gamma`` the grip forces may use (module docstring).
FRICTION_MARGIN = 0.75
#: Friction-cone fractions (lateral, torsional) the controller tries in turn at the
#: simulator's contacts (`balance_forces`): half the cone first (room for the contacts to
#: move), then the planner's `FRICTION_MARGIN`, then the whole cone as a last resort (the
#: simulator's contacts are not the plan's; the replay's verdict says whether it held).
CONE_MARGINS = ((0.5, 0.0), (0.5, 0.5), (FRICTION_MARGIN, 0.0), (FRICTION_MARGIN, FRICTION_MARGIN), (1.0, 0.0), (1.0, 1.0))
#: Capacities are reported up to this multiple of the load (a grasp whose joints the load
#: barely loads, e.g. a finger pushing along its own length, would otherwise be unbounded).
FACTOR_MAX = 1000.0


@dataclass(frozen=True, eq=False)
class FingerStatics:
    """What one finger's joints do at one realized contact (a graph slot), object frame.

    Attributes:
        finger: finger name.
        joints: the finger's actuated joint names, in its joint order: all its joints, or for a
            coupled finger its free ones (`planner.hand.Finger.drivers`; each column then
            carries its followers', times the multiplier).
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
        object.__setattr__(self, "_levers", {})

    def lever(self, mu: float, gamma: float) -> np.ndarray:
        """(n_joints,): the most torque a joint delivers per newton of normal force at any of
        the contact points, with friction ``mu`` and torsion ``gamma`` at most: the largest over
        the points of ``|J_lin[:, j]| sqrt(1 + mu^2) + |J_ang[:, j]| gamma`` (`holds_by_bound`;
        remembered per (mu, gamma): the search asks it of every state holding this contact)."""
        key = (float(mu), float(gamma))
        out = self._levers.get(key)
        if out is None:
            J = self.jacobians
            out = (np.linalg.norm(J[:, :3], axis=1) * math.sqrt(1.0 + key[0] * key[0])
                   + np.linalg.norm(J[:, 3:], axis=1) * key[1]).max(axis=0)
            out.setflags(write=False)
            self._levers[key] = out
        return out


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
    not even the hand's own weight or no multiple is held), ``limit`` (what bounds it;
    None when the friction cones bound it before any joint, or at ``FACTOR_MAX``) and
    ``forces`` and ``moments`` (finger -> (n_points, 3) contact forces, N, and torsional
    moments, N m, at its contact points holding ``factor`` times the load, object frame: a
    witness anyone can re-check)."""

    factor: float
    limit: Limit | None
    forces: Mapping[str, np.ndarray] | None = None
    moments: Mapping[str, np.ndarray] | None = None

    def words(self, factor_needed: float | None = None) -> str:
        held = f"holds {self.factor:.3g}x" if self.factor < FACTOR_MAX else f"holds over {FACTOR_MAX:g}x"
        need = "" if factor_needed is None else f" (needs {factor_needed:g}x)"
        by = "" if self.limit is None else f", limited by {self.limit.words()}"
        return f"{held} its weight{need}{by}"


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


def finger_statics(hand, finger: str, q, points_obj, T_palm_obj, effort=None, links=None) -> FingerStatics:
    """A finger's contact Jacobians and gravity torques at a configuration, object frame.

    Args:
        hand: `planner.hand.Hand`.
        finger: finger name.
        q: (nq,) hand configuration (only the finger's joints matter).
        points_obj: (n, 3) the finger's contact points, object frame.
        T_palm_obj: (4, 4) object pose in the palm frame.
        effort: (n_joints,) limits to use instead of ``hand.effort``.
        links: the link of each point (`planner.model.Patch.links`), or None.

    Returns:
        `FingerStatics`; each point's Jacobian is that of its link when ``links`` names one
        of the finger's contact links, else of the finger's contact link nearest to it (a
        mean contact lies between the touching links' points).
    """
    fg = hand.fingers[finger]
    T = np.asarray(T_palm_obj, dtype=float)
    R = T[:3, :3]
    pts_obj = np.asarray(points_obj, dtype=float).reshape(-1, 3)
    pts_palm = pts_obj @ R.T + T[:3, 3]
    state = hand.state(q)
    candidates = [l for l in fg.contact_links if l in hand.collision.link_geometries] or [fg.tip_frame]
    on = []
    for pt, named in zip(pts_palm, [None] * len(pts_palm) if links is None else links):
        if named in candidates:
            on.append(named)
            continue
        if len(candidates) == 1:
            on.append(candidates[0])
            continue
        dist = [state.point_distance(pt, hand.collision.link_geometries[l]) for l in candidates]
        on.append(candidates[int(np.argmin(dist))])
    cols = list(fg.q_index)
    Js = state.point_jacobians(list(zip(on, pts_palm)), angular=True)
    jac = np.array([np.vstack([R.T @ J[:3, cols], R.T @ J[3:, cols]]) for J in Js]).reshape(-1, 6, len(cols))
    G = np.stack([state.gravity_torques(e)[cols] for e in np.eye(3)], axis=1)  # (nj, 3) per unit g_palm
    # a coupled finger's actuators are its drivers (`planner.hand.Finger.reduce`): a follower
    # has none; by virtual work its torque loads its driver's actuator, tau_d + m tau_f, which
    # the driver's effort limit bounds (the follower's own limit bounds nothing)
    jac, G = fg.reduce(jac), fg.reduce(G.T).T
    free = list(fg.free)
    tau_max = np.asarray(hand.effort, dtype=float)[cols] if effort is None else np.asarray(effort, dtype=float)
    return FingerStatics(finger, fg.drivers, jac, G @ R, tau_max[free] if len(free) != len(tau_max) else tau_max)


def one_actuator_rows(jacobians, normals, mu: float) -> np.ndarray:
    """A one-actuator finger's contact rows (module docstring): per contact point, up to two
    rows ``r`` (6,) over the force ``f`` and moment ``m`` it applies there, ``r . [f ; m] = 0``:
    the friction along the finger's slide ``t = (v - (v.n) n) / |v - (v.n) n|`` pushes the
    object the way the finger closes, at the cone's edge (``f.t = mu f.n``: the finger slides
    closed until friction stops it, and that friction is what its motor works against), and the
    torsion about ``n`` carries none of the motor's generalized force (``(a.n) m.n = 0``).

    Args:
        jacobians: (n, 6, 1) the finger's contact Jacobians over its one actuated
            coordinate (`FingerStatics.jacobians`), rows 0-2 linear ``v``, 3-5 angular ``a``.
        normals: (n, 3) the contacts' normals (into the object), same frame.
        mu: the friction coefficient of the cone in use (its inscribed radius).

    Returns:
        (r, 7): the contact index, then the row; a point the finger moves along its normal
        has no friction row, a finger with other than one actuated coordinate no rows.
    """
    J = np.asarray(jacobians, dtype=float)
    if J.ndim != 3 or J.shape[2] != 1:
        return np.zeros((0, 7))
    N = np.asarray(normals, dtype=float).reshape(-1, 3)
    slides = dict(slide_directions(J, N))
    N = N / np.linalg.norm(N, axis=1, keepdims=True)
    out = []
    for i, (v, a, n) in enumerate(zip(J[:, :3, 0], J[:, 3:, 0], N)):
        if i in slides:
            out.append(np.r_[i, slides[i] - float(mu) * n, np.zeros(3)])
        if abs(float(a @ n)) > 1e-9:
            out.append(np.r_[i, np.zeros(3), float(a @ n) * n / max(float(np.linalg.norm(v)), 1e-3)])
    return np.array(out).reshape(-1, 7)


def slide_directions(jacobians, normals) -> list[tuple[int, np.ndarray]]:
    """The slide of each contact point of a one-actuator finger: ``(i, t)`` with ``t`` the unit
    direction of ``v - (v.n) n`` (``v`` the point's velocity per unit of the finger's one
    coordinate, ``n`` its normal), for points the finger moves along the surface; none for a
    finger with other than one actuated coordinate.

    Args:
        jacobians: (n, 6, n_free) the finger's contact Jacobians (`FingerStatics.jacobians`).
        normals: (n, 3) the contacts' normals (into the object), same frame.
    """
    J = np.asarray(jacobians, dtype=float)
    if J.ndim != 3 or J.shape[2] != 1:
        return []
    N = np.asarray(normals, dtype=float).reshape(-1, 3)
    N = N / np.linalg.norm(N, axis=1, keepdims=True)
    out = []
    for i, (v, n) in enumerate(zip(J[:, :3, 0], N)):
        t = v - float(v @ n) * n
        if np.linalg.norm(t) > 1e-3 * max(float(np.linalg.norm(v)), 1e-3):
            out.append((i, t / np.linalg.norm(t)))
    return out


# --------------------------------------------------------------------------- the programs


@dataclass(frozen=True)
class GripProgram:
    """The rows both programs share for one grasp state, whatever the load and gravity:
    wrench columns, joint-torque rows, force-cap rows (`grip_program`; a state held under
    several gravity directions builds them once)."""

    W: np.ndarray          # (k, 6) rim wrenches (unit normal force each), object frame
    torque: np.ndarray     # (r, k) joint torque per unit of each rim wrench
    gravity_rows: np.ndarray  # (r, 3) the hand's own gravity torques per unit gravity (object frame)
    tau_max: np.ndarray    # (r,) limits (finite ones only)
    names: tuple           # (finger, joint) per torque row
    cap_rows: np.ndarray   # (f, k) each finger's normal force per rim wrench
    fingers: tuple         # finger per cap row
    per_point: int         # rim wrenches per contact point (point-major within a finger)
    points: Mapping[str, np.ndarray]  # finger -> (n, 3) its contact points
    #: (e, k) per contact of a one-actuator finger, the generalized force its friction
    #: carries per unit rim wrench, held at zero (`one_actuator_rows`)
    one_actuator: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    #: (e, k) rows ``<= 0`` per contact of a one-actuator finger (`slide_directions`,
    #: ``one_actuator="no_wedge"``): minus the friction along its slide per unit rim wrench
    one_actuator_ub: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))

    def tau_g(self, gravity_obj) -> np.ndarray:
        """(r,) the fingers' own gravity torques for a gravity vector (object frame)."""
        return self.gravity_rows @ np.asarray(gravity_obj, dtype=float).reshape(3)

    def forces(self, lam: np.ndarray) -> tuple[dict, dict]:
        """finger -> (n_points, 3) contact forces (N) and torsional moments (N m) applied at
        the contact points, object frame, of rim-wrench weights ``lam``."""
        forces, moments = {}, {}
        for i, f in enumerate(self.fingers):
            cols = np.flatnonzero(self.cap_rows[i])
            w = (self.W[cols] * lam[cols, None]).reshape(-1, self.per_point, 6).sum(axis=1)
            forces[f] = w[:, :3]
            moments[f] = w[:, 3:] - np.cross(self.points[f], w[:, :3])
        return forces, moments


def grip_program(patches: Mapping[str, tuple], statics: Mapping[str, FingerStatics], friction: Friction, *,
                 margin: float = FRICTION_MARGIN, cone_sides: int = GRIP_CONE_SIDES,
                 one_actuator: bool | str = False) -> GripProgram:
    """The `GripProgram` of a grasp state (arguments as `hold_capacity`); ``one_actuator``
    adds rows for the friction along one-actuator fingers' slides (experiments, off everywhere
    the planner builds programs: see the module docstring): True or "edge", the closing-slide
    friction at the cone's edge (`one_actuator_rows`); "none", none along the slide; "no_wedge",
    between none and the edge (inequality rows, `GripProgram.one_actuator_ub`)."""
    if not isinstance(friction, Friction):
        raise InputError(f"friction must be a Friction, got {type(friction).__name__}")
    if not 0 < margin <= 1:
        raise InputError(f"friction margin must be in (0, 1], got {margin!r}")
    fr = Friction(friction.mu * margin, friction.gamma * margin, int(cone_sides))
    blocks, torque, at, fingers, slides, wedges = [], [], {}, [], [], []
    per_point = 2 * fr.edges
    for finger, (points, normals) in patches.items():
        P = np.asarray(points, dtype=float).reshape(-1, 3)
        if not len(P):
            continue
        Wf = contact_wrenches(P, normals, fr)  # point-major, 2 * edges rows per point
        blocks.append(Wf)
        fingers.append(finger)
        at[finger] = P
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
        torque.append((T, st.gravity, st.effort, [(finger, j) for j in st.joints]))
        start = sum(len(b) for b in blocks[:-1])
        if one_actuator in (True, "edge"):
            for row in one_actuator_rows(st.jacobians, normals, fr.mu * math.cos(math.pi / fr.edges)):
                p = int(row[0])
                sl = slice(p * per_point, (p + 1) * per_point)
                slides.append((start + p * per_point, f[sl] @ row[1:4] + moment[sl] @ row[4:], per_point))
        elif one_actuator in ("none", "no_wedge"):
            for p, t in slide_directions(st.jacobians, normals):
                sl = slice(p * per_point, (p + 1) * per_point)
                if one_actuator == "none":
                    slides.append((start + p * per_point, f[sl] @ t, per_point))
                else:  # f.t >= 0: -f.t <= 0
                    wedges.append((start + p * per_point, -(f[sl] @ t), per_point))
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
        tg_all = np.vstack([r[1] for r in rows])
        tm_all = np.concatenate([r[2] for r in rows])
        nm_all = tuple(n for r in rows for n in r[3])
    else:
        torque_m, tg_all, tm_all, nm_all = np.zeros((0, k)), np.zeros((0, 3)), np.zeros(0), ()
    one = np.zeros((len(slides), k))
    for i, (start, coeff, n) in enumerate(slides):
        one[i, start:start + n] = coeff
    wedge = np.zeros((len(wedges), k))
    for i, (start, coeff, n) in enumerate(wedges):
        wedge[i, start:start + n] = coeff
    return GripProgram(W, torque_m, tg_all, tm_all, nm_all, cap, tuple(fingers), per_point, at, one, wedge)


def _lever(W: np.ndarray) -> float:
    """Torque rows are divided by this (m) so that force and torque rows weigh alike."""
    return max(1e-3, float(np.abs(W[:, 3:]).max(initial=0.0)) / max(float(np.abs(W[:, :3]).max(initial=1.0)), 1e-12))


def _binding(prog: GripProgram, lam: np.ndarray, force_cap_n: float | None, tau_g: np.ndarray) -> Limit | None:
    """The joint (or cap) closest to its limit at a solution."""
    best, best_ratio = None, 0.0
    if len(prog.tau_max):
        tau = tau_g + prog.torque @ lam
        ratio = np.abs(tau) / prog.tau_max
        i = int(np.argmax(ratio))
        best, best_ratio = Limit(prog.names[i][0], prog.names[i][1], float(abs(tau[i])), float(prog.tau_max[i])), float(ratio[i])
    capped = _capped(prog)
    if force_cap_n is not None and len(capped):
        fn = prog.cap_rows @ lam
        i = int(capped[int(np.argmax(fn[capped]))])
        if fn[i] / force_cap_n > best_ratio:
            best, best_ratio = Limit(prog.fingers[i], None, float(fn[i]), float(force_cap_n)), float(fn[i] / force_cap_n)
    return best if best_ratio > 0.98 else None


def _capped(prog: GripProgram) -> np.ndarray:
    """Indices of the cap rows of fingers (the palm's force is not capped: it is rigid)."""
    return np.array([i for i, f in enumerate(prog.fingers) if f != PALM], dtype=int)


def _cap_rows(prog: GripProgram, force_cap_n: float | None, extra_cols: int):
    rows = prog.cap_rows[_capped(prog)] if len(prog.cap_rows) else prog.cap_rows
    if force_cap_n is None or not len(rows):
        return np.zeros((0, len(prog.W) + extra_cols)), np.zeros(0)
    return np.c_[rows, np.zeros((len(rows), extra_cols))], np.full(len(rows), float(force_cap_n))


def hold_capacity(patches: Mapping[str, tuple], statics: Mapping[str, FingerStatics], friction: Friction, load,
                  gravity_obj, *, margin: float = FRICTION_MARGIN, force_cap_n: float | None = None,
                  cone_sides: int = GRIP_CONE_SIDES, program: GripProgram | None = None,
                  witness: bool = True) -> Capacity:
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
        program: the state's `grip_program` when already built (then ``patches``,
            ``statics``, ``friction``, ``margin`` and ``cone_sides`` are its).
        witness: also return the witness forces and moments (else None).

    Returns:
        `Capacity` (factor 0: not even the fingers' own weight is held within the limits, or
        the contacts cannot push against the load at all).
    """
    w = checked_load(load)
    prog = program or grip_program(patches, statics, friction, margin=margin, cone_sides=cone_sides)
    tau_g = prog.tau_g(gravity_obj)
    k = len(prog.W)
    if k == 0:
        return Capacity(0.0, None)
    L = _lever(prog.W)
    scale = max(float(np.abs(w).max()), 1e-12)
    A_eq = np.c_[prog.W.T, w / scale]
    A_eq[3:] /= L
    if len(prog.one_actuator):
        A_eq = np.r_[A_eq, np.c_[prog.one_actuator, np.zeros(len(prog.one_actuator))]]
    b_eq = np.zeros(len(A_eq))
    A_ub = np.r_[np.c_[prog.torque, np.zeros(len(prog.torque))], np.c_[-prog.torque, np.zeros(len(prog.torque))]]
    b_ub = np.r_[prog.tau_max - tau_g, prog.tau_max + tau_g]
    if len(prog.one_actuator_ub):
        A_ub = np.r_[A_ub, np.c_[prog.one_actuator_ub, np.zeros(len(prog.one_actuator_ub))]]
        b_ub = np.r_[b_ub, np.zeros(len(prog.one_actuator_ub))]
    A_cap, b_cap = _cap_rows(prog, force_cap_n, 1)
    A_ub, b_ub = np.r_[A_ub, A_cap], np.r_[b_ub, b_cap]
    c = np.zeros(k + 1)
    c[k] = -1.0
    alpha_max = FACTOR_MAX * scale
    res = solve_highs(c, A_ub, b_ub, A_eq, b_eq, [(0, None)] * k + [(0, alpha_max)], "grip capacity LP")
    if res is None:  # not even lambda = 0: a finger cannot hold itself up
        over = np.abs(tau_g) - prog.tau_max
        i = int(np.argmax(over)) if len(over) else None
        lim = None if i is None else Limit(prog.names[i][0], prog.names[i][1], float(abs(tau_g[i])), float(prog.tau_max[i]))
        return Capacity(0.0, lim)
    alpha = max(0.0, float(res.x[k]) / scale)  # no -0 ("holds -0x its weight")
    lam = res.x[:k]
    limit = None if alpha >= FACTOR_MAX * (1 - 1e-9) else _binding(prog, lam, force_cap_n, tau_g)
    return Capacity(min(alpha, FACTOR_MAX), limit, *(prog.forces(lam) if witness else (None, None)))


def torque_demand(patches: Mapping[str, tuple], statics: Mapping[str, FingerStatics], friction: Friction, load,
                  gravity_obj, *, factor: float = HOLD_FACTOR, margin: float = FRICTION_MARGIN,
                  force_cap_n: float | None = None, cone_sides: int = GRIP_CONE_SIDES,
                  program: GripProgram | None = None) -> Demand:
    """Smallest fraction ``u`` of every joint's limit with which the fingers hold ``factor``
    times the load: ``min u`` s.t. the forces balance ``factor * load`` inside the cones and
    ``|tau_g + T lambda| <= u tau_max`` (arguments as `hold_capacity`). ``u <= 1``: the
    joints can. The joint at ``u tau_max`` is named with the torque it needs."""
    w = checked_load(load) * float(factor)
    prog = program or grip_program(patches, statics, friction, margin=margin, cone_sides=cone_sides)
    tau_g = prog.tau_g(gravity_obj)
    k = len(prog.W)
    if k == 0:
        return Demand(math.inf, None)
    L = _lever(prog.W)
    A_eq = np.c_[prog.W.T, np.zeros(6)]
    A_eq[3:] /= L
    b_eq = -w.copy()
    b_eq[3:] /= L
    if len(prog.one_actuator):
        A_eq = np.r_[A_eq, np.c_[prog.one_actuator, np.zeros(len(prog.one_actuator))]]
        b_eq = np.r_[b_eq, np.zeros(len(prog.one_actuator))]
    tm = prog.tau_max
    A_ub = np.r_[np.c_[prog.torque, -tm], np.c_[-prog.torque, -tm]]
    b_ub = np.r_[-tau_g, tau_g]
    if len(prog.one_actuator_ub):
        A_ub = np.r_[A_ub, np.c_[prog.one_actuator_ub, np.zeros(len(prog.one_actuator_ub))]]
        b_ub = np.r_[b_ub, np.zeros(len(prog.one_actuator_ub))]
    A_cap, b_cap = _cap_rows(prog, force_cap_n, 1)
    A_ub, b_ub = np.r_[A_ub, A_cap], np.r_[b_ub, b_cap]
    c = np.zeros(k + 1)
    c[k] = 1.0
    res = solve_highs(c, A_ub, b_ub, A_eq, b_eq, [(0, None)] * (k + 1), "torque demand LP")
    if res is None:
        return Demand(math.inf, None)
    u = float(res.x[k])
    lam = res.x[:k]
    lim = None
    if len(tm):
        tau = tau_g + prog.torque @ lam
        i = int(np.argmax(np.abs(tau) / tm))
        lim = Limit(prog.names[i][0], prog.names[i][1], float(abs(tau[i])), float(tm[i]))
    return Demand(u, lim)


def holds_by_bound(statics: Mapping[str, FingerStatics], grip_force_n: float, friction: Friction, gravity_obj, *,
                   factor: float = HOLD_FACTOR, margin: float = FRICTION_MARGIN,
                   force_cap_n: float | None = None) -> bool:
    """A sufficient condition for ``hold_capacity >= factor``, without a program.

    ``grip_force_n`` is `planner.closure.min_grip_force` of the state for the load (the same
    cone polygon, ``mu`` and ``gamma`` times ``margin``): its forces, scaled by ``factor``,
    hold ``factor`` times the load with at most ``factor * grip_force_n`` of normal force per
    finger. Each contact force is then at most ``sqrt(1 + mu'^2)`` times its normal force and
    its torsion ``gamma'`` times it, so a joint delivers at most

        |tau_g| + factor * grip_force_n * max_c (|J_lin,c[:, j]| sqrt(1 + mu'^2) + |J_ang,c[:, j]| gamma')

    When that is within every joint's limit (and ``factor * grip_force_n`` within the cap),
    those forces are a witness and the state holds; otherwise the program decides.
    """
    if not math.isfinite(grip_force_n):
        return False
    push = factor * grip_force_n
    if force_cap_n is not None and push > force_cap_n:
        return False
    mu, gamma = friction.mu * margin, friction.gamma * margin
    g = np.asarray(gravity_obj, dtype=float).reshape(3)
    for st in statics.values():
        if np.any(np.abs(st.gravity @ g) + push * st.lever(mu, gamma) > st.effort):
            return False
    return True


def torque_rows(jacobians: Sequence[np.ndarray], effort: Sequence[float], tau_g,
                torsion: Sequence[np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Joint-limit rows ``A [f ; t] <= b`` over a finger's stacked contact forces (the
    controller's form of the constraint): ``|tau_g + sum_c J_c^T f_c + a_c t_c| <= effort``
    with ``J_c`` (3, n_joints) linear Jacobians, ``f_c`` (3,) the forces the finger applies and,
    with ``torsion``, ``a_c = J_ang,c^T n_c`` (n_joints,) the joint torques per unit torsional
    moment ``t_c`` about the contact normal, in one frame.

    Returns:
        A (2 n_joints, 3 n_contacts [+ n_contacts]), b (2 n_joints,); rows of unbounded
        joints are dropped.
    """
    JT = np.hstack([np.asarray(J, dtype=float).T for J in jacobians]) if len(jacobians) else np.zeros((len(effort), 0))
    if torsion is not None:
        JT = np.hstack([JT] + [np.asarray(a, dtype=float).reshape(-1, 1) for a in torsion])
    tm = np.asarray(effort, dtype=float)
    g = np.asarray(tau_g, dtype=float)
    ok = np.isfinite(tm)
    return np.r_[JT[ok], -JT[ok]], np.r_[tm[ok] - g[ok], tm[ok] + g[ok]]


# --------------------------------------------------------------------------- the controller's form


def balance_forces(points, normals, targets, load, centre, friction: Friction, fn_min,
                   f_max: float, margins=CONE_MARGINS, joint_rows=None, one_actuator=None) -> np.ndarray | None:
    """Contact forces that balance a load on the object: grasp force optimization.

    Solves, for the margins ``(s, s_t)`` in turn, the linear program (HiGHS, through highspy as
    the planner's programs: `planner.lp.highs_lp`)

        min  sum_i |f_i - f0_i|_1
        s.t. sum_i [f_i ; (p_i - c) x f_i + t_i n_i] = -load    (equilibrium)
             f_i in the 8-sided pyramid inscribed in the cone of friction s mu about n_i
             |t_i| <= s_t gamma (f_i . n_i)                       (soft-finger torsion)
             f_i . n_i >= fn_min
             A_f f_f <= b_f          (every finger f: its joints' torque limits, `torque_rows`)
             r_i . [f_i ; t_i n_i] = 0   (contacts of one-actuator fingers: `one_actuator_rows`)

    and returns the first solution whose components stay within ``f_max``. The torsion
    ``t_i`` is a reaction of the simulator's spinning friction, not commanded. This is the
    planner's grip model (`hold_capacity`: cones, torsion, joint limits) solved at the
    simulator's contacts for the forces to command.

    Args:
        points: (k, 3) contact points, any frame F.
        normals: (k, 3) inward unit normals, frame F.
        targets: (k, 3) preferred forces ``f0`` (the squeeze; zero for passive contacts).
        load: (6,) external wrench on the object ``[f ; tau]`` in frame F, torque about ``centre``.
        centre: (3,) the point torques are taken about (the object's centre of mass).
        friction: Coulomb ``mu`` and torsional ``gamma`` (m).
        fn_min: smallest normal force per contact, N (a number or (k,)).
        f_max: largest absolute force component, N.
        margins: friction fractions tried in turn.
        joint_rows: optional [(contact indices of one finger, A, b)] with ``A`` (r, 3 m_f) over
            those contacts' stacked forces, or (r, 4 m_f) with their torsions after them
            (`torque_rows`): the joints' limits.
        one_actuator: optional ``[(contact index, jacobian (6, 1))]``: the contacts of
            one-actuator fingers, with their Jacobian over its coordinate; their rows
            (`one_actuator_rows`, at each margin's ``mu``) hold.

    Returns:
        (k, 3) forces the fingers apply ON the object, or None when no balanced forces exist.
    """
    P = np.asarray(points, float).reshape(-1, 3)
    N = np.asarray(normals, float).reshape(-1, 3)
    N = N / np.linalg.norm(N, axis=1, keepdims=True)
    k = len(P)
    if k == 0:
        return None
    m = 3 * k
    r = P - np.asarray(centre, float)
    # torque rows scaled by 1/lever so force and torque rows weigh alike
    lever = max(1e-3, float(np.max(np.linalg.norm(r, axis=1))))
    cross = np.zeros((k, 3, 3))  # [r_i]x: cross[i] @ f = r_i x f
    cross[:, 0, 1], cross[:, 0, 2], cross[:, 1, 2] = -r[:, 2], r[:, 1], -r[:, 0]
    cross -= cross.transpose(0, 2, 1)
    A_eq = np.zeros((6, 2 * m + k))
    A_eq[:3, :m] = np.tile(np.eye(3), k)
    A_eq[3:, :m] = cross.transpose(1, 0, 2).reshape(3, m) / lever
    A_eq[3:, m:m + k] = N.T / lever
    b = -np.asarray(load, float).reshape(6).copy()
    b[3:] /= lever
    one_idx = [i for i, _ in (one_actuator or ())]
    one_J = np.array([np.asarray(J, float).reshape(6, 1) for _, J in (one_actuator or ())]).reshape(-1, 6, 1)
    base_eq, base_b = A_eq, b
    f0 = np.asarray(targets, float).reshape(m)
    fn_min = np.broadcast_to(np.asarray(fn_min, float), (k,))
    angles = np.linspace(0.0, 2.0 * np.pi, 8, endpoint=False)
    # the pyramid's rim directions (cos a t1 + sin a t2) per contact, the same for every margin
    t1, t2 = tangent_basis(N)
    rims = np.cos(angles)[None, :, None] * t1[:, None] + np.sin(angles)[None, :, None] * t2[:, None]  # (k, 8, 3)
    # variables: f (m), t (k), slack (m) with |f - f0| <= slack; rows: 8 rim + 1 normal per
    # contact, 2 torsion per contact, then the two slack rows per force component
    rows = 11 * k + 2 * m
    G = np.zeros((rows, 2 * m + k))
    h = np.zeros(rows)
    blocks = np.arange(k)
    rim_rows = (9 * blocks[:, None] + np.arange(8)).ravel()
    cols = 3 * blocks[:, None] + np.arange(3)  # (k, 3) force columns of each contact
    G[9 * blocks[:, None, None] + np.arange(9)[None, 8:, None], cols[:, None, :]] = -N[:, None, :]
    h[9 * blocks + 8] = -fn_min
    tor = 9 * k + 2 * blocks
    G[tor, m + blocks], G[tor + 1, m + blocks] = 1.0, -1.0
    I = np.eye(m)
    G[11 * k:11 * k + m, :m], G[11 * k:11 * k + m, m + k:] = I, -I
    G[11 * k + m:, :m], G[11 * k + m:, m + k:] = -I, -I
    h[11 * k:] = np.r_[f0, -f0]
    c = np.r_[np.zeros(m + k), np.ones(m)]
    bounds = [(None, None)] * (m + k) + [(0, None)] * m
    if joint_rows:
        extra_G, extra_h = [], []
        for idx, A, bj in joint_rows:
            idx = np.asarray(idx)
            row = np.zeros((len(A), 2 * m + k))
            row[:, (3 * idx[:, None] + np.arange(3)).ravel()] = A[:, :3 * len(idx)]
            if A.shape[1] == 4 * len(idx):  # the torsion columns
                row[:, m + idx] = A[:, 3 * len(idx):]
            extra_G.append(row)
            extra_h.append(np.asarray(bj, float))
        if extra_G:
            G, h = np.vstack([G] + extra_G), np.concatenate([h] + extra_h)
    for s, s_t in margins:
        mu, gamma = s * friction.mu * math.cos(math.pi / 8), s_t * friction.gamma
        G[rim_rows[:, None], np.repeat(cols, 8, axis=0)] = (rims - mu * N[:, None, :]).reshape(8 * k, 3)
        # (the joint rows appended after row 11 k + 2 m do not depend on the margin)
        G[tor[:, None], cols] = G[tor[:, None] + 1, cols] = -gamma * N
        A_eq, b = base_eq, base_b
        if one_idx:  # at this margin's mu
            rows1 = one_actuator_rows(one_J, N[one_idx], mu)
            extra = np.zeros((len(rows1), 2 * m + k))
            for r_i, row in enumerate(rows1):
                i = one_idx[int(row[0])]
                extra[r_i, 3 * i:3 * i + 3] = row[1:4]
                extra[r_i, m + i] = row[4:] @ N[i]  # the torsion t_i acts about n_i
            A_eq, b = np.r_[base_eq, extra], np.r_[base_b, np.zeros(len(rows1))]
        res = highs_lp(c, G, h, A_eq, b, bounds, "highs")
        if res.status == 0 and float(np.abs(res.x[:m]).max()) <= f_max:
            return res.x[:m].reshape(k, 3)
    return None


def release_equilibrium(patches: Mapping[str, tuple], statics: Mapping[str, FingerStatics], friction: Friction, *,
                        margin: float = 1.0, cone_sides: int = GRIP_CONE_SIDES, turns_freely: bool = False) -> bool:
    """Whether the object is in equilibrium when the fingers have closed on it and no load
    acts yet (the replay's release, gravity off): every one-actuator finger's contacts carry
    the friction at the cone's edge along the finger's slide, against its motor
    (`one_actuator_rows`: a finger that closes slides until friction stops it), every finger
    presses (its normal force at least 1, the problem is homogeneous), the palm pushes back,
    and the forces balance with no load: ``W^T lambda = 0``. When no such forces exist, the
    closed fingers push the object away at its release, before any load comes (Psyonic box
    state 7, docs/YOUR_HAND.md). Fingers with two or more actuated coordinates keep the
    whole cone. ``margin`` defaults to the whole cone: the engine's friction, not the
    planner's reserve."""
    prog = grip_program(patches, statics, friction, margin=margin, cone_sides=cone_sides, one_actuator="edge")
    k = len(prog.W)
    if k == 0:
        return False
    L = _lever(prog.W)
    A_eq = prog.W.T.copy()
    A_eq[3:] /= L
    if turns_freely:  # a ball turns about its centre (the origin) under any moment, its contacts unchanged
        A_eq = A_eq[:3]
    b_eq = np.zeros(len(A_eq))
    if len(prog.one_actuator):
        A_eq = np.r_[A_eq, prog.one_actuator]
        b_eq = np.r_[b_eq, np.zeros(len(prog.one_actuator))]
    pressing = prog.cap_rows[_capped(prog)]
    A_ub = -pressing
    b_ub = -np.ones(len(pressing))
    res = solve_highs(np.zeros(k), A_ub, b_ub, A_eq, b_eq, [(0, None)] * k, "release equilibrium LP")
    return res is not None


# --------------------------------------------------------------------------- a whole grasp


@dataclass(frozen=True)
class DirectionHold:
    """How a grasp holds its object under one gravity direction: ``name``, ``gravity``
    (palm frame, m/s^2), `Capacity` and, at ``HOLD_FACTOR``, the `Demand` (None when not
    computed)."""

    name: str
    gravity: tuple[float, float, float]
    capacity: Capacity
    demand: Demand | None

    @property
    def holds(self) -> bool:
        return self.capacity.factor >= HOLD_FACTOR

    def words(self) -> str:
        if self.holds:
            return f"{self.name}: {self.capacity.words()}"
        tail = "" if self.demand is None else f"; at {HOLD_FACTOR:g}x, {self.demand.words()}"
        return f"{self.name}: {self.capacity.words(HOLD_FACTOR)}{tail}"


def grasp_statics(hand, q, patches: Mapping[str, tuple], T_palm_obj) -> dict[str, FingerStatics]:
    """`finger_statics` of every touching finger of a grasp (``patches`` as the model sees
    them, e.g. after `planner.closure.apply_contact_model`); the palm (`PALM`) has no joints,
    so no statics: its contacts push inside their cones without a limit."""
    return {f: finger_statics(hand, f, q, patch[0], T_palm_obj, links=getattr(patch, "links", None))
            for f, patch in patches.items() if f != PALM and len(patch[0])}


def grasp_hold(hand, q, patches: Mapping[str, tuple], T_palm_obj, mass_kg: float, friction: Friction,
               directions: Sequence[tuple[str, Sequence[float]]], *, force_cap_n: float | None = None,
               margin: float = FRICTION_MARGIN, demand: bool = True) -> list[DirectionHold]:
    """`hold_capacity` and (``demand``; else None) `torque_demand` of a realized grasp for
    each named gravity direction (palm frame, m/s^2; `planner.gravity.gravity_directions`)."""
    R = np.asarray(T_palm_obj, dtype=float)[:3, :3]
    statics = grasp_statics(hand, q, patches, T_palm_obj)
    prog = grip_program(patches, statics, friction, margin=margin)
    out = []
    for name, g in directions:
        g_obj = R.T @ np.asarray(g, dtype=float)
        load = np.r_[float(mass_kg) * g_obj, np.zeros(3)]
        cap = hold_capacity(patches, statics, friction, load, g_obj, force_cap_n=force_cap_n, program=prog)
        dem = (torque_demand(patches, statics, friction, load, g_obj, force_cap_n=force_cap_n, program=prog)
               if demand else None)
        out.append(DirectionHold(name, tuple(float(v) for v in g), cap, dem))
    return out
