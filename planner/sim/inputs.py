"""What a replay is built from: the typed plan, its hand and its object.

`typed_plan` reads a plan (file, data or `planner.plan_data.Plan`) through `planner.plan`'s one
parser; `plan_hand` and `load_hand_info` load the plan's hand and check every joint value of
the plan against its limits; `object_mass` gives the mass and size the replay builds the
plan's object with and `replay_world` the `planner.sim.engine.World` an engine builds. Files the plan names resolve relative to
the plan file (`planner.plan_data.plan_file`; its hand: `planner.plan_data.plan_hand`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from planner.model import Friction
from planner.objects import GraspObject
from planner.plan import plan_from_data, read_plan
from planner.plan_data import Plan, plan_hand  # noqa: F401 (plan_hand: re-exported for the replay)

#: A plan's joint values may exceed the hand's limits by this much (rad or m): rounding.
JOINT_LIMIT_TOL = 1e-3


def typed_plan(plan, strict: bool = False) -> Plan:
    """The typed plan of `planner.plan` (its one parser): a file is read and verified by
    `read_plan` (integrity, structure, closures, inputs; ``strict``: a changed or missing
    input is an error, not a warning), plan data is checked by `plan_from_data`, a `Plan`
    is used as it is."""
    if isinstance(plan, Plan):
        return plan
    if isinstance(plan, Mapping):
        return plan_from_data(dict(plan))
    return read_plan(plan, strict=strict)


@dataclass(frozen=True)
class HandInfo:
    """What the replay takes from the plan's hand (`load_hand_info`)."""

    urdf_path: str
    fingers: dict[str, tuple[str, ...]]  # finger -> joint names
    T_palm_base: np.ndarray  # pose of the URDF root link in the palm frame
    hand: Any  # planner.hand.Hand: Jacobians for the controller
    palm_normal: tuple[float, float, float]


def T_palm_root(hand) -> np.ndarray:
    """Pose of the URDF root link in the palm frame (identity when the root is the palm)."""
    root = getattr(getattr(hand, "model", None), "frames", None)
    if root is None or len(root) < 2 or not hasattr(hand, "state"):
        return np.eye(4)
    root_name = root[1].name  # frame 0 is "universe", frame 1 the root link
    if root_name == getattr(hand, "palm_frame", root_name):
        return np.eye(4)
    return np.asarray(hand.state(hand.q_open).link_pose(root_name), dtype=float)


def load_hand_info(plan: Plan, joints: list[str], hand=None) -> HandInfo:
    """Hand URDF, finger -> joints and the pinocchio model of the plan's hand; every joint
    value of the plan must lie within the hand's limits (``JOINT_LIMIT_TOL`` beyond)."""
    if hand is None:
        hand = plan_hand(plan)
    missing = [j for j in joints if j not in hand.joint_names]
    if missing:
        raise plan.error("joints", f"joints {missing[:5]} are not joints of hand {hand.name!r}")
    names = list(hand.joint_names)
    lo = np.array([hand.lower[names.index(j)] for j in joints]) - JOINT_LIMIT_TOL
    hi = np.array([hand.upper[names.index(j)] for j in joints]) + JOINT_LIMIT_TOL
    for i, st in enumerate(plan.states):
        bad = np.flatnonzero((np.asarray(st.q) < lo) | (np.asarray(st.q) > hi))
        if len(bad):
            j = joints[bad[0]]
            raise plan.error(f"states[{i}].q.{j}", f"{st.q[bad[0]]:.6g} is outside the joint's limits "
                                                   f"[{lo[bad[0]] + JOINT_LIMIT_TOL:.4g}, {hi[bad[0]] - JOINT_LIMIT_TOL:.4g}]")
    for i, step in enumerate(plan.steps):
        k = [joints.index(j) for j in step.joints]
        path = np.asarray(step.path)
        bad = np.argwhere((path < lo[k]) | (path > hi[k]))
        if len(bad):
            w, c = bad[0]
            raise plan.error(f"steps[{i}].path[{w}]", f"joint {step.joints[c]} at {path[w, c]:.6g} is outside its "
                                                      f"limits [{lo[k][c] + JOINT_LIMIT_TOL:.4g}, {hi[k][c] - JOINT_LIMIT_TOL:.4g}]")
    fingers = {f: tuple(fg.joints) for f, fg in hand.fingers.items()}
    return HandInfo(str(hand.urdf_path), fingers, T_palm_root(hand), hand, tuple(hand.palm_normal))


def object_mass(obj: GraspObject, density_kg_m3: float) -> tuple[float, float]:
    """The object's mass (kg: the plan's, which records the planner's; volume x
    ``density_kg_m3`` for an object without one) and its smallest half-extent (m)."""
    radius = float(np.min(obj.extents)) / 2
    mass = obj.mass_kg if obj.mass_given else density_kg_m3 * obj.volume_m3
    return float(mass), radius


def replay_world(info: HandInfo, obj: GraspObject, mass_kg: float, friction: Friction, dt_s: float,
                 solver_iterations: int, visual: bool = False):
    """The `planner.sim.engine.World` of a replay: the plan's hand at its root pose with the
    replay's inertias for placeholder ones (`planner.handtool.replay_inertia`: a solid box of
    the link's mass and collision size), the plan's object of ``mass_kg`` and friction."""
    from planner.handtool import replay_inertia
    from planner.sim.engine import World

    inertia = {link: tuple(box.tolist()) for link, (_, _, box) in replay_inertia(info.hand).items()}
    return World(info.urdf_path, info.T_palm_base, inertia, obj, float(mass_kg), friction, float(dt_s),
                 int(solver_iterations), visual, info.hand)
