"""The physics seam: what the replay needs from a physics engine, and nothing engine-specific.

The replay (`planner.sim.replay`) and its controller (`planner.sim.controller`) talk to an
engine only through `PhysicsEngine`, built from the project's own types (`World`: the hand's
URDF and pose, the `planner.objects.GraspObject`, the plan's `planner.model.Friction`, the
time step). Everything is named, never numbered: joints by their URDF joint names, hand links
by their URDF link names (the root link included), so an engine that numbers its bodies
otherwise (pybullet's link indices, MuJoCo's body ids) keeps its numbers to itself.

Frames and units: the world frame IS the palm frame (the hand is fixed); positions in m,
quaternions (x, y, z, w), joint values in rad (m for prismatic joints), torques in N m (N),
forces in N, inertias in kg m^2. A contact's normal is the unit surface normal of the object
pointing INTO the object (the direction the hand link pushes), as everywhere in the planner.

`planner.sim.engine_pybullet.PybulletEngine` and `planner.sim.engine_mujoco.MujocoEngine`
implement it (`engine_for`; `default_engine`: pybullet when installed, else MuJoCo).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from planner.model import Friction
from planner.objects import GraspObject


@dataclass(frozen=True)
class World:
    """What an engine builds: one fixed hand and one free object, gravity off.

    Attributes:
        urdf_path: the hand's URDF (its mesh links collide as convex hulls).
        T_palm_base: (4, 4) pose of the URDF's root link in the palm (= world) frame.
        link_inertia_kg_m2: URDF link -> principal moments of inertia (3,) that replace the
            URDF's (`planner.handtool.replay_inertia`: placeholder inertias), about the link's
            inertial frame.
        obj: the object (shape, size, pose in the palm frame).
        object_mass_kg: the object's mass.
        friction: the plan's friction: every hand-object contact gets Coulomb ``mu`` and
            torsional ``gamma`` (m) of the soft-finger model, no rolling friction, no
            restitution, no damping.
        dt_s: physics time step, s.
        solver_iterations: contact solver iterations per step.
        visual: also load the hand's visual shapes (only a picture needs them).
        hand: the `planner.hand.Hand` of ``urdf_path`` (MuJoCo's scene takes its effort
            limits, mesh folders and inertia rules from it; pybullet reads the URDF alone).
    """

    urdf_path: str
    T_palm_base: np.ndarray
    link_inertia_kg_m2: Mapping[str, tuple[float, float, float]]
    obj: GraspObject
    object_mass_kg: float
    friction: Friction
    dt_s: float
    solver_iterations: int
    visual: bool = False
    hand: Any = field(default=None, compare=False, repr=False)


@dataclass(frozen=True)
class HandTopology:
    """The hand as the engine built it.

    Attributes:
        joints: the movable joints (revolute or prismatic), in the engine's order: the order
            of `JointStates` and of `PhysicsEngine.set_joint_torques`.
        links: every link, the root first, in the engine's order (contacts of one step are
            grouped in this order).
        parent: link -> (the joint it hangs from, its parent link), every link but the root.
    """

    joints: tuple[str, ...]
    links: tuple[str, ...]
    parent: Mapping[str, tuple[str, str]] = field(default_factory=dict)

    @property
    def root(self) -> str:
        """The root link (the base the hand is fixed by)."""
        return self.links[0]

    def link_owner(self, finger_of_joint: Mapping[str, str], default: str) -> dict[str, str]:
        """Link -> the finger of the nearest joint above it that belongs to one
        (``finger_of_joint``), else ``default`` (e.g. the palm), for every link."""
        out = {}
        for link in self.links:
            owner, k = None, link
            while owner is None and k in self.parent:
                joint, k = self.parent[k]
                owner = finger_of_joint.get(joint)
            out[link] = owner or default
        return out


@dataclass(frozen=True)
class JointStates:
    """The movable joints' positions (rad or m) and velocities (rad/s or m/s), in the
    engine's joint order (`HandTopology.joints`)."""

    position: np.ndarray
    velocity: np.ndarray


@dataclass(frozen=True)
class ObjectPose:
    """The object's pose in the palm (= world) frame.

    Attributes:
        position_m: (3,) origin of the object frame.
        quat_xyzw: (4,) unit quaternion.
        R: (3, 3) its rotation matrix, as the engine computes it (every consumer of one pose
            then agrees with the engine to the last bit).
    """

    position_m: tuple[float, float, float]
    quat_xyzw: tuple[float, float, float, float]
    R: np.ndarray

    @property
    def T(self) -> np.ndarray:
        """(4, 4) homogeneous transform palm <- object."""
        T = np.eye(4)
        T[:3, :3] = self.R
        T[:3, 3] = self.position_m
        return T


