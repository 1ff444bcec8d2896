"""Plan data and its versioned export (YAML or JSON): the plan's frozen types and writing.

A plan is an ordered list of hand configurations (``states``) and the finger motions
between them (``steps``). Every state carries its contact patches in the object frame
(normals pointing INTO the object), its closure and its removable fingers, so another
tool can re-check the plan from the file alone. The schema is documented in
``docs/INTERFACES.md`` and versioned by ``schema_version``. Reading a plan file back
(the one plan parser and its checks) is `planner.plan.read_plan`.

Same inputs, parameters and seed give a byte-identical file: floats are rounded to
``FLOAT_DIGITS`` significant digits and keys are written in a fixed order.

Integrity (schema version 2). A plan is what a user hands to a robot, so it proves it is
complete and unaltered: its last key, ``integrity``, holds the number of states and steps
and the sha256 of the canonical content (every other key, as compact JSON with sorted
keys: the same digest for the YAML and the JSON file; `integrity_record`). Files are never
recorded by an absolute path: an input that is a bundled grasp (`planner.resources`) is
recorded by name (``inputs.initial: {bundled: icub/box_ir2m.yaml, sha256: ..}``), any
other by its path relative to the plan file (``{path: ../a.yaml, sha256: ..}``);
``hand.spec`` is a bundled hand's name or the path of a hand.yaml relative to the plan
file; ``object.mesh`` is relative to the plan file. So a plan of bundled grasps replays
from anywhere, a plan moved together with its files stays valid, and both stay
byte-identical.

Schema versions grow only by optional keys (e.g. ``states[i].grip_force_n``): files
written before a key existed lack it and read as if it were null.

Schema 4 (reposing): a state may carry ``object_pose`` ({position, quat_xyzw}, palm frame),
the object's pose there when it differs from the plan's ``object`` pose (which is the pose
of state 0); a step with ``action: repose`` (``finger: object``) moves the object along
``object_path`` (one pose per waypoint, [x, y, z, qx, qy, qz, qw]) while every touching
finger follows by its joints (``joints``/``path``: those fingers' joints) with its contacts
fixed on the object.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import yaml

from planner.errors import InputError, SpecError
from planner.fileio import as_path, check_hand_file, describe, sha256_file, write_atomic
from planner.model import PALM, Friction, holders
from planner.objects import GraspObject
from planner.resources import bundled_grasp_name, bundled_hand_name, is_hand_path

SCHEMA_VERSION = 4
PLAN_KIND = "regrasp-plan"
FLOAT_DIGITS = 10
ACTIONS = ("lift", "move", "land", "repose")
#: The ``finger`` of a reposing step (schema 4): the object moves, held by every touching finger.
OBJECT = "object"
FORMATS = {".yaml": "yaml", ".yml": "yaml", ".json": "json"}


def _num(x: float) -> float:
    """Round a float to FLOAT_DIGITS significant digits (stable text across runs)."""
    x = float(x)
    if x == 0.0:
        return 0.0
    return float(f"{x:.{FLOAT_DIGITS}g}")


def _vecs(a: np.ndarray) -> list[list[float]]:
    return [[_num(v) for v in row] for row in np.asarray(a, dtype=float).reshape(len(a), -1)]


def pose_vector(T) -> tuple[float, ...]:
    """A pose (4, 4) as (x, y, z, qx, qy, qz, qw), the quaternion with qw >= 0."""
    from scipy.spatial.transform import Rotation

    T = np.asarray(T, dtype=float)
    quat = Rotation.from_matrix(T[:3, :3]).as_quat()
    if quat[3] < 0:
        quat = -quat
    return tuple(float(v) for v in (*T[:3, 3], *quat))


def pose_matrix(pose) -> np.ndarray:
    """(x, y, z, qx, qy, qz, qw) as a pose (4, 4)."""
    from scipy.spatial.transform import Rotation

    pose = np.asarray(pose, dtype=float)
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(pose[3:7]).as_matrix()
    T[:3, 3] = pose[:3]
    return T


def order_entry(finger: str, action: str, label: str | None = None) -> str:
    """One entry of a plan's ``summary.order``, the gait sequence other tools read: a lift
    ``finger:lift``, a landing ``finger:land>label`` (the finger's label in the state it
    reaches), a reposing move ``object:repose``; finger moves between them are not listed."""
    return f"{finger}:land>{label}" if action == "land" else f"{finger}:{action}"


def object_still(a, b) -> bool:
    """Two consecutive waypoints of a reposing step's object path (each (x, y, z, qx, qy, qz,
    qw)) are one pose: the object does not move there (the fingers re-posture on it)."""
    return bool(np.allclose(np.asarray(a, dtype=float), np.asarray(b, dtype=float), rtol=0.0, atol=1e-12))


def pose_between(a, b, s: float) -> np.ndarray:
    """The pose a fraction ``s`` (0..1) of the way from pose ``a`` to pose ``b`` (each
    (x, y, z, qx, qy, qz, qw)): the position along the line, the orientation along the
    shortest rotation (slerp), as a reposing step's object moves between two waypoints (the
    replay's reference, the viewer's frames)."""
    import math

    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    qa, qb = a[3:7] / np.linalg.norm(a[3:7]), b[3:7] / np.linalg.norm(b[3:7])
    dot = float(qa @ qb)
    if dot < 0.0:
        qb, dot = -qb, -dot
    if dot > 1.0 - 1e-9:
        q = qa + s * (qb - qa)
    else:
        th = math.acos(min(1.0, dot))
        q = (math.sin((1.0 - s) * th) * qa + math.sin(s * th) * qb) / math.sin(th)
    return np.concatenate([a[:3] + s * (b[:3] - a[:3]), q / np.linalg.norm(q)])


def pose_dict(pose) -> dict:
    """A state's ``object_pose`` in the file: {position, quat_xyzw}."""
    return {"position": [_num(v) for v in pose[:3]], "quat_xyzw": [_num(v) for v in pose[3:7]]}


