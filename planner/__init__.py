"""Finger-gaiting regrasp planner for dexterous robot hands.

The public API is re-exported here lazily, so that ``import planner.closure`` or
``import planner.graph`` pulls in no kinematics, collision, OMPL or pybullet code.
"""

from __future__ import annotations

import importlib
import types

_EXPORTS = {
    # the one-call API (planner.api): each command as a function of paths or objects;
    # ``planner.plan`` is also the plan-file module (planner.plan.read_plan), callable
    "check": "planner.api",
    "replay": "planner.api",
    "synth": "planner.api",
    "verify": "planner.api",
    "AuditReport": "planner.audit",
    "audit_plan": "planner.audit",
    # errors
    "InputError": "planner.errors",
    "KinematicsError": "planner.errors",
    "MotionError": "planner.errors",
    "NoSequenceError": "planner.errors",
    "PlannerError": "planner.errors",
    "SimulationError": "planner.errors",
    "SpecError": "planner.errors",
    "UnknownNameError": "planner.errors",
    # the value types every module shares
    "Contact": "planner.model",
    "Friction": "planner.model",
    "tangent_basis": "planner.model",
    # closure (thesis eqs. 1-7, Algorithm 1)
    "CONTACT_MODELS": "planner.closure",
    "Closure": "planner.hull",
    "apply_contact_model": "planner.closure",
    "batch_grasp_closure": "planner.closure",
    "closure_from_wrenches": "planner.closure",
    "contact_wrenches": "planner.closure",
    "grasp_closure": "planner.closure",
    "min_grip_force": "planner.closure",
    "removable_fingers": "planner.closure",
    # hands, objects, contacts
    "Finger": "planner.hand",
    "Hand": "planner.hand",
    "GraspObject": "planner.objects",
    "make_object": "planner.objects",
    "collisions": "planner.contacts",
    "contact_patches": "planner.contacts",
    # grasps
    "GraspSpec": "planner.grasp",
    "RealizedGrasp": "planner.realization",
    "load_grasp": "planner.grasp",
    "realize": "planner.realization",
    # graph and planning
    "GaitProblem": "planner.graph",
    "Slot": "planner.graph",
    "build_graph": "planner.graph",
    "GaitSequence": "planner.gait_search",
    "greedy": "planner.gait_search",
    "search": "planner.gait_search",
    "PlanOptions": "planner.options",
    "plan_regrasp": "planner.regrasp",
    # the grip model (what the hand's joints hold)
    "FingerStatics": "planner.grip",
    "grasp_hold": "planner.grip",
    "hold_capacity": "planner.grip",
    "torque_demand": "planner.grip",
    # replay (pybullet, imported when first used)
    "replay_gravity_set": "planner.sim.verify",
    "replay_plan": "planner.sim.replay",
    # plans
    "Plan": "planner.plan_data",
    "read_plan": "planner.plan",
    "write_plan": "planner.plan_data",
}

__all__ = sorted([*_EXPORTS, "plan"])

try:
    from importlib.metadata import PackageNotFoundError, version as _version

    __version__ = _version("regrasp-planner")
except PackageNotFoundError:  # a checkout that was never installed
    __version__ = "0+unknown"


class CallablePlanModule(types.ModuleType):
    """The class of the module `planner.plan`: ``planner.plan.read_plan`` reads a plan file
    and ``planner.plan("a.yaml", "b.yaml", ...)`` is the one-call planner (`planner.api.plan`)."""

    def __call__(self, initial, final, **options):
        return importlib.import_module("planner.api").plan(initial, final, **options)


def __getattr__(name: str):
    if name == "plan":  # the module planner.plan, callable as the one-call planner
        return importlib.import_module("planner.plan")
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'planner' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))
