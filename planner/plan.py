"""Plan data and its versioned export (YAML or JSON).

A plan is an ordered list of hand configurations (``states``) and the finger motions
between them (``steps``). Every state carries its contact patches in the object frame
(normals pointing INTO the object), its closure and its removable fingers, so another
tool can re-check the plan from the file alone. The schema is documented in
``docs/INTERFACES.md`` and versioned by ``schema_version``.

Same inputs, parameters and seed give a byte-identical file: floats are rounded to
``FLOAT_DIGITS`` significant digits and keys are written in a fixed order.

Schema version 1 grows only by optional keys (e.g. ``states[i].grip_force_n``): files
written before a key existed lack it and read as if it were null.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import yaml

from planner.errors import SpecError

SCHEMA_VERSION = 1
PLAN_KIND = "regrasp-plan"
FLOAT_DIGITS = 10
ACTIONS = ("lift", "move", "land")
FORMATS = {".yaml": "yaml", ".yml": "yaml", ".json": "json"}


def _num(x: float) -> float:
    """Round a float to FLOAT_DIGITS significant digits (stable text across runs)."""
    x = float(x)
    if x == 0.0:
        return 0.0
    return float(f"{x:.{FLOAT_DIGITS}g}")


def _vecs(a: np.ndarray) -> list[list[float]]:
    return [[_num(v) for v in row] for row in np.asarray(a, dtype=float).reshape(len(a), -1)]


@dataclass(frozen=True)
class PlanState:
    """One hand configuration of the plan.

    Attributes:
        fingers: finger -> slot label ("initial", "final", "int3", "lifted").
        patches: touching finger -> (p_obj (n, 3), n_in_obj (n, 3)).
        is_force_closure: closure of ``patches``.
        metric: signed closure metric of ``patches`` (see planner.closure).
        removable: fingers removable from this state (thesis Algorithm 1).
        q: joint values in the plan's ``joints`` order, radians.
        grip_force_n: normal force each finger must be able to press with to hold the
            object's weight under every gravity direction the plan was made for (the
            largest `planner.closure.min_grip_force` over them), N; None without gravity.
        grip_force_by_gravity_n: gravity direction name -> that direction's grip force, N;
            None without gravity.
    """

    fingers: Mapping[str, str]
    patches: Mapping[str, tuple[np.ndarray, np.ndarray]]
    is_force_closure: bool
    metric: float
    removable: tuple[str, ...]
    q: tuple[float, ...]
    grip_force_n: float | None = None
    grip_force_by_gravity_n: Mapping[str, float] | None = None

    def to_dict(self, joints: tuple[str, ...]) -> dict:
        return {
            "fingers": dict(self.fingers),
            "patches": {
                f: {"points": _vecs(p), "normals": _vecs(n)} for f, (p, n) in self.patches.items()
            },
            "closure": {"is_force_closure": bool(self.is_force_closure), "metric": _num(self.metric)},
            "grip_force_n": None if self.grip_force_n is None else _num(self.grip_force_n),
            "grip_force_by_gravity_n": None if self.grip_force_by_gravity_n is None
            else {str(k): _num(v) for k, v in self.grip_force_by_gravity_n.items()},
            "removable": sorted(self.removable),
            "q": {j: _num(v) for j, v in zip(joints, self.q)},
        }


@dataclass(frozen=True)
class PlanStep:
    """One finger motion between two states.

    Attributes:
        finger: the moving finger.
        action: "lift", "move" or "land".
        from_state, to_state: indices into the plan's states.
        joints: the finger's joint names, the columns of ``path``.
        path: joint waypoints (m, len(joints)), radians; first = from_state, last = to_state.
    """

    finger: str
    action: str
    from_state: int
    to_state: int
    joints: tuple[str, ...]
    path: tuple[tuple[float, ...], ...]

    def to_dict(self) -> dict:
        return {
            "finger": self.finger,
            "action": self.action,
            "from_state": int(self.from_state),
            "to_state": int(self.to_state),
            "joints": list(self.joints),
            "path": [[_num(v) for v in wp] for wp in self.path],
        }


@dataclass(frozen=True)
class Alternative:
    """A ranked gait ordering, compactly: ``order`` is "finger:action>slot" items;
    ``bottleneck_grip_force_n`` is the largest grip force along it (None without gravity)."""

    order: tuple[str, ...]
    bottleneck_metric: float
    gait_steps: int
    mean_metric: float
    bottleneck_grip_force_n: float | None = None

    def to_dict(self) -> dict:
        return {
            "order": list(self.order),
            "bottleneck_metric": _num(self.bottleneck_metric),
            "gait_steps": int(self.gait_steps),
            "mean_metric": _num(self.mean_metric),
            "bottleneck_grip_force_n": None if self.bottleneck_grip_force_n is None else _num(self.bottleneck_grip_force_n),
        }


@dataclass(frozen=True)
class Plan:
    """A finger-gaiting plan, ready to export."""

    hand: Mapping[str, Any]
    object: Mapping[str, Any]
    friction: Mapping[str, Any]
    inputs: Mapping[str, Any]
    parameters: Mapping[str, Any]
    summary: Mapping[str, Any]
    joints: tuple[str, ...]
    states: tuple[PlanState, ...]
    steps: tuple[PlanStep, ...]
    alternatives: tuple[Alternative, ...] = field(default_factory=tuple)

    def to_dict(self) -> dict:
        """The plan as plain data in schema order (the file's content)."""
        return {
            "schema_version": SCHEMA_VERSION,
            "kind": PLAN_KIND,
            "hand": _plain(self.hand),
            "object": _plain(self.object),
            "friction": _plain(self.friction),
            "inputs": _plain(self.inputs),
            "parameters": _plain(self.parameters),
            "summary": _plain(self.summary),
            "joints": list(self.joints),
            "states": [s.to_dict(self.joints) for s in self.states],
            "steps": [s.to_dict() for s in self.steps],
            "alternatives": [a.to_dict() for a in self.alternatives],
        }


def _plain(value: Any) -> Any:
    """Numpy scalars/arrays and tuples to plain rounded Python data."""
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_plain(v) for v in value]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return _num(value)
    return value


