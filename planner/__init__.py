"""Finger-gaiting regrasp planner for dexterous robot hands."""

from planner.errors import (
    InputError,
    KinematicsError,
    MotionError,
    NoSequenceError,
    PlannerError,
    SimulationError,
    SpecError,
    UnknownNameError,
)

__all__ = sorted(
    [
        "InputError",
        "KinematicsError",
        "MotionError",
        "NoSequenceError",
        "PlannerError",
        "SimulationError",
        "SpecError",
        "UnknownNameError",
    ]
)
