"""pybullet behind the physics seam (`planner.sim.engine.PhysicsEngine`).

The one module of the replay that simulates with pybullet (the pictures draw with it in
`planner.sim.render`; the bodies are built by `planner.sim.scene`). It turns the seam's
names into pybullet's numbers (body ids, link indices: link -1 is the URDF's root) and back.

Settings (from the `planner.sim.engine.World`):

- the time step and ``numSolverIterations`` as given, no sub-steps, deterministic overlapping
  pairs (a replay is repeatable bit for bit);
- friction: Bullet multiplies the two bodies' lateral friction and combines spinning friction
  as ``s_a * mu_b + s_b * mu_a``; with the hand links at lateral friction 1 and spinning 0 and
  the object at ``mu`` and ``gamma``, every finger-object contact gets exactly the plan's
  ``mu`` (Coulomb) and ``gamma`` (torsional, metres) of the soft-finger model (thesis eq. 1).
  No rolling friction, no restitution, no linear or angular damping;
- joint damping off: Bullet applies a URDF's ``<dynamics damping>`` explicitly, and the
  Allegro's 3-10 N m s/rad on links of ~1e-5 kg m^2 diverges within a few steps under torque
  control (the replay's controller damps the joints itself, critically for their inertia);
- the default velocity motors off (zero force): the joints move under the torques of
  `set_joint_torques` alone;
- the object is held (`hold_object`) by a fixed constraint of at most ``HOLD_FORCE_N``;
- coupled joints (the hand's `planner.hand.Coupling`, ``q_f = m q_d + o``: a URDF ``<mimic>``,
  which pybullet's URDF loader ignores, or a hand.yaml coupling): one ``JOINT_GEAR``
  constraint per coupling, from the follower's link (parent) to the driver's (child).
  Bullet's gear row is ``qdot_parent + ratio qdot_child = 0`` with the position error
  ``q_parent + ratio q_child - relativePositionTarget`` corrected at the constraint's ERP, so
  ``gearRatio = -m`` and ``relativePositionTarget = o`` (measured on the test hand's
  ``right_2 = 1.2 right_1 + 0.1``: the other sign or the links swapped turns the follower the
  other way or at ``1/m``). ``GEAR_ERP`` corrects the whole error each step (at Bullet's default
  0.2 a swinging finger left 0.026 rad; at 1, 0.007 rad), ``GEAR_MAX_TORQUE`` makes it a gear
  train rather than a clutch.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Mapping, Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from planner.errors import SimulationError
from planner.sim.engine import ContactPoint, HandTopology, JointStates, ObjectPose, World
from planner.sim.scene import hand_body, object_body, p  # p: pybullet, its build banner silenced

#: The replay's object colour (its films).
OBJECT_RGBA = (0.85, 0.45, 0.15, 1.0)
#: Largest force of the constraint that holds the object while the fingers acquire it, N:
#: far above any squeeze of the bundled hands (a few N), so the object does not move.
HOLD_FORCE_N = 1000.0
#: A coupling's gear constraint: the share of its position error corrected per step, and its
#: largest torque, N m (1000: three orders above any finger joint's effort limit, as the hold).
GEAR_ERP = 1.0
GEAR_MAX_TORQUE = 1000.0


def no_display() -> bool:
    """No display for a window: on Linux (X11 or Wayland) neither variable is set (macOS and
    Windows have one whenever a user is logged in)."""
    return sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


class PybulletEngine:
    """A `World` in a pybullet client (`planner.sim.engine.PhysicsEngine`).

    Args:
        world: what to build.
        client: an existing pybullet client id: the bodies are added there and removed by
            `close`; None: a private DIRECT (or GUI) client, disconnected by `close`.
        gui: open a GUI window for the private client (needs a display).

    Raises:
        SimulationError: pybullet could not connect or build the scene.
    """

    name = "pybullet"

    def __init__(self, world: World, client: int | None = None, gui: bool = False):
        self.own = client is None
        if self.own:
            if gui and no_display():  # pybullet's window would end the process from C (exit 1, nothing said)
                raise SimulationError("--gui needs a display, and DISPLAY (or WAYLAND_DISPLAY) is not set: replay "
                                      "without --gui, or film it with --gif FILE")
            cid = p.connect(p.GUI if gui else p.DIRECT)
            if cid < 0:
                raise SimulationError("could not connect to pybullet" + (" GUI (is there a display?)" if gui else ""))
        else:
            cid = int(client)
        self.cid, self.dt_s = cid, float(world.dt_s)
        self.bodies: list[int] = []
        self._hold: int | None = None
        self._gears: list[int] = []  # the couplings' constraints (removed with the bodies by `close`)
        try:
            self._build(world)
        except BaseException:
            self.close()
            raise

    def _build(self, world: World) -> None:
        cid = self.cid
        p.setPhysicsEngineParameter(fixedTimeStep=self.dt_s, numSolverIterations=int(world.solver_iterations),
                                    numSubSteps=0, deterministicOverlappingPairs=1, physicsClientId=cid)
        p.setGravity(0, 0, 0, physicsClientId=cid)
        T = np.asarray(world.T_palm_base, float)
        base_pos = T[:3, 3].tolist()
        base_quat = Rotation.from_matrix(T[:3, :3]).as_quat().tolist()
        self.hand = hand_body(cid, world.urdf_path, base_pos=base_pos, base_quat_xyzw=base_quat,
                              inertia_from_file=True, visual=world.visual)
        self.bodies.append(self.hand)
        obj = world.obj
        self.obj = object_body(cid, obj.shape, list(obj.size), obj.mesh_path, list(obj.position), list(obj.quat_xyzw),
                               float(world.object_mass_kg), OBJECT_RGBA)
        self.bodies.append(self.obj)

        # names <-> pybullet numbers (link -1: the root)
        n = p.getNumJoints(self.hand, physicsClientId=cid)
        root = p.getBodyInfo(self.hand, physicsClientId=cid)[0].decode()
        self.link_index: dict[str, int] = {root: -1}
        self.jidx: dict[str, int] = {}
        movable, parent, link_of = [], {}, {-1: root}
        infos = [p.getJointInfo(self.hand, i, physicsClientId=cid) for i in range(n)]
        for i, ji in enumerate(infos):
            link_of[i] = ji[12].decode()
            self.link_index[link_of[i]] = i
            if ji[2] in (p.JOINT_REVOLUTE, p.JOINT_PRISMATIC):
                self.jidx[ji[1].decode()] = i
            if ji[2] != p.JOINT_FIXED:
                movable.append(i)
        for i, ji in enumerate(infos):
            parent[link_of[i]] = (ji[1].decode(), link_of[ji[16]])
        self.link_name = link_of
        self.movable = movable
        names = [infos[i][1].decode() for i in movable]
        self.topology = HandTopology(tuple(names), tuple(link_of[i] for i in range(-1, n)), parent)

        # friction and damping: the module docstring
        for link in range(-1, n):
            p.changeDynamics(self.hand, link, lateralFriction=1.0, spinningFriction=0.0, rollingFriction=0.0,
                             restitution=0.0, linearDamping=0.0, angularDamping=0.0, physicsClientId=cid)
            if link >= 0:
                p.changeDynamics(self.hand, link, jointDamping=0.0, physicsClientId=cid)
        for link, moments in world.link_inertia_kg_m2.items():
            if link in self.link_index:
                p.changeDynamics(self.hand, self.link_index[link], localInertiaDiagonal=list(moments),
                                 physicsClientId=cid)
        fr = world.friction
        p.changeDynamics(self.obj, -1, lateralFriction=fr.mu, spinningFriction=fr.gamma, rollingFriction=0.0,
                         restitution=0.0, linearDamping=0.0, angularDamping=0.0, physicsClientId=cid)
        for i in self.movable:  # pybullet's default velocity motors off: torques act alone
            p.setJointMotorControl2(self.hand, i, p.VELOCITY_CONTROL, force=0.0, physicsClientId=cid)
        for c in getattr(world.hand, "couplings", ()):  # coupled joints: gear constraints (module docstring)
            if c.joint in self.jidx and c.follows in self.jidx:
                gear = p.createConstraint(self.hand, self.jidx[c.joint], self.hand, self.jidx[c.follows], p.JOINT_GEAR,
                                          [0, 0, 1], [0, 0, 0], [0, 0, 0], physicsClientId=cid)
                p.changeConstraint(gear, gearRatio=-float(c.multiplier), relativePositionTarget=float(c.offset),
                                   erp=GEAR_ERP, maxForce=GEAR_MAX_TORQUE, physicsClientId=cid)
                self._gears.append(gear)

    # -- the seam ---------------------------------------------------------------------

    def set_gravity(self, g_mps2: Sequence[float]) -> None:
        p.setGravity(*[float(v) for v in g_mps2], physicsClientId=self.cid)

    def reset_joints(self, q: Mapping[str, float]) -> None:
        for j, v in q.items():
            p.resetJointState(self.hand, self.jidx[j], v, 0.0, physicsClientId=self.cid)

    def joint_states(self) -> JointStates:
        st = p.getJointStates(self.hand, self.movable, physicsClientId=self.cid)
        return JointStates(np.array([s[0] for s in st]), np.array([s[1] for s in st]))

    def set_joint_torques(self, tau: np.ndarray) -> None:
        p.setJointMotorControlArray(self.hand, self.movable, p.TORQUE_CONTROL, forces=np.asarray(tau).tolist(),
                                    physicsClientId=self.cid)

    def step(self) -> None:
        p.stepSimulation(physicsClientId=self.cid)

    def object_pose(self) -> ObjectPose:
        pos, quat = p.getBasePositionAndOrientation(self.obj, physicsClientId=self.cid)
        R = np.reshape(p.getMatrixFromQuaternion(quat, physicsClientId=self.cid), (3, 3))
        return ObjectPose(pos, quat, R)

    def set_object_pose(self, position_m: Sequence[float], quat_xyzw: Sequence[float]) -> None:
        p.resetBasePositionAndOrientation(self.obj, list(position_m), list(quat_xyzw), physicsClientId=self.cid)
        p.resetBaseVelocity(self.obj, [0, 0, 0], [0, 0, 0], physicsClientId=self.cid)

    def hold_object(self, position_m: Sequence[float], quat_xyzw: Sequence[float]) -> None:
        self._hold = p.createConstraint(self.obj, -1, -1, -1, p.JOINT_FIXED, [0, 0, 0], [0, 0, 0], list(position_m),
                                        childFrameOrientation=list(quat_xyzw), physicsClientId=self.cid)
        p.changeConstraint(self._hold, maxForce=HOLD_FORCE_N, physicsClientId=self.cid)

    def release_object(self) -> None:
        if self._hold is not None:
            p.removeConstraint(self._hold, physicsClientId=self.cid)
            self._hold = None

    def _points(self, raw) -> list[ContactPoint]:
        # pybullet: [3] link of the hand, [6] point on the object, [7] normal on the object
        # (towards the hand), [8] distance, [9] normal force
        name = self.link_name
        return [ContactPoint(name[c[3]], c[6], (-c[7][0], -c[7][1], -c[7][2]), c[8], c[9]) for c in raw]

    def contacts(self) -> list[ContactPoint]:
        return self._points(p.getContactPoints(self.hand, self.obj, physicsClientId=self.cid))

    def closest_points(self, gap_m: float, link: str | None = None) -> list[ContactPoint]:
        if link is None:
            raw = p.getClosestPoints(self.hand, self.obj, gap_m, physicsClientId=self.cid)
        else:
            raw = p.getClosestPoints(self.hand, self.obj, gap_m, linkIndexA=self.link_index[link],
                                     physicsClientId=self.cid)
        return self._points(raw)

    def link_masses(self) -> dict[str, float]:
        return {name: p.getDynamicsInfo(self.hand, i, physicsClientId=self.cid)[0] for i, name in self.link_name.items()}

    def raise_link_inertia(self, link: str, floor_kg_m2: float) -> None:
        i = self.link_index[link]
        diag = p.getDynamicsInfo(self.hand, i, physicsClientId=self.cid)[2]
        p.changeDynamics(self.hand, i, localInertiaDiagonal=[max(float(d), floor_kg_m2) for d in diag],
                         physicsClientId=self.cid)

    def render_bodies(self) -> tuple[int, int, int]:
        """(hand body, object body, client): what `planner.sim.render` draws a frame of."""
        return self.hand, self.obj, self.cid

    def close(self) -> None:
        if self.own:
            if self.cid is not None:
                p.disconnect(physicsClientId=self.cid)
        else:
            for c in self._gears + ([self._hold] if self._hold is not None else []):
                p.removeConstraint(c, physicsClientId=self.cid)
            for b in self.bodies:
                p.removeBody(b, physicsClientId=self.cid)
        self.bodies, self._gears, self._hold = [], [], None
        self.cid = None if self.own else self.cid