@dataclass(frozen=True, slots=True)
class ContactPoint:
    """One point where a hand link meets the object (or comes within a gap of it).

    Attributes:
        link: the hand's URDF link name.
        point_m: (3,) the point on the object's surface, palm (= world) frame.
        normal: (3,) unit surface normal INTO the object, palm frame.
        distance_m: signed separation (negative: penetration), m.
        normal_force_n: the normal force the engine applied at the point this step, N (0 for
            a closest point that is not a contact).
    """

    link: str
    point_m: Sequence[float]
    normal: Sequence[float]
    distance_m: float
    normal_force_n: float


class Sensor(Protocol):
    """What the controller reads from the simulation (a `PhysicsEngine` is one; a test may
    give synthetic readings)."""

    def joint_states(self) -> JointStates:
        """Positions and velocities of the movable joints, engine order."""

    def object_pose(self) -> ObjectPose:
        """The object's current pose."""

    def closest_points(self, gap_m: float, link: str | None = None) -> list[ContactPoint]:
        """Hand-object point pairs closer than ``gap_m`` (every link, or ``link`` only),
        links in `HandTopology.links` order."""


class PhysicsEngine(Sensor, Protocol):
    """A built `World` the replay steps (module docstring: names, frames, units)."""

    name: str  # e.g. "pybullet": named in what a replay reports
    topology: HandTopology
    dt_s: float

    def set_gravity(self, g_mps2: Sequence[float]) -> None:
        """Gravity vector, palm frame, m/s^2."""

    def reset_joints(self, q: Mapping[str, float]) -> None:
        """Put the named joints at these values with zero velocity."""

    def set_joint_torques(self, tau: np.ndarray) -> None:
        """Torques (forces) on every movable joint for the next step, engine order; the
        joints have no other motor."""

    def step(self) -> None:
        """Advance one time step ``dt_s``."""

    def set_object_pose(self, position_m: Sequence[float], quat_xyzw: Sequence[float]) -> None:
        """Put the object at a pose, at rest."""

    def hold_object(self, position_m: Sequence[float], quat_xyzw: Sequence[float]) -> None:
        """Hold the object rigidly at a pose (as if a hand outside the scene held it) until
        `release_object`."""

    def release_object(self) -> None:
        """Let go of the object held by `hold_object`."""

    def contacts(self) -> list[ContactPoint]:
        """This step's hand-object contact points (the engine's contact manifold, which may
        include points a little apart: filter on ``distance_m``)."""

    def link_masses(self) -> dict[str, float]:
        """Link -> mass, kg, as simulated."""

    def raise_link_inertia(self, link: str, floor_kg_m2: float) -> None:
        """Raise every principal moment of a link's inertia to at least ``floor_kg_m2`` (the
        reflected rotor inertia of a geared motor: `planner.sim.controller`'s armature)."""

    def close(self) -> None:
        """Free what the engine built (and its connection, when it owns one)."""


#: The physics engines a replay can run in (`engine_for`), the preferred default first, and
#: the Python package each needs.
ENGINES = {"pybullet": "pybullet", "mujoco": "mujoco"}


def engine_installed(name: str) -> bool:
    """Whether the package of engine ``name`` can be imported here (without importing it)."""
    import importlib.util

    return name in ENGINES and importlib.util.find_spec(ENGINES[name]) is not None


def require_engine(name: str) -> str:
    """``name`` when it is a known, installed engine.

    Raises:
        InputError: no engine of that name.
        SimulationError: its package is not installed (one line naming the package).
    """
    from planner.errors import InputError, SimulationError

    if name not in ENGINES:
        raise InputError(f"unknown physics engine {name!r}; choose from: {', '.join(ENGINES)}")
    if not engine_installed(name):
        have = [e for e in ENGINES if engine_installed(e)]
        raise SimulationError(f"physics engine {name!r} is not installed: pip install {ENGINES[name]}"
                              + (f" (installed: {', '.join(have)})" if have else " (no engine is installed)"))
    return name


def default_engine() -> str:
    """The engine a replay uses when none is asked for: pybullet when it is installed (it has
    wheels only up to Python 3.11), else MuJoCo.

    Raises:
        SimulationError: neither is installed.
    """
    for name in ENGINES:
        if engine_installed(name):
            return name
    from planner.errors import SimulationError

    raise SimulationError("no physics engine is installed: pip install mujoco (or pybullet, Python <= 3.11)")


def engine_for(name: str, world: World, **options: Any) -> PhysicsEngine:
    """Build ``world`` in the engine named ``name`` (``options``: the engine's own, e.g.
    pybullet's ``client``/``gui``).

    Raises:
        InputError: no engine of that name.
        SimulationError: its package is not installed.
    """
    require_engine(name)
    if name == "pybullet":
        from planner.sim.engine_pybullet import PybulletEngine  # pybullet: loaded only here

        return PybulletEngine(world, **options)
    from planner.sim.engine_mujoco import MujocoEngine  # mujoco: loaded only there

    return MujocoEngine(world, **options)