def _patch_dict(patch) -> dict:
    """A patch's file form: points, normals and (schema 3, when known) the link of each point."""
    out = {"points": _vecs(patch[0]), "normals": _vecs(patch[1])}
    links = getattr(patch, "links", None)
    if links is not None:
        out["links"] = [str(link) for link in links]
    return out


@dataclass(frozen=True)
class PlanState:
    """One hand configuration of the plan.

    Attributes:
        fingers: finger -> slot label ("initial", "final", "int3", "lifted").
        patches: owner -> `planner.model.Patch` (p_obj (n, 3), n_in_obj (n, 3), links):
            the touching fingers, then the palm (`planner.model.PALM`) when it holds.
        is_force_closure: closure of ``patches``.
        metric: signed closure metric of ``patches`` (see planner.closure).
        removable: fingers removable from this state (thesis Algorithm 1).
        q: joint values in the plan's ``joints`` order, radians.
        grip_force_n: normal force each finger must be able to press with to hold the
            object's weight under every gravity direction the plan was made for (the
            largest `planner.closure.min_grip_force` over them), N; None without gravity.
        grip_force_by_gravity_n: gravity direction name -> that direction's grip force, N;
            None without gravity.
        hold_factor_by_gravity: gravity direction name -> the largest multiple of the
            object's weight the hand's joints hold there (`planner.grip.hold_capacity`, at
            most `planner.grip.FACTOR_MAX`); None without gravity.
        object_pose: the object's pose in this state, (x, y, z, qx, qy, qz, qw) in the palm
            frame, when a reposing step moved it from the plan's ``object`` pose; None: that
            pose (`Plan.object_at`).
    """

    fingers: Mapping[str, str]
    patches: Mapping[str, tuple[np.ndarray, np.ndarray]]
    is_force_closure: bool
    metric: float
    removable: tuple[str, ...]
    q: tuple[float, ...]
    grip_force_n: float | None = None
    grip_force_by_gravity_n: Mapping[str, float] | None = None
    hold_factor_by_gravity: Mapping[str, float] | None = None
    object_pose: tuple[float, ...] | None = None

    @property
    def touching(self) -> tuple[str, ...]:
        """The fingers on the object (those with a contact patch; the palm is not a finger)."""
        return holders(self.patches)

    @property
    def palm_holds(self) -> bool:
        """The palm is one of the state's contacts (`planner.model.PALM`)."""
        return PALM in self.patches

    def to_dict(self, joints: tuple[str, ...]) -> dict:
        return {
            "fingers": dict(self.fingers),
            "patches": {f: _patch_dict(patch) for f, patch in self.patches.items()},
            "closure": {"is_force_closure": bool(self.is_force_closure), "metric": _num(self.metric)},
            "grip_force_n": None if self.grip_force_n is None else _num(self.grip_force_n),
            "grip_force_by_gravity_n": None if self.grip_force_by_gravity_n is None
            else {str(k): _num(v) for k, v in self.grip_force_by_gravity_n.items()},
            **({} if self.hold_factor_by_gravity is None else
               {"hold_factor_by_gravity": {str(k): _num(v) for k, v in self.hold_factor_by_gravity.items()}}),
            "removable": sorted(self.removable),
            "q": {j: _num(v) for j, v in zip(joints, self.q)},
            **({} if self.object_pose is None else {"object_pose": pose_dict(self.object_pose)}),
        }


