"""MuJoCo behind the physics seam (`planner.sim.engine.PhysicsEngine`).

The scene is `planner.sim.mujoco_model.build`'s (its docstring and docs/ENGINES.md give every
setting and why: friction ``(mu, gamma)`` on every hand-object contact, elliptic cones,
``condim`` 4, contact time constant 2 dt critically damped, ``impratio`` 10, the hold weld);
this module only adapts it to the seam: the engine's joint order is the hand's, torques go
to one motor actuator per joint (clipped at the hand's effort limits, as the controller
clips them), and the readings are the seam's values.

Readings after a step. ``mj_step`` computes positions, contacts and forces at the start of
the step and then integrates, so after it ``qpos`` is one step ahead of the body poses and
the contact array. The object pose is read from ``qpos`` (as pybullet reports the integrated
pose), the contacts are the step's own (their forces are those that acted), and the
kinematics are brought up to ``qpos`` (``mj_kinematics``, cheap) before a closest-point
query, which reads the geoms' poses.

Friction that sticks (`friction_impratio`). A soft friction constraint lets a sticking
contact creep: MuJoCo's constraint obeys ``a1 + d (b v + k r) = (1 - d) a0`` and friction has
no position term, so under a steady tangential load (unconstrained acceleration ``a0``) a
"sticking" contact slides at ``v = (1 - d_f) a0 / (d_f b)``, ``b = 2 / (dmax tau)``: every step it
creeps ``(1 - d_f) / d_f`` of the distance ``a0`` would move it freely in one step. The
scene's ``impratio`` scales friction's regularizer down, ``(1 - d_f) / d_f = (1 - d) / (d
impratio)``; the replay holds loads for thousands of steps, so the engine takes friction as
stiff as MuJoCo's stiffest constraint (impedance ``mjMAXIMP`` = 0.9999), the closest it comes
to Bullet's hard friction; the slip limit ``mu`` is unchanged. Measured on the bundled iCub box
pair planned for execution: at the scene's default ``impratio`` 10 the thumb crept 6.2 mm palm
down and the object turned 22 deg palm up (4 of 6 directions failed); at this one it held in
every direction.

Contact points: MuJoCo puts a contact midway between the two surfaces; the seam (and
pybullet) gives the point on the object's surface, half the signed distance back along the
normal (sub-millimetre: `planner.sim.mujoco_model.CONTACT_SOLIMP`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from planner.errors import SimulationError
from planner.sim.engine import ContactPoint, HandTopology, JointStates, ObjectPose, World
from planner.sim import mujoco_model

import mujoco  # noqa: E402 (the back end of this module)


def friction_impratio(dmax: float = mujoco_model.CONTACT_SOLIMP[1]) -> float:
    """MuJoCo's ``impratio`` that makes a contact's friction as stiff as a constraint at
    MuJoCo's largest impedance (``mjMAXIMP``): ``((1 - dmax) / dmax) / ((1 - mjMAXIMP) /
    mjMAXIMP)``, with ``dmax`` the contacts' impedance once penetrated (101 for 0.99). See the
    module docstring (creep of a soft friction constraint)."""
    top = float(mujoco.mjMAXIMP)
    return max(mujoco_model.IMPRATIO, ((1.0 - dmax) / dmax) / ((1.0 - top) / top))


class MujocoEngine:
    """A `World` in a MuJoCo model (`planner.sim.engine.PhysicsEngine`).

    Args:
        world: what to build; its ``hand`` (the `planner.hand.Hand` of its URDF) is needed:
            MuJoCo's scene takes the hand's effort limits, mesh folders and inertia rules
            from it.
        client: pybullet's option; MuJoCo has no client (must be None).
        gui: a window; this engine has none (must be False).

    Raises:
        SimulationError: a window or client was asked for, or MuJoCo cannot build the scene.
    """

    name = "mujoco"

    def __init__(self, world: World, client: int | None = None, gui: bool = False):
        if gui:
            raise SimulationError("the mujoco engine opens no window here; use --engine pybullet for --gui")
        if client is not None:
            raise SimulationError("the mujoco engine takes no pybullet client")
        hand = getattr(world, "hand", None)
        if hand is None:
            raise SimulationError("the mujoco engine needs the World's hand (planner.sim.inputs.replay_world sets it)")
        self.dt_s = float(world.dt_s)
        self.scene = mujoco_model.build(hand, world.obj, world.friction, dt_s=self.dt_s,
                                        object_mass_kg=float(world.object_mass_kg),
                                        solver_iterations=int(world.solver_iterations), visual=world.visual,
                                        impratio=friction_impratio())
        s, m = self.scene, self.scene.model
        self.model, self.data = m, s.data
        joints = tuple(s.joint_names)
        self._ctrl = np.array([mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, j) for j in joints])
        self.topology = HandTopology(joints, tuple(s.link_names), s.link_parents())
        self._stale = False  # body poses behind qpos (after a step) until mj_kinematics

    # -- the seam ---------------------------------------------------------------------

    def set_gravity(self, g_mps2: Sequence[float]) -> None:
        self.scene.set_gravity(g_mps2)

    def reset_joints(self, q: Mapping[str, float]) -> None:
        self.scene.set_joint_positions(q)
        self._stale = False

    def joint_states(self) -> JointStates:
        return JointStates(self.scene.q(), self.scene.qd())

    def set_joint_torques(self, tau: np.ndarray) -> None:
        self.data.ctrl[self._ctrl] = np.asarray(tau, dtype=float)

    def step(self) -> None:
        mujoco.mj_step(self.model, self.data)
        self._stale = True

    def object_pose(self) -> ObjectPose:
        pos, quat = self.scene.object_pose()
        R = np.empty(9)
        x, y, z, w = quat
        mujoco.mju_quat2Mat(R, np.array([w, x, y, z]))
        return ObjectPose(tuple(float(v) for v in pos), quat, R.reshape(3, 3))

    def set_object_pose(self, position_m: Sequence[float], quat_xyzw: Sequence[float]) -> None:
        self.scene.set_object_pose(position_m, quat_xyzw)
        self._stale = False

    def hold_object(self, position_m: Sequence[float], quat_xyzw: Sequence[float]) -> None:
        self.scene.hold_object(position_m, quat_xyzw)
        self._stale = False

    def release_object(self) -> None:
        self.scene.release_object()

    def contacts(self) -> list[ContactPoint]:
        out = []
        for c in self.scene.contacts():
            n = np.asarray(c.normal, dtype=float)
            # the midpoint moved onto the object's surface: half the distance against the
            # normal into the object (towards the link when they overlap)
            p_obj = np.asarray(c.point_m, dtype=float) + 0.5 * float(c.distance_m) * n
            out.append(ContactPoint(c.link, p_obj, n, float(c.distance_m), float(c.normal_force_n)))
        return out

    def closest_points(self, gap_m: float, link: str | None = None) -> list[ContactPoint]:
        if self._stale:
            mujoco.mj_kinematics(self.model, self.data)
            self._stale = False
        return [ContactPoint(c.link, c.point_m, c.normal, float(c.distance_m), 0.0)
                for c in self.scene.closest_points(gap_m, link)]

    def link_masses(self) -> dict[str, float]:
        return self.scene.link_masses()

    def raise_link_inertia(self, link: str, floor_kg_m2: float) -> None:
        self.scene.raise_link_inertia(link, floor_kg_m2)

    def close(self) -> None:
        self.scene = self.model = self.data = None


__all__ = ["MujocoEngine"]