def plan_format(path: str | os.PathLike) -> str:
    """The export format chosen by a file suffix; SpecError for anything else."""
    suffix = Path(path).suffix.lower()
    if suffix not in FORMATS:
        raise SpecError(str(path), "", f"unknown plan file suffix {suffix!r}; use one of {', '.join(FORMATS)}")
    return FORMATS[suffix]


def dumps_plan(plan: Plan | Mapping[str, Any], fmt: str = "yaml") -> str:
    """Serialize a plan deterministically as YAML or JSON text."""
    data = plan.to_dict() if isinstance(plan, Plan) else _plain(plan)
    if fmt == "json":
        return json.dumps(data, indent=1) + "\n"
    return yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=100)


def write_plan(plan: Plan, path: str | os.PathLike) -> Path:
    """Write a plan as YAML or JSON (by suffix), atomically: never half a file.

    Raises:
        SpecError: unknown suffix. OutputError: the OS refused the write (nothing is left
            behind and an existing file is untouched).
    """
    from planner.fileio import write_atomic

    path = Path(path)
    text = dumps_plan(plan, plan_format(path))
    return write_atomic(path, text)


REQUIRED_KEYS = ("schema_version", "hand", "object", "friction", "joints", "states", "steps")
STATE_KEYS = ("patches", "closure", "removable", "q")
STEP_KEYS = ("finger", "action", "from_state", "to_state", "joints", "path")


def read_plan(path: str | os.PathLike) -> dict:
    """Read and check a plan file; SpecError names the file and key on any problem.

    Returns:
        The plan as plain data (the schema of ``Plan.to_dict``).
    """
    path = Path(path)
    fmt = plan_format(path)
    try:
        text = path.read_text()
    except OSError as err:
        raise SpecError(str(path), "", f"cannot read plan: {err.strerror}") from err
    try:
        data = json.loads(text) if fmt == "json" else yaml.safe_load(text)
    except (json.JSONDecodeError, yaml.YAMLError) as err:
        raise SpecError(str(path), "", f"not valid {fmt.upper()}: {str(err).splitlines()[0]}") from err
    if not isinstance(data, dict):
        raise SpecError(str(path), "", "expected a mapping at the top level")
    for key in REQUIRED_KEYS:
        if key not in data:
            raise SpecError(str(path), key, "missing key")
    if data["schema_version"] != SCHEMA_VERSION:
        raise SpecError(
            str(path), "schema_version", f"unsupported version {data['schema_version']!r}; supported: {SCHEMA_VERSION}"
        )
    joints = data["joints"]
    n_states = len(data["states"])
    for i, state in enumerate(data["states"]):
        for key in STATE_KEYS:
            if key not in state:
                raise SpecError(str(path), f"states[{i}].{key}", "missing key")
        missing = set(joints) - set(state["q"])
        if missing:
            raise SpecError(str(path), f"states[{i}].q", f"missing joints {sorted(missing)}")
        grip = state.get("grip_force_n")
        if grip is not None and (isinstance(grip, bool) or not isinstance(grip, (int, float)) or not grip >= 0):
            raise SpecError(str(path), f"states[{i}].grip_force_n", f"expected a force >= 0 in newtons or null, got {grip!r}")
        for finger, patch in state["patches"].items():
            pts, nrm = patch.get("points"), patch.get("normals")
            if pts is None or nrm is None or len(pts) != len(nrm):
                raise SpecError(str(path), f"states[{i}].patches.{finger}", "needs points and normals of equal length")
    for i, step in enumerate(data["steps"]):
        for key in STEP_KEYS:
            if key not in step:
                raise SpecError(str(path), f"steps[{i}].{key}", "missing key")
        if step["action"] not in ACTIONS:
            raise SpecError(str(path), f"steps[{i}].action", f"unknown action {step['action']!r}; actions are {', '.join(ACTIONS)}")
        for key in ("from_state", "to_state"):
            if not (isinstance(step[key], int) and 0 <= step[key] < n_states):
                raise SpecError(str(path), f"steps[{i}].{key}", f"expected a state index in 0..{n_states - 1}")
    return data