@dataclass(frozen=True)
class PlanStep:
    """One finger motion between two states, or a reposing move of the object.

    Attributes:
        finger: the moving finger (`OBJECT` for a reposing move).
        action: "lift", "move", "land" or "repose".
        from_state, to_state: indices into the plan's states.
        joints: the finger's joint names (a reposing move: the joints of every touching
            finger), the columns of ``path``.
        path: joint waypoints (m, len(joints)), radians; first = from_state, last = to_state.
        object_path: a reposing move's object poses, one per waypoint of ``path``:
            (x, y, z, qx, qy, qz, qw) in the palm frame; None for a finger's move.
    """

    finger: str
    action: str
    from_state: int
    to_state: int
    joints: tuple[str, ...]
    path: tuple[tuple[float, ...], ...]
    object_path: tuple[tuple[float, ...], ...] | None = None

    def to_dict(self) -> dict:
        return {
            "finger": self.finger,
            "action": self.action,
            "from_state": int(self.from_state),
            "to_state": int(self.to_state),
            "joints": list(self.joints),
            "path": [[_num(v) for v in wp] for wp in self.path],
            **({} if self.object_path is None else {"object_path": [[_num(v) for v in p] for p in self.object_path]}),
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
    """A finger-gaiting plan, ready to export (or read back by `read_plan`).

    ``object`` is a `planner.objects.GraspObject` and ``friction`` a `planner.model.Friction`
    (their file forms are accepted and converted); the file's ``object.mass_kg`` is always
    the mass the planner used (the grasp's, or volume x density when it gave none), so the
    replay simulates the same object. ``source`` is the file it was read from (None for
    a plan made in memory); relative paths in it (inputs, mesh, hand spec) are relative
    to that file's folder. ``plan["states"]`` reads the plan as plain data (the file's
    content), for code that works on plans as data.
    """

    hand: Mapping[str, Any]
    object: GraspObject
    friction: Friction
    inputs: Mapping[str, Any]
    parameters: Mapping[str, Any]
    summary: Mapping[str, Any]
    joints: tuple[str, ...]
    states: tuple[PlanState, ...]
    steps: tuple[PlanStep, ...]
    alternatives: tuple[Alternative, ...] = field(default_factory=tuple)
    source: str | None = field(default=None, compare=False)

    def __post_init__(self):
        if isinstance(self.object, Mapping):  # the file form
            object.__setattr__(self, "object", plan_object(self.object, self.source))
        if isinstance(self.friction, Mapping):
            object.__setattr__(self, "friction", Friction(**self.friction))

    def __getitem__(self, key: str):
        return self.to_dict()[key]

    def __contains__(self, key: str) -> bool:
        return key in self.to_dict()

    def error(self, key: str, message: str) -> SpecError:
        """A SpecError about this plan at a key path (names the file it was read from)."""
        return SpecError(self.source or "<plan>", key, message)

    def q_of(self, state: int) -> dict[str, float]:
        """Joint name -> value of a state (rad or m)."""
        return dict(zip(self.joints, self.states[state].q))

    def object_at(self, state: int) -> GraspObject:
        """The object at its pose in a state (the plan's ``object`` unless a reposing step
        moved it: `PlanState.object_pose`)."""
        pose = self.states[state].object_pose
        return self.object if pose is None else self.object.with_pose(pose_matrix(pose))

    @property
    def reposes(self) -> bool:
        """The plan moves the object (has a reposing step)."""
        return any(s.action == "repose" for s in self.steps)

    def to_dict(self, relative_to: str | os.PathLike | None = None) -> dict:
        """The plan as plain data in schema order (the file's content), sealed with its
        ``integrity`` record.

        Args:
            relative_to: the folder the file will be written to: input and mesh paths are
                written relative to it (None: as they are).
        """
        data = self._content(relative_to)
        data["integrity"] = integrity_record(data)
        return data

    def _content(self, relative_to) -> dict:
        inputs = {k: _input_record(v, relative_to, self.source) for k, v in _plain(self.inputs).items()}
        hand = _plain(self.hand)
        obj = _plain({**self.object.to_data(), "mass_kg": self.object.mass_kg})
        if isinstance(hand.get("spec"), str):
            hand["spec"] = _hand_spec(hand["spec"], relative_to, self.source)
        if relative_to is not None and isinstance(obj.get("mesh"), str):
            obj["mesh"] = _relative(obj["mesh"], relative_to, self.source)
        return {
            # the lowest schema that holds the plan: one without reposing stays readable by schema-3 tools
            "schema_version": SCHEMA_VERSION if self.reposes else 3,
            "kind": PLAN_KIND,
            "hand": hand,
            "object": obj,
            "friction": _plain(self.friction.to_data()),
            "inputs": inputs,
            "parameters": _plain(self.parameters),
            "summary": _plain(self.summary),
            "joints": list(self.joints),
            "states": [s.to_dict(self.joints) for s in self.states],
            "steps": [s.to_dict() for s in self.steps],
            "alternatives": [a.to_dict() for a in self.alternatives],
        }


def _absolute(path: str, source: str | None) -> Path:
    """``path`` as written in a plan: absolute, or relative to the folder of ``source`` (the
    plan file; the working directory for a plan made in memory)."""
    p = Path(path)
    return Path(os.path.abspath(p if p.is_absolute() else (Path(source).parent if source else Path.cwd()) / p))


def plan_object(data: Mapping[str, Any], source) -> GraspObject:
    """The object of a plan's ``object`` block (its file form): a relative ``mesh`` is
    relative to the plan file ``source`` (the working directory for a plan made in memory)."""
    obj = dict(data)
    if isinstance(obj.get("mesh"), str):
        obj["mesh"] = str(_absolute(obj["mesh"], None if source in (None, "<plan>") else str(source)))
    return GraspObject.from_data(obj)


def _relative(path: str, folder, source: str | None) -> str:
    """``path`` (see `_absolute`) relative to ``folder``, with forward slashes."""
    return Path(os.path.relpath(_absolute(path, source), os.path.abspath(folder))).as_posix()


def _input_record(value, relative_to, source: str | None):
    """An ``inputs`` entry as written: a bundled grasp by name (``bundled``), any other file
    by its path (relative to ``relative_to`` when given)."""
    if not isinstance(value, dict) or not isinstance(value.get("path"), str):
        return value

    name = bundled_grasp_name(_absolute(value["path"], source))
    if name is not None:
        return {"bundled": name, **{k: v for k, v in value.items() if k != "path"}}
    if relative_to is not None:
        value["path"] = _relative(value["path"], relative_to, source)
    return value


def _hand_spec(spec: str, relative_to, source: str | None) -> str:
    """``hand.spec`` as written: a bundled hand by name, any other hand.yaml (or its folder)
    by its path (relative to ``relative_to`` when given)."""

    if not is_hand_path(spec):
        return spec
    name = bundled_hand_name(_absolute(spec, source))
    if name is not None:
        return name
    return _relative(spec, relative_to, source) if relative_to is not None else spec


def plan_file(ref: str, source: str | os.PathLike | None) -> Path | None:
    """A file a plan refers to (``hand.spec``, ``object.mesh``, an input's ``path``): absolute,
    or relative to the plan file's folder (the working directory for a plan made in memory);
    None when no such file or folder exists."""
    p = _absolute(ref, None if source in (None, "<plan>") else str(source))
    return p if p.exists() else None


def plan_hand_ref(hand: Mapping[str, Any], source: str | os.PathLike | None) -> str:
    """What to load the plan's hand from (`planner.hand.Hand.load`): ``hand.spec`` as a bundled
    hand's name or the path it names, else the hand's name (a bundled hand)."""

    spec = hand.get("spec")
    if isinstance(spec, str) and spec:
        if not is_hand_path(spec):
            return spec
        found = plan_file(spec, source)
        if found is not None:
            return str(found)
    return str(hand.get("name"))


def hand_files_record(hand) -> dict[str, str]:
    """What a plan records of its hand's files (``hand.files``): the hand.yaml and the URDF by
    their names, each mesh by its path relative to the URDF's folder (names that do not depend
    on where the hand is installed) -> its sha256, so that `planner.audit` refuses a plan whose
    hand changed since planning."""
    spec, urdf, *meshes = getattr(hand, "files", ())
    urdf_dir = Path(urdf).parent
    names = [Path(spec).name, Path(urdf).name] + [Path(os.path.relpath(m, urdf_dir)).as_posix() for m in meshes]
    return {n: sha256_file(f) for n, f in zip(names, (spec, urdf, *meshes))}


def plan_hand(plan, source: str | os.PathLike | None = None):
    """The plan's `planner.hand.Hand`: the one resolver of a plan's hand (replay, audit, view,
    films). ``plan``: a `Plan` or plain plan data (then ``source`` is its file). The hand is
    where `plan_hand_ref` says; a hand.yaml is read within bounds and an error names the
    plan's ``hand.spec``, never the hand file's content."""
    from planner.hand import Hand  # pinocchio and coal: loaded only when a hand is

    if isinstance(plan, Plan):
        block, source = plan.hand, plan.source
    else:
        block = plan.get("hand") or {}
    ref = plan_hand_ref(block, source)
    path = Path(ref)
    if is_hand_path(ref) and path.is_file():
        return Hand(path, check_hand_file(path, str(source or "<plan>"), "hand.spec"))
    return Hand.load(ref)


def canonical_sha256(content: Mapping[str, Any]) -> str:
    """sha256 of plan content as compact JSON with sorted keys (format independent)."""
    text = json.dumps(content, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=True)
    return hashlib.sha256(text.encode("ascii")).hexdigest()


def integrity_record(content: Mapping[str, Any]) -> dict:
    """The ``integrity`` key of a plan: counts and the digest of everything else."""
    body = {k: v for k, v in content.items() if k != "integrity"}
    return {"states": len(body.get("states") or ()), "steps": len(body.get("steps") or ()),
            "sha256": canonical_sha256(body)}


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
    if "integrity" not in data:
        data["integrity"] = integrity_record(data)
    if fmt == "json":
        return json.dumps(data, indent=1) + "\n"
    return yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=100)


def write_plan(plan: Plan, path: str | os.PathLike) -> Path:
    """Write a plan as YAML or JSON (by suffix), atomically: never half a file.

    Raises:
        SpecError: unknown suffix. OutputError: the OS refused the write (nothing is left
            behind and an existing file is untouched).
    """

    path = as_path(path, "plan", "a plan file path (.yaml/.json)")
    if not isinstance(plan, (Plan, Mapping)):
        raise InputError(f"plan: expected a Plan or plan data, got {describe(plan)}")
    fmt = plan_format(path)
    data = plan.to_dict(relative_to=path.absolute().parent) if isinstance(plan, Plan) else plan
    return write_atomic(path, dumps_plan(data, fmt))
