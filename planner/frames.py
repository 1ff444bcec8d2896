"""A plan as frames to draw: poses, plain plan data, its hand and object, paths resampled.

What the pictures share: the meshcat page (`planner.view`) and the pybullet pictures and
films (`planner.sim.render`, `planner.sim.film`) both turn a plan (`planner.plan.read_plan`
data) into a hand, an object and finger configurations through these helpers. Nothing here
draws, and nothing here imports pybullet, meshcat or the grasp layer.
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

import numpy as np

from planner.objects import GraspObject
from planner.plan_data import plan_hand, plan_object


def pose_matrix(R=None, t=None) -> np.ndarray:
    """A 4x4 pose of a rotation R (3, 3) and a translation t (3,) (identity where None)."""
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = R
    if t is not None:
        T[:3, 3] = t
    return T


def resample(path: np.ndarray, k: int) -> np.ndarray:
    """k configurations evenly spaced by joint-space arc length along a waypoint polyline."""
    path = np.asarray(path, float).reshape(len(path), -1)
    if len(path) == 1:
        return np.repeat(path, k, axis=0)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])
    if s[-1] <= 0:
        return np.repeat(path[:1], k, axis=0)
    t = np.linspace(0.0, s[-1], k)
    return np.column_stack([np.interp(t, s, path[:, j]) for j in range(path.shape[1])])


def plain_plan(plan) -> dict:
    """A plan as plain data (the file's content): `read_plan` gives a typed `Plan` or a dict."""
    return plan.to_dict() if hasattr(plan, "to_dict") else dict(plan)


def hand_of_plan(plan: Mapping, plan_path: Path):
    """The plan's `planner.hand.Hand` (its ``hand`` block, paths relative to the plan file)."""
    return plan_hand(plan, plan_path)


def object_of_plan(plan: Mapping, plan_path: Path) -> GraspObject:
    """The `planner.objects.GraspObject` of plain plan data at its planned pose (palm frame):
    `planner.plan_data.plan_object`, the rule a `Plan` reads its object with."""
    return plan_object(plan["object"], plan_path)
