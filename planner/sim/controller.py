"""Grasp controller of the replay: contact forces from the grasp's mechanics, commanded as joint torques.

Position control with capped motor forces is not force control: a saturated finger pushes
with whatever its caps allow, in whatever direction its position error points, and the
object is thrown when those pushes do not balance. This controller instead decides the
force every contact must apply and commands it:

1. **Contacts from the simulator.** Every hand link within ``CONTACT_GAP_M`` of the object
   (the engine's closest points: a contact that opens for one step keeps its force) gives one
   contact per face it touches, at the mean of that face's points, normal INTO the object;
   links of the fingers the plan holds the object with are *commanded*, the palm's are
   *passive* (they push back but cannot be commanded). A holding finger that does not
   touch yet approaches along the normal of its closest point.
2. **Forces that balance the load** (grasp force optimization, `balance_forces`): the
   object's weight ``m g`` must be balanced by the contact forces inside the friction
   cones, shrunk by a safety factor (half the cone first, then 3/4, then the whole cone;
   point forces first, then with the soft-finger torsion the simulator's torsional friction
   provides), each commanded force as close as possible (L1) to a squeeze ``F n_i`` along its
   inward normal, and every finger's joint torques ``|g(q) + J^T f|`` within the hand's
   effort limits: the planner's grip model (`planner.grip.balance_forces`, the cones, margin
   and joint limits of `planner.grip.hold_capacity`) at the simulator's contacts. Solutions
   are cached while the hold is static.
3. **Joint torques** ``tau = g(q) + sum_c J_c(q)^T f_c``: ``g(q)`` compensates the hand's own
   weight (pinocchio's generalized gravity of the same URDF masses) and ``J_c`` is the
   linear Jacobian of contact point ``c`` over its finger's joints (pinocchio, the
   planner's hand model). Forces are re-solved every ``UPDATE_EVERY`` physics steps at the
   current contacts and configuration.
4. **Posture springs, capped at a fraction of the grip.** Every joint also gets an explicit
   spring-damper towards its target (for a holding finger, where it touched: `latch`),
   saturating at the torque of ``POSTURE_SHARE * F`` at the finger's pad, reached over a pad
   travel of a tenth of the object's smallest radius (at most ``MAX_TRAVEL_M``). The springs
   hold the joints the contact force does not load (the finger's null space) and pull a
   drifting object back; they cannot throw it. The sum is clipped at the joints' effort
   limits, as a real motor saturates. A free or moving finger gets
   ``FREE_SHARE * F``, so a lifting finger cannot drag the object and a landing one touches
   down softly. An armature floor on the finger links (`Controller.armature_floor`, the
   reflected inertia a geared finger motor has; the replay gives it to the engine) keeps the
   explicit springs stable at the time step, and no heavier: a heavier finger lags an object
   that moves and lets go of it.

The squeeze ``F`` comes from the load: ``F = SAFETY * m |g_max| / (n mu)`` for ``n`` holding
fingers (each contact's friction alone would hold the weight twice over), but never less
than the weight of the hand's heaviest finger: a grip weaker than the fingers' own weight
is dominated by errors of the hand model rather than by the object.

Gravity enters gradually (`Controller.set_gravity`): contacts are acquired with the object
held and gravity off, then gravity ramps up while the forces follow it (the solutions for
no load and for the full load are blended). Before a
finger lifts, its load is handed over (its forces fade to zero while the other fingers'
forces fade to the solution without it); after a finger lands the reverse.

Coupled joints (`planner.hand.Coupling`, ``q_f = m q_d + o``): the engine enforces each
coupling (`planner.sim.engine.PhysicsEngine`: a gear constraint in pybullet, a joint
equality in MuJoCo) and the controller commands the drivers only; a follower gets no motor
torque. By virtual work the torque a follower's joint needs is its driver's actuator's load:
``tau_d + m tau_f`` for gravity and contact forces (`_to_actuators`), the force solution's
joint limits are the drivers' (`planner.hand.Finger.reduce` on the Jacobians and the
gravity torques, ``effort[drivers]``), and a driver's posture spring acts on the finger's
reduced coordinate (its lever: the pad Jacobian's driver column ``J_d + m J_f``).

The controller is engine-free: it reads joint states, the object's pose and closest points
through `planner.sim.engine.Sensor` (a physics engine, or synthetic readings in a test), and
`Controller.step` returns the joint torques; the replay applies them.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from planner.model import Contact, Friction
from planner.grip import balance_forces, torque_rows
from planner.sim.engine import HandTopology, JointStates, Sensor

#: Physics steps between two force solutions (at 240 Hz: 60 Hz).
UPDATE_EVERY = 4
#: Squeeze force over the force that holds the object's weight by friction alone.
SAFETY = 2.0
#: Posture motors may change a contact force by at most this fraction of the squeeze.
POSTURE_SHARE = 0.3
#: A moving finger's motors: this multiple of the squeeze at its pad.
FREE_SHARE = 0.15
#: A commanded force above this multiple of the squeeze is rejected (a near-singular
#: grasp balanced by internal forces the fingers cannot hold) for fingers whose joints have
#: no torque limits; the limits bound the others (`planner.grip.torque_rows`).
MAX_FORCE_RATIO = 5.0
#: Smallest commanded normal force, as a fraction of the squeeze: contacts stay closed.
MIN_NORMAL_RATIO = 0.5
#: Contact points and the object centre are quantized to this in the force cache, m.
CACHE_M = 0.0002
#: Pad travel over which a posture spring reaches its cap: a tenth of the object's smallest
#: radius (a pad slipping that far turns the object by ~6 deg), at most ``MAX_TRAVEL_M``.
TRAVEL_PER_RADIUS = 0.1
MAX_TRAVEL_M = 0.001
#: Smallest lever of a posture spring (joints whose axis passes near the pad), m.
MIN_LEVER_M = 0.005
#: The armature floor puts the stiffest posture spring at this omega * dt. Bullet (pybullet)
#: integrates
#: an explicit, critically damped spring stably up to omega dt ~ 0.83 (spectral radius of
#: the semi-implicit Euler step: 0.83 at 0.3, 0.72 at 0.6, 0.68 at its optimum 0.73, > 1
#: past 0.83); 0.5 leaves room for 2.7x the stiffness (contacts add some). Every bit of
#: inertia above the floor makes the fingers slower to follow the object: with the floor at
#: omega dt = 0.3 (2.8x the inertia) the bundled box, held at its edges, broke away from
#: the thumb at 82 % of the palm-up gravity ramp, and held with it at 0.5 or 0.6, or at
#: half the time step (which also quarters the floor). At 0.75 (near the limit) thin pens
#: started to fail.
ARMATURE_OMEGA_DT = 0.5
#: A point farther than this outside the object is not a contact (an engine may report
#: speculative manifold points with positive distance: pybullet does).
TOUCH_TOL_M = 0.0005
#: A link this close to the object counts as a contact for the force solution, m.
CONTACT_GAP_M = 0.001
#: Contact normals of one link closer than this (cosine, ~10 deg) belong to one face.
FACE_COS = math.cos(math.radians(10.0))
#: A holding finger that does not touch approaches the object when it is closer than this.
APPROACH_M = 0.01
#: The replay starts a holding finger this far outside the object where its planned posture
#: overlaps the engine's geometry (`Controller.back_off`), m: the finger closes the gap
#: under its commanded torques, as a finger closes on an object, inside ``TOUCH_TOL_M`` (a
#: contact for the force solution from the first step).
START_CLEARANCE_M = 0.0001
#: Back-off iterations at most (each re-reads the engine's closest points).
BACK_OFF_ITERATIONS = 8


# --------------------------------------------------------------------------- force optimization


def squeeze_force_n(mass_kg: float, g_max_mps2: float, n_fingers: int, mu: float, floor_n: float) -> float:
    """The squeeze ``F`` (module docstring): ``SAFETY m g / (n mu)``, at least ``floor_n``."""
    return max(SAFETY * mass_kg * g_max_mps2 / (max(1, n_fingers) * mu), floor_n)


# --------------------------------------------------------------------------- controller


class Controller:
    """Torque-level grasp controller of a hand holding one object (module docstring).

    Args:
        sensor: what it reads the simulation through (a `planner.sim.engine.PhysicsEngine`).
        hand: `planner.hand.Hand` (pinocchio) of the same URDF; the palm frame is the world.
        topology: the hand as the engine built it (joint order of the torques, link order).
        link_finger: URDF link name -> finger name or "palm".
        link_mass_kg: URDF link name -> mass, as simulated.
        mass_kg: object mass; friction: the plan's friction.
        g_max_mps2: largest gravity magnitude of the replay (sets the squeeze).
        force_n: squeeze per holding finger, N; None derives it (`squeeze_force_n`).
        dt_s: physics time step (sets the armature).
        object_radius_m: the object's smallest half-extent (sets the posture springs' travel).
    """

    def __init__(self, sensor: Sensor, hand, topology: HandTopology, link_finger: Mapping[str, str],
                 link_mass_kg: Mapping[str, float], mass_kg: float, friction: Friction, g_max_mps2: float,
                 force_n: float | None = None, dt_s: float = 1.0 / 240.0, object_radius_m: float = math.inf):
        self.sensor, self.hand = sensor, hand
        self.col = {j: i for i, j in enumerate(hand.joint_names)}
        self.link_order = {name: k for k, name in enumerate(topology.links)}
        self.link_finger = {link: link_finger.get(link, "palm") for link in topology.links}
        self.link_parent = dict(topology.parent)  # link -> (the joint it hangs from, its parent link)
        self.finger_links = {f: [i for i, g in self.link_finger.items() if g == f] for f in hand.fingers}
        self.mass, self.friction, self.g_max = float(mass_kg), friction, float(g_max_mps2)
        # torques are in the engine's joint order; the hand's own order reads them
        self.movable = list(topology.joints)
        self.hand_pos = {j: k for k, j in enumerate(self.movable)}
        self._hand_order = [self.hand_pos[j] for j in hand.joint_names]
        self.floor_n = self._heaviest_finger_weight_n(link_mass_kg, g_max_mps2)
        self.travel_m = min(MAX_TRAVEL_M, TRAVEL_PER_RADIUS * float(object_radius_m))
        self.force_override = force_n
        self.gravity = np.zeros(3)
        # what is commanded: posture targets, holding fingers, finger load fractions (handover)
        self.q_ref: dict[str, float] = {}
        self.holding: tuple[str, ...] = ()
        self.share: dict[str, float] = {}
        self.moving: str | None = None
        self.force_n = self.floor_n
        self.tau = np.zeros(len(self.movable))
        self.forces: dict[str, np.ndarray] = {}  # link -> commanded force (palm frame)
        self.balanced = True
        # the share (0..1) of the load the palm's contacts carry in the force balance (they push
        # back passively); 0 while the object moves relative to the palm (a reposing step: the
        # planner holds it with the fingers alone there, `planner.repose`), handed over as a
        # finger's load is (`fade_palm`)
        self.palm_share = 1.0
        self._tick = 0
        self._cache: dict = {}
        self._near: dict = {}  # (F, load, links) -> (points, normals, centre, solution) last solved
        self._motors_stale = True
        self.q_target = np.array(sensor.joint_states().position, dtype=float)
        self.kp = self.kd = self.cap = np.zeros(len(self.movable))
        self.armature, self.armature_floor = self._armature(dt_s)
        # the hand's joint torque limits (`planner.hand.Hand.effort`), hand order and engine order
        self.effort = np.asarray(getattr(hand, "effort", np.full(len(hand.joint_names), np.inf)), dtype=float)
        self.tau_max = np.full(len(self.movable), np.inf)
        for j in self.movable:
            if j in self.col:
                self.tau_max[self.hand_pos[j]] = self.effort[self.col[j]]
        # coupled joints: (follower, driver, multiplier), engine positions; a follower has no motor
        self.coupled = [(self.hand_pos[c.joint], self.hand_pos[c.follows], float(c.multiplier))
                        for c in hand.couplings if c.joint in self.hand_pos and c.follows in self.hand_pos]
        for f, _, _ in self.coupled:
            self.tau_max[f] = 0.0
        # fingers every actuated joint of which has a torque limit: the limits bound their forces
        self.limited = {f for f, fg in hand.fingers.items()
                        if np.all(np.isfinite(self.effort[[self.col[fg.joints[k]] for k in fg.free]]))}

    def _heaviest_finger_weight_n(self, link_mass_kg: Mapping[str, float], g: float) -> float:
        mass = {}
        for link, f in self.link_finger.items():  # the links in the engine's order
            if f in self.hand.fingers:
                mass[f] = mass.get(f, 0.0) + link_mass_kg[link]
        return max(mass.values(), default=0.0) * max(g, 9.81)

    def _armature(self, dt_s: float) -> tuple[np.ndarray, dict[str, float]]:
        """The rotational inertia every finger link needs at least to keep the explicit
        posture springs stable (``omega dt <= ARMATURE_OMEGA_DT`` at the stiffest spring each
        joint gets, one-finger squeeze), as the reflected rotor inertia of a geared finger
        motor would: (n_movable,) the floor per joint and link -> the floor of its principal
        moments (kg m^2), which the replay gives the engine
        (`planner.sim.engine.PhysicsEngine.raise_link_inertia`).

        Each joint's floor comes from its own spring (``Kp_j`` grows with the square of its
        lever to the pad) and goes on the links it turns first (the link hanging from it, and
        links fixed to that one); a joint's inertia about its axis includes every link beyond
        it, so each joint gets at least its own floor. One floor per finger, from its longest
        lever, made a distal joint's inertia the base joint's: critically damped, a saturated
        distal spring then moved its joint at a few tenths of a rad/s."""
        F = max(self.force_override or 0.0, squeeze_force_n(self.mass, self.g_max, 1, self.friction.mu, self.floor_n))
        state = self.hand.state(np.array(self.hand.q_open))
        floor = np.zeros(len(self.movable))
        per_joint: dict[str, float] = {}
        for name, finger in self.hand.fingers.items():
            for j, lever in self._levers(state, finger).items():
                kp_max = max(FREE_SHARE, POSTURE_SHARE) * F / self.travel_m * lever ** 2
                per_joint[j] = kp_max * (dt_s / ARMATURE_OMEGA_DT) ** 2
                floor[self.hand_pos[j]] = per_joint[j]
            for f, d, _, _ in finger.coupled:  # a follower's links: its driver's floor
                per_joint[finger.joints[f]] = per_joint[finger.joints[d]]
                floor[self.hand_pos[finger.joints[f]]] = per_joint[finger.joints[d]]
        links: dict[str, float] = {}
        for name in self.hand.fingers:
            for link in self.finger_links.get(name, ()):
                k = link  # up to the finger joint that turns it
                while k in self.link_parent and self.link_parent[k][0] not in per_joint:
                    k = self.link_parent[k][1]
                joint = self.link_parent.get(k, (None,))[0]
                links[link] = per_joint.get(joint, max(per_joint[j] for j in self.hand.fingers[name].joints))
        return floor, links

    # -- commands -----------------------------------------------------------------

    def command(self, q_ref: Mapping[str, float], holding: Sequence[str], moving: str | None = None,
                share: Mapping[str, float] | None = None) -> None:
        """Set the posture targets, the fingers that hold the object and the one that moves.

        Args:
            q_ref: joint -> target angle (every plan joint).
            holding: fingers that press on the object (their planned contacts).
            moving: the finger that tracks a path (free-finger motor caps), or None.
            share: finger -> fraction (0..1) of its balanced load it carries (handover);
                fingers not named carry all of theirs.
        """
        self.q_ref = dict(q_ref)
        self.holding = tuple(holding)
        self.moving = moving
        self.share = dict(share or {})
        self._motors_stale = True
        self.force_n = self.force_override or squeeze_force_n(self.mass, self.g_max, len(self.holding),
                                                              self.friction.mu, self.floor_n)
        self._update()

    def latch(self, fingers: Sequence[str]) -> None:
        """The fingers' posture targets become their current joint angles (where they
        touch the object), so the posture springs add no force to the balanced ones."""
        q = self.q()
        for f in fingers:
            for j in self.hand.fingers[f].joints:
                self.q_ref[j] = float(q[self.col[j]])
                self.q_target[self.hand_pos[j]] = self.q_ref[j]

    def back_off(self, fingers: Sequence[str], clearance_m: float = START_CLEARANCE_M) -> dict[str, float] | None:
        """One step of the start posture's clearance: the joints of ``fingers`` moved so that
        every link of theirs that overlaps the object (the sensor's closest points, negative
        distance) comes out along its contact normal to ``clearance_m`` outside it, or None
        when none overlaps. Per finger, over its free coordinates ``z`` (a coupled finger's
        drivers, `planner.hand.Finger.reduce`): rows ``g_k = n_k^T J_k`` (the normal speed of
        overlapping point ``k``, ``J_k`` its Jacobian) and ``g_k dz = -(clearance - d_k)``,
        solved by damped least squares and clipped at the joints' limits. A one-actuator
        finger's point moves along its one direction ``v``: it backs off by ``(c - d) / (v.n)``
        of its coordinate, sliding ``|v_t| / (v.n)`` times farther along the face.

        Returns:
            joint -> angle for the joints of the fingers that moved (followers by their
            coupling), or None.
        """
        per_link: dict[str, list] = {}
        for cp in self.sensor.closest_points(clearance_m):
            if self.link_finger.get(cp.link) in fingers and cp.distance_m < 0.0:
                per_link.setdefault(cp.link, []).append(cp)
        if not per_link:
            return None
        q = self.q()
        state = self.hand.state(q)
        out: dict[str, float] = {}
        for f in fingers:
            cps = [cp for link in self.finger_links.get(f, ()) for cp in per_link.get(link, ())]
            if not cps:
                continue
            fg = self.hand.fingers[f]
            cols = [self.col[j] for j in fg.joints]
            Js = state.point_jacobians([(cp.link, np.asarray(cp.point_m, float)) for cp in cps])
            G = np.array([fg.reduce(J[:, cols]).T @ np.asarray(cp.normal, float) for J, cp in zip(Js, cps)])
            b = np.array([-(clearance_m - cp.distance_m) for cp in cps])
            lam = 1e-3 * max(float(np.abs(G).max()), 1e-9)  # damping: a point the finger barely moves along n
            dz = G.T @ np.linalg.solve(G @ G.T + lam * lam * np.eye(len(G)), b)
            q_f = fg.step(q[cols], dz, self.hand.lower[cols], self.hand.upper[cols])
            out.update({j: float(v) for j, v in zip(fg.joints, q_f)})
        return out or None

    def palm_clearance(self, clearance_m: float = START_CLEARANCE_M) -> np.ndarray | None:
        """The translation (3,) that takes the object out of the palm's links (the links of no
        finger) to ``clearance_m`` outside them where it overlaps them in the sensor's geometry,
        or None when it does not: ``n_k . d >= clearance - d_k`` for every overlapping point
        ``k`` (normal ``n_k`` into the object, distance ``d_k < 0``), the least-norm ``d`` of
        those rows taken as equalities (the palm cannot back off: the object is placed)."""
        cps = [cp for cp in self.sensor.closest_points(clearance_m)
               if self.link_finger.get(cp.link, "palm") == "palm" and cp.distance_m < 0.0]
        if not cps:
            return None
        N = np.array([np.asarray(cp.normal, float) for cp in cps])
        b = np.array([clearance_m - cp.distance_m for cp in cps])
        d, *_ = np.linalg.lstsq(N, b, rcond=None)
        return d

    def fade(self, finger: str, share: float) -> None:
        """Hand over: the finger carries ``share`` (0..1) of its balanced load (applied at
        the next force solution)."""
        self.share[finger] = float(min(1.0, max(0.0, share)))

    def fade_palm(self, share: float) -> None:
        """Hand over: the palm carries ``share`` (0..1) of the load it would in the balance,
        the fingers the rest (applied at the next force solution)."""
        self.palm_share = float(min(1.0, max(0.0, share)))

    def set_gravity(self, g) -> None:
        """The gravity the simulator has now (palm frame; the replay sets the engine's):
        compensation and load follow it."""
        self.gravity = np.asarray(g, dtype=float).copy()

    def set_moving_target(self, q_finger: Mapping[str, float]) -> None:
        """New path waypoint of the moving finger (posture targets only)."""
        self.q_ref.update(q_finger)
        for j, v in q_finger.items():
            self.q_target[self.hand_pos[j]] = v

    def tracking_speed_rad_s(self, joints: Sequence[str]) -> np.ndarray:
        """How fast each joint can follow a moving target, rad/s (the current motors): a
        saturated posture spring pushes with ``cap`` against the damping ``Kd qdot``, so the
        joint's terminal speed is ``cap / Kd``; half of it leaves the other half of the cap
        to correct the tracking error and the model's errors (the lag then stays under
        ``cap / (2 Kp)``). The replay times a moving finger's path by it: a path timed
        faster is not followed, and a landing finger reached the end of its path millimetres
        short of the object."""
        speed = 0.5 * self.cap / np.maximum(self.kd, 1e-12)
        for f, d, m in self.coupled:  # a follower moves with its driver
            speed[f] = abs(m) * speed[d]
        return speed[[self.hand_pos[j] for j in joints]]

    def step(self) -> np.ndarray:
        """The joint torques for the next physics step, engine joint order (forces re-solved
        every ``UPDATE_EVERY`` calls): ``tau_ff + clip(Kp (q_ref - q), +-cap) - Kd qdot``."""
        self._tick += 1
        js = self.sensor.joint_states()
        if self._tick % UPDATE_EVERY == 0:
            self._update(js)
        return self.torques(js)

    def torques(self, js: JointStates) -> np.ndarray:
        """``tau_ff + clip(Kp (q_ref - q), +-cap) - Kd qdot`` at these joint states, clipped at
        the joints' limits as the motors saturate."""
        spring = np.clip(self.kp * (self.q_target - js.position), -self.cap, self.cap)
        return np.clip(self.tau + spring - self.kd * js.velocity, -self.tau_max, self.tau_max)

    # -- measurement ----------------------------------------------------------------

    def q(self, js: JointStates | None = None) -> np.ndarray:
        """Configuration in ``hand.joint_names`` order (of ``js``, or read now)."""
        js = self.sensor.joint_states() if js is None else js
        return js.position[self._hand_order]

    def contacts(self) -> list[Contact]:
        """Touching links (per link and face: mean point and normal) and approach points of
        holding fingers that do not touch."""
        per_link: dict[str, list] = {}
        # closest points within a small gap rather than this step's contact points: a contact
        # that opens for a step (a bounce) keeps its balanced force instead of flipping to
        # the approach force and back
        for cp in self.sensor.closest_points(CONTACT_GAP_M):
            per_link.setdefault(cp.link, []).append(cp)
        out = []
        for link in sorted(per_link, key=self.link_order.__getitem__):
            # one contact per face the link touches: a manifold on one face shares its normal,
            # while a link on an edge touches two faces, and the mean of their normals is the
            # normal of neither (forces along it would slip on both)
            groups: list[list] = []
            for c in per_link[link]:
                n = np.asarray(c.normal, float)
                for g in groups:
                    if float(n @ g[0]) >= FACE_COS:
                        g[1].append(c)
                        break
                else:
                    groups.append((n, [c]))
            for n0, cps in groups:
                if len(cps) == 1:
                    pt, n = np.asarray(cps[0].point_m, float), np.asarray(cps[0].normal, float)
                else:
                    pt = np.add.reduce([c.point_m for c in cps]) / len(cps)
                    n = np.add.reduce([c.normal for c in cps])
                out.append(Contact(self._finger(link), link, pt, n / np.linalg.norm(n), frame="palm"))
        touching = {c.finger for c in out}
        for f in self.holding:
            if f in touching:
                continue
            best = None
            for link in self.finger_links.get(f, ()):
                for cp in self.sensor.closest_points(APPROACH_M, link):
                    if best is None or cp.distance_m < best.distance_m:
                        best = cp
            if best is not None:
                n = np.asarray(best.normal, float)
                if np.linalg.norm(n) > 0.5:
                    out.append(Contact(f, best.link, best.point_m, n / np.linalg.norm(n), frame="palm", touching=False))
        return out

    def _finger(self, link: str) -> str | None:
        f = self.link_finger.get(link, "palm")
        return None if f == "palm" else f

    # -- control law ------------------------------------------------------------------

    def _finger_jacobians(self, state, contacts: Sequence[Contact]) -> list[np.ndarray]:
        """(3, n_finger_joints) linear Jacobian of each contact point (fixed to its link)
        over its finger's joints at the update's kinematic state, one pass for all."""
        Js = state.point_jacobians([(c.link, c.point) for c in contacts])
        return [J[:, [self.col[j] for j in self.hand.fingers[c.finger].joints]] for c, J in zip(contacts, Js)]

    def _update(self, js: JointStates | None = None) -> None:
        q = self.q(js)
        # one kinematic state per update: the gravity torques, the force solution's joint rows,
        # the contact Jacobians and the posture springs all read it (FK once)
        state = self.hand.state(q)
        tau = np.zeros(len(self.movable))
        if self.gravity.any():
            g_q = state.gravity_torques(self.gravity)
            for j, tj in zip(self.hand.joint_names, g_q):
                tau[self.hand_pos[j]] = tj
        F = self.force_n
        contacts = [c for c in self.contacts() if (c.finger is None and self.palm_share > 0.0) or c.finger in self.holding]
        forces = self._balanced(contacts, F, state)
        self.forces = {}
        pushing = [(c, f_c) for c, f_c in zip(contacts, forces) if c.finger is not None and np.any(f_c)]
        for (c, f_c), J in zip(pushing, self._finger_jacobians(state, [c for c, _ in pushing])):
            self.forces[c.link] = self.forces.get(c.link, 0.0) + f_c
            t = J.T @ f_c
            for j, tj in zip(self.hand.fingers[c.finger].joints, t):
                tau[self.hand_pos[j]] += tj
        self.tau = self._to_actuators(tau)
        if self._tick % (16 * UPDATE_EVERY) == 0 or self._motors_stale:
            self._set_motors(state, F)
            self._motors_stale = False

    def _to_actuators(self, tau: np.ndarray) -> np.ndarray:
        """Joint torques (engine order) as actuator torques: a follower's torque loads its
        driver's actuator times the multiplier (virtual work, `planner.hand.Finger.reduce`),
        and the follower gets none."""
        for f, d, m in self.coupled:
            tau[d] += m * tau[f]
            tau[f] = 0.0
        return tau

    def _levers(self, state, finger) -> dict[str, float]:
        """Actuated joint -> its lever to the finger's pad (the pad Jacobian's column over the
        finger's free coordinates, `planner.hand.Finger.reduce`), at least ``MIN_LEVER_M``."""
        J = state.frame_jacobian(finger.pad_link, finger.pad_p_link)[:3]
        J = finger.reduce(J[:, [self.col[j] for j in finger.joints]])
        return {finger.joints[k]: max(float(np.linalg.norm(J[:, i])), MIN_LEVER_M) for i, k in enumerate(finger.free)}

    def _balanced(self, contacts: list[Contact], F: float, state) -> list[np.ndarray]:
        """Forces of the contacts (zero for passive ones): the balanced solution, blended for
        the handover of fingers with a share below 1."""
        if not contacts:
            return []
        centre = np.asarray(self.sensor.object_pose().position_m, float)
        g_now = float(np.linalg.norm(self.gravity))
        full_load = np.zeros(6)
        if g_now > 0:
            full_load[:3] = self.mass * max(self.g_max, g_now) * self.gravity / g_now
        scale = g_now / max(self.g_max, g_now) if g_now > 0 else 0.0

        def solve(active: set, palm: bool = True) -> list[np.ndarray] | None:
            """Balanced forces for the load of the current gravity. While gravity ramps, the
            solutions for no load and for the full load are blended: a convex combination of
            two balanced force sets inside the cones balances the blended load inside them."""
            if 0.0 < scale < 1.0:
                lo, hi = solve_at(active, np.zeros(6), palm), solve_at(active, full_load, palm)
                if lo is not None and hi is not None:
                    return [(1.0 - scale) * a + scale * b for a, b in zip(lo, hi)]
            return solve_at(active, scale * full_load, palm)

        def solve_at(active: set, load: np.ndarray, palm: bool) -> list[np.ndarray] | None:
            idx = [i for i, c in enumerate(contacts) if c.touching and (c.finger in active or (c.finger is None and palm))]
            if not idx:
                return None
            per_finger = {}
            for i in idx:
                per_finger[contacts[i].finger] = per_finger.get(contacts[i].finger, 0) + 1
            targets = [np.zeros(3) if contacts[i].finger is None else F / per_finger[contacts[i].finger] * contacts[i].normal
                       for i in idx]
            fn_min = [0.0 if contacts[i].finger is None else MIN_NORMAL_RATIO * F / per_finger[contacts[i].finger] for i in idx]
            # a static hold meets the same problem step after step: reuse its solution
            key = (F, tuple(np.round(load / max(self.mass * 9.81, 1e-9), 2)), tuple(np.round(centre / CACHE_M)),
                   tuple((contacts[i].link, tuple(np.round(contacts[i].point / CACHE_M)),
                          tuple(np.round(contacts[i].normal, 2))) for i in idx))
            # the contacts moving within the cache's resolution of the last ones solved for
            # the same load and links reuse that solution (a contact drifting across a cell
            # boundary would otherwise re-solve for a change smaller than a cell)
            near = (F, key[1], tuple(contacts[i].link for i in idx))
            pts = np.array([contacts[i].point for i in idx])
            nrm = np.array([contacts[i].normal for i in idx])
            last = self._near.get(near)
            if key not in self._cache and last is not None and last[0].shape == pts.shape \
                    and float(np.max(np.abs(last[0] - pts))) <= CACHE_M and float(np.max(np.abs(last[1] - nrm))) <= 0.01 \
                    and float(np.max(np.abs(last[2] - centre))) <= CACHE_M:
                self._cache[key] = last[3]
            if key not in self._cache:
                if len(self._cache) > 256:
                    self._cache.clear()
                    self._near.clear()
                commanded = [contacts[i] for i in idx]
                # the rows hold the fingers' own weight under the gravity of this load (the ramp
                # blends the solutions for no load and the full load; g(q) is linear in gravity)
                rows = self._joint_rows(state, commanded, load[:3] / self.mass if self.mass > 0 else np.zeros(3))
                # the joints' limits say what the fingers can hold; only fingers without limits
                # keep the ratio cap on their forces
                bounded = all(c.finger is None or c.finger in self.limited for c in commanded)
                self._cache[key] = balance_forces([c.point for c in commanded], [c.normal for c in commanded],
                                                  targets, load, centre, self.friction, fn_min,
                                                  math.inf if bounded else MAX_FORCE_RATIO * F, joint_rows=rows)
            x = self._cache[key]
            if last is None or last[3] is not x:
                self._near[near] = (pts, nrm, centre.copy(), x)
            if x is None:
                return None
            out = [np.zeros(3) for _ in contacts]
            for i, f in zip(idx, x):
                out[i] = f
            return out

        full = solve(set(self.holding))
        if self.palm_share < 1.0 and any(c.finger is None for c in contacts):
            # the palm handing its load over: the fingers' solution without it, blended
            alone = solve(set(self.holding), palm=False)
            if alone is not None and full is not None:
                full = [self.palm_share * a + (1.0 - self.palm_share) * b for a, b in zip(full, alone)]
            elif alone is not None:  # (no balance with the palm's contacts: the fingers' alone)
                full = alone
        self.balanced = full is not None
        if full is None:  # no balanced forces at these contacts: plain squeeze along the normals
            full = [np.zeros(3) if c.finger is None else F * c.normal for c in contacts]
        # approaching fingers press along their normal (they carry nothing yet)
        for i, c in enumerate(contacts):
            if not c.touching and c.finger is not None:
                full[i] = F * c.normal
        fading = {f: s for f, s in self.share.items() if s < 1.0 and f in self.holding}
        if not fading:
            return full
        without = solve(set(self.holding) - set(fading))
        if without is None:
            without = [np.zeros(3) if c.finger in fading else f for c, f in zip(contacts, full)]
        s = min(fading.values())
        return [s * a + (1.0 - s) * b for a, b in zip(full, without)]

    def _joint_rows(self, state, contacts: Sequence[Contact], gravity) -> list:
        """The joint torque limits of every commanded finger over its contacts' forces and
        torsions (`planner.grip.torque_rows`) at ``q``, its own weight compensated under
        ``gravity`` (the gravity of the load solved for): the planner's limits, at the
        simulator's contacts."""
        gravity = np.asarray(gravity, dtype=float)
        g_q = state.gravity_torques(gravity) if gravity.any() else np.zeros(len(state.q))
        rows = []
        by_finger: dict[str, list[int]] = {}
        for i, c in enumerate(contacts):
            if c.finger is not None:
                by_finger.setdefault(c.finger, []).append(i)
        # one kinematics pass for every commanded contact
        order = [i for idx in by_finger.values() for i in idx]
        J_all = dict(zip(order, state.point_jacobians(
            [(contacts[i].link, contacts[i].point) for i in order], angular=True)))
        for f, idx in by_finger.items():
            # over the finger's actuated joints: a follower's torque loads its driver's motor
            fg = self.hand.fingers[f]
            cols = [self.col[j] for j in fg.joints]
            Js = [J_all[i] for i in idx]
            A, b = torque_rows([fg.reduce(J[:3, cols]) for J in Js], self.effort[[cols[k] for k in fg.free]],
                               fg.reduce(g_q[cols]),
                               torsion=[fg.reduce(J[3:, cols]).T @ contacts[i].normal for J, i in zip(Js, idx)])
            if len(A):
                rows.append((idx, A, b))
        return rows

    def _set_motors(self, state, F: float) -> None:
        """Posture springs: a pad displacement of ``travel_m`` costs ``share * F``
        (``share``: ``POSTURE_SHARE`` for holding fingers, ``FREE_SHARE`` for the others),
        i.e. ``Kp_j = share F / travel |J_pad[:, j]|^2``, saturating at ``share F |J_pad[:, j]|``;
        damping critical for the joint's armature."""
        kp, cap = np.zeros(len(self.movable)), np.zeros(len(self.movable))
        for name, finger in self.hand.fingers.items():
            share = FREE_SHARE if (name == self.moving or name not in self.holding) else POSTURE_SHARE
            for j, lever in self._levers(state, finger).items():
                k = self.hand_pos[j]
                kp[k] = share * F / self.travel_m * lever ** 2
                cap[k] = share * F * lever
        self.kp, self.cap = kp, cap  # (a follower: no spring, no motor)
        # a driver moves its followers: its armature is theirs too, times the multiplier squared
        inertia = self.armature.copy()
        for f, d, m in self.coupled:
            inertia[d] += m * m * self.armature[f]
        self.kd = 2.0 * np.sqrt(kp * inertia)
        for j, v in self.q_ref.items():
            self.q_target[self.hand_pos[j]] = v
