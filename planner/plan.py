"""Plan data and its versioned export (YAML or JSON).

A plan is an ordered list of hand configurations (``states``) and the finger motions
between them (``steps``). Every state carries its contact patches in the object frame
(normals pointing INTO the object), its closure and its removable fingers, so another
tool can re-check the plan from the file alone. The schema is documented in
``docs/INTERFACES.md`` and versioned by ``schema_version``.

Same inputs, parameters and seed give a byte-identical file: floats are rounded to
``FLOAT_DIGITS`` significant digits and keys are written in a fixed order.

Integrity (schema version 2). A plan is what a user hands to a robot, so it proves it is
complete and unaltered: its last key, ``integrity``, holds the number of states and steps
and the sha256 of the canonical content (every other key, as compact JSON with sorted
keys: the same digest for the YAML and the JSON file). `read_plan` refuses a file whose
record is missing (e.g. truncated), whose counts or digest do not match, or whose
structure is inconsistent (`plan_from_data`: steps chained in order, each step's finger
lifted, moved or landed as its action says, the other joints unchanged, paths starting
and ending at their states, finite numbers within the documented ranges), and re-checks
every state's force closure from its patches. Files are never recorded by an absolute
path: an input that is a bundled grasp (`planner.resources`) is recorded by name
(``inputs.initial: {bundled: icub/box_ir2m.yaml, sha256: ..}``), any other by its path
relative to the plan file (``{path: ../a.yaml, sha256: ..}``); ``hand.spec`` is a bundled
hand's name or the path of a hand.yaml relative to the plan file; ``object.mesh`` is
relative to the plan file. So a plan of bundled grasps replays from anywhere, a plan moved
together with its files stays valid, and both stay byte-identical. Version 1 files (no
integrity record) are still read, with a `PlannerWarning`.

Schema versions grow only by optional keys (e.g. ``states[i].grip_force_n``): files
written before a key existed lack it and read as if it were null.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import sys
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import yaml

import planner
from planner.closure import CONTACT_MODELS, grasp_closure
from planner.errors import IntegrityError, PlannerError, PlannerWarning, SpecError, UnknownNameError
from planner.fileio import MAX_GRASP_BYTES, MAX_PLAN_BYTES, Reader, load_json, load_yaml, read_limited, sha256_file, shown, write_atomic
from planner.model import Friction
from planner.objects import SHAPES, SIZE_LENGTHS, SIZE_MEANING, GraspObject
from planner.resources import bundled_grasp, bundled_grasp_name, bundled_hand_name, is_hand_path

SCHEMA_VERSION = 2
#: Versions `read_plan` reads (1: no integrity record, read with a warning).
READABLE_VERSIONS = (1, 2)
PLAN_KIND = "regrasp-plan"
FLOAT_DIGITS = 10
ACTIONS = ("lift", "move", "land")
FORMATS = {".yaml": "yaml", ".yml": "yaml", ".json": "json"}

#: Ranges a plan file must respect (README "Hardening / plan integrity").
MAX_STATES = 10_000          # states (and steps) per plan
MAX_WAYPOINTS = 10_000       # waypoints per step path
MAX_POINTS = 10_000          # points per contact patch
MAX_JOINTS = 256             # joints per hand
MAX_JOINT_VALUE = 100.0      # |joint value|, rad or m (the hand's limits are checked by the replay)
MAX_COORD_M = 10.0           # |object position| and |contact point|, m
MAX_MASS_KG = 1000.0
#: A path's ends must equal its states' joint values within this (rad or m).
PATH_END_TOL = 1e-6
#: Recorded closure metrics are re-computed within this (relative, absolute).
METRIC_RTOL, METRIC_ATOL = 1e-6, 1e-9


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
        hold_factor_by_gravity: gravity direction name -> the largest multiple of the
            object's weight the hand's joints hold there (`planner.grip.hold_capacity`, at
            most `planner.grip.FACTOR_MAX`); None without gravity.
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

    @property
    def touching(self) -> tuple[str, ...]:
        """The fingers on the object (those with a contact patch)."""
        return tuple(self.patches)

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
            **({} if self.hold_factor_by_gravity is None else
               {"hold_factor_by_gravity": {str(k): _num(v) for k, v in self.hold_factor_by_gravity.items()}}),
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
        if isinstance(self.object, Mapping):  # the file form: a relative mesh is relative to the plan file
            obj = dict(self.object)
            if isinstance(obj.get("mesh"), str):
                obj["mesh"] = str(_absolute(obj["mesh"], self.source))
            object.__setattr__(self, "object", GraspObject.from_data(obj))
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
            "schema_version": SCHEMA_VERSION,
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

    path = Path(path)
    fmt = plan_format(path)
    data = plan.to_dict(relative_to=path.absolute().parent) if isinstance(plan, Plan) else plan
    return write_atomic(path, dumps_plan(data, fmt))


# --------------------------------------------------------------------------- reading


def read_plan(path: str | os.PathLike, *, strict: bool = False) -> Plan:
    """Read, verify and type a plan file (the one plan parser: `regrasp replay` uses it).

    Checks, in order: size and YAML limits (`planner.fileio`), the schema version, the
    structure (`plan_from_data`), the integrity record (counts, then the sha256 of the
    content), every state's force closure re-computed from its patches, and the inputs:
    a recorded input file that is gone or whose sha256 changed is a `PlannerWarning`
    (the plan carries its own states, so it stays replayable), or an error with ``strict``.

    Returns:
        The typed `Plan` (``source`` = this file).

    Raises:
        SpecError: naming the file and the key path of the first problem;
            `IntegrityError` when the plan is incomplete or altered.
    """
    path = Path(path)
    fmt = plan_format(path)
    text = read_limited(path, MAX_PLAN_BYTES, "plan")
    data = load_json(text, path) if fmt == "json" else load_yaml(text, path, "plan")
    plan = plan_from_data(data, path)
    version = data["schema_version"]
    if version >= 2:
        _check_counts(data, str(path))
    else:
        warnings.warn(f"{path}: schema_version {version} plan has no integrity record: its completeness cannot be "
                      f"proven (re-plan to get a version {SCHEMA_VERSION} file)", PlannerWarning, stacklevel=2)
    _check_closures(plan, str(path))  # before the digest: names the state that does not match
    if version >= 2:
        _check_digest(data, str(path))
    _check_inputs(plan, str(path), strict)
    return plan


def _check_counts(data: Mapping, src: str) -> None:
    rec = data.get("integrity")
    if not isinstance(rec, Mapping) or not isinstance(rec.get("sha256"), str):
        raise IntegrityError(src, "integrity", "missing integrity record: the plan is truncated or was not "
                                               "written by regrasp plan")
    for key in ("states", "steps"):
        if rec.get(key) != len(data[key]):
            raise IntegrityError(src, key, f"the plan has {len(data[key])} {key}, its integrity record says "
                                           f"{shown(rec.get(key))}: truncated or edited")


def _check_digest(data: Mapping, src: str) -> None:
    if canonical_sha256({k: v for k, v in data.items() if k != "integrity"}) != data["integrity"]["sha256"]:
        raise IntegrityError(src, "integrity.sha256", "the content does not match its sha256 digest: "
                                                      "the plan was altered or damaged after it was written")


def _check_closures(plan: Plan, src: str) -> None:
    """Every state's recorded closure must be the closure of its patches (ms per state)."""

    friction = plan.friction
    for i, st in enumerate(plan.states):
        c = grasp_closure(dict(st.patches), friction) if st.patches else None
        fc = bool(c.is_force_closure) if c is not None else False
        if fc != st.is_force_closure or (c is not None and not math.isclose(
                c.metric, st.metric, rel_tol=METRIC_RTOL, abs_tol=METRIC_ATOL)):
            got = f"{'force closure' if fc else 'not force closure'}, metric {c.metric if c else 0.0:.6g}"
            raise IntegrityError(src, f"states[{i}].closure", f"does not match the state's patches ({got}; "
                                 f"recorded {'force closure' if st.is_force_closure else 'not force closure'}, "
                                 f"metric {st.metric:.6g})")


def recorded_input(rec, source) -> tuple[Path | None, str, str | None] | None:
    """A plan's record of an input file (``inputs.<name>``: ``bundled`` or ``path``, ``sha256``):
    (the file or None, how messages name it, the problem: gone, or changed since planning;
    None when present and unchanged). None when the record names no file."""

    if not isinstance(rec, Mapping):
        return None
    if rec.get("bundled"):
        shown = f"bundled grasp {rec['bundled']}"
        try:
            p = bundled_grasp(rec["bundled"])
        except UnknownNameError:
            p = None
    elif rec.get("path"):
        shown, p = f"input file {rec['path']}", plan_file(rec["path"], source)
    else:
        return None
    if p is None or not p.is_file():
        return None, shown, f"{shown} is gone"
    if rec.get("sha256") and sha256_file(p, MAX_GRASP_BYTES) != rec["sha256"]:
        return p, shown, f"{shown} changed since planning (sha256 differs)"
    return p, shown, None


def _check_inputs(plan: Plan, src: str, strict: bool) -> None:
    for name, rec in plan.inputs.items():
        found = recorded_input(rec, src)
        problem = found[2] if found is not None else None
        if problem and strict:
            raise SpecError(src, f"inputs.{name}", problem)
        if problem:
            warnings.warn(f"{src}: inputs.{name}: {problem}; replaying the plan's own states", PlannerWarning,
                          stacklevel=3)


def plan_from_data(data: Any, source: str | os.PathLike | None = None) -> Plan:
    """Check plan data (the file schema) and build the typed `Plan`.

    Structure only (no integrity record, closure or input check: `read_plan` adds those
    for files): required keys and types; finite numbers within the module's ranges; every
    state has a value for every joint; steps chained in order (step k goes from state k to
    state k + 1, ``len(steps) == len(states) - 1``); a lift takes a touching finger off, a
    land puts a free finger on, a move keeps it off, and no other finger's contact changes;
    a step moves only its finger's joints and its path starts and ends at its states.

    Raises:
        SpecError: naming ``source`` and the key path of the first problem.
    """
    src = str(source) if source is not None else "<plan>"
    r = Reader(src, data, got=shown, got_value=shown, ranged=True).mapping()
    r.require(*REQUIRED_KEYS, message="missing key")
    version = data["schema_version"]
    if isinstance(version, bool) or version not in READABLE_VERSIONS:
        raise r.fail(f"unsupported plan version {shown(version)}; this planner reads "
                     f"{', '.join(map(str, READABLE_VERSIONS))} (re-plan the grasps)", "schema_version")
    if data.get("kind", PLAN_KIND) != PLAN_KIND:
        raise r.fail(f"expected {PLAN_KIND!r}, got {shown(data.get('kind'))}", "kind")
    hand = r.child("hand").mapping()
    hand.child("name").name()
    if hand.get("spec") is not None:
        hand.child("spec").name()
    obj = _check_object(r.child("object"))
    friction = r.child("friction").mapping().value
    try:
        Friction(friction.get("mu"), friction.get("gamma"), friction.get("edges", 5))
    except PlannerError as err:
        raise r.fail(str(err), "friction") from None
    friction = {"mu": float(friction["mu"]), "gamma": float(friction["gamma"]), "edges": int(friction.get("edges", 5))}
    inputs = r.at(data.get("inputs") or {}, "inputs").mapping()
    for name, rec in inputs.items():
        rec.mapping()
        if ("path" in rec) == ("bundled" in rec):
            raise rec.fail("expected either path (a file, relative to the plan) or bundled (a bundled grasp's name)")
        kind = "path" if "path" in rec else "bundled"
        rec.child(kind).name()
        sha = rec.get("sha256")
        if not (isinstance(sha, str) and len(sha) == 64 and all(c in "0123456789abcdef" for c in sha)):
            raise rec.fail("expected 64 lowercase hex digits", "sha256")
    parameters = r.at(data.get("parameters") or {}, "parameters").mapping()

    parameters.child("contact_model", "patch").choice(CONTACT_MODELS, "contact model", valid="valid:")
    joints = tuple(j.name() for _, j in r.child("joints").seq(MAX_JOINTS, 1).items())
    if len(set(joints)) != len(joints):
        raise r.fail("joint names repeat", "joints")
    states = tuple(_check_state(s, i, joints) for i, s in r.child("states").seq(MAX_STATES, 1).items())
    raw_steps = r.child("steps").seq(MAX_STATES).items()
    if len(raw_steps) != len(states) - 1:
        raise r.fail(f"{len(raw_steps)} steps for {len(states)} states: a plan has one step less than "
                     f"states (truncated or edited)", "steps")
    steps = tuple(_check_step(s, i, joints, states) for i, s in raw_steps)
    alternatives = []
    for _, alt in r.at(data.get("alternatives") or [], "alternatives").seq(1000).items():
        alt.mapping()
        order_r = alt.child("order").seq(MAX_STATES)
        order = tuple(order_r.at(o).name() for o in order_r.value)
        grip = alt.get("bottleneck_grip_force_n")
        alternatives.append(Alternative(
            order, alt.child("bottleneck_metric").number(),
            int(alt.child("gait_steps").number(0, MAX_STATES)),
            alt.child("mean_metric").number(),
            None if grip is None else alt.child("bottleneck_grip_force_n").number(0)))
    summary = dict(r.at(data.get("summary") or {}, "summary").mapping().value)
    try:
        return Plan(dict(hand.value), obj, friction, dict(inputs.value), dict(parameters.value), summary, joints, states,
                    steps, tuple(alternatives), source=None if source is None else src)
    except PlannerError as err:  # the default mass needs the object (e.g. its mesh file)
        raise r.fail(str(err), "object") from None


REQUIRED_KEYS = ("schema_version", "hand", "object", "friction", "joints", "states", "steps")
STATE_KEYS = ("patches", "closure", "removable", "q")
STEP_KEYS = ("finger", "action", "from_state", "to_state", "joints", "path")


def _check_object(r: Reader) -> dict:
    r.mapping()
    o = dict(r.value)
    r.require("shape", "size", "position", "quat_xyzw", message="missing key")
    shape = r.child("shape").choice(SHAPES, "shape")
    size = r.child("size").seq(max(SIZE_LENGTHS[shape]), min(SIZE_LENGTHS[shape]))
    if len(size.value) not in SIZE_LENGTHS[shape]:  # a mesh: 1 or 3, never 2
        raise size.fail(f"a {shape} size is {SIZE_MEANING[shape]}, got {len(size.value)} entries")
    o["size"] = [v.number(1e-6, MAX_COORD_M) for _, v in size.items()]
    o["position"] = r.child("position").numbers(3, -MAX_COORD_M, MAX_COORD_M)
    quat = r.child("quat_xyzw").numbers(4, -1.0 - 1e-6, 1.0 + 1e-6)
    if abs(math.sqrt(sum(v * v for v in quat)) - 1.0) > 1e-6:
        raise r.fail("expected a unit quaternion [x, y, z, w]", "quat_xyzw")
    o["quat_xyzw"] = quat
    if o.get("mass_kg") is not None:
        o["mass_kg"] = r.child("mass_kg").number(1e-9, MAX_MASS_KG)
    if shape == "mesh":
        r.child("mesh").name()
    return o


def _check_state(s: Reader, i: int, joints: tuple[str, ...]) -> PlanState:
    key = s.key
    s.mapping()
    s.require(*STATE_KEYS, message="missing key")
    fingers_r = s.at(s.get("fingers") or {}, f"{key}.fingers").mapping()
    fingers = {fingers_r.at(f).name(): v.name() for f, v in fingers_r.items()}
    patches = {}
    patches_r = s.child("patches").mapping()
    for f, patch in patches_r.items():
        patches_r.at(f).name()
        patch.mapping()
        if patch.get("points") is None or patch.get("normals") is None:
            raise patch.fail("needs points and normals of equal length")
        pts = patch.child("points").rows(MAX_POINTS, 3, MAX_COORD_M)
        nrm = patch.child("normals").rows(MAX_POINTS, 3, 1.0 + 1e-6)
        if len(pts) != len(nrm) or not len(pts):
            raise patch.fail("needs points and normals of equal length")
        if np.any(np.abs(np.linalg.norm(nrm, axis=1) - 1.0) > 1e-6):
            raise patch.fail("expected unit normals", "normals")
        patches[f] = (pts, nrm)
    if fingers and not set(patches) <= set(fingers):
        raise s.fail(f"fingers {sorted(set(patches) - set(fingers))} are not in {key}.fingers", "patches")
    closure = s.child("closure").mapping()
    fc = closure.get("is_force_closure")
    if not isinstance(fc, bool):
        raise closure.fail(f"expected true or false, got {shown(fc)}", "is_force_closure")
    metric = closure.child("metric").number()
    removable_r = s.child("removable").seq(MAX_JOINTS)
    removable = tuple(removable_r.at(f).name() for f in removable_r.value)
    if not set(removable) <= set(patches) | set(fingers):
        raise removable_r.fail("names fingers the state does not have")
    q = s.child("q").mapping()
    missing = [j for j in joints if j not in q]
    if missing:
        raise q.fail(f"missing joints {missing[:5]}")
    qv = tuple(q.child(j).number(-MAX_JOINT_VALUE, MAX_JOINT_VALUE) for j in joints)
    grip = s.get("grip_force_n")
    if grip is not None and (isinstance(grip, bool) or not isinstance(grip, (int, float)) or not 0 <= grip < math.inf):
        raise s.fail(f"expected a force >= 0 in newtons or null, got {shown(grip)}", "grip_force_n")
    by_g = s.get("grip_force_by_gravity_n")
    if by_g is not None:
        by_g = {str(k): v.number(0) for k, v in s.child("grip_force_by_gravity_n").mapping().items()}
    hold = s.get("hold_factor_by_gravity")
    if hold is not None:
        hold = {str(k): v.number(0, 1e6) for k, v in s.child("hold_factor_by_gravity").mapping().items()}
    return PlanState(fingers, patches, fc, metric, removable, qv,
                     None if grip is None else float(grip), by_g, hold)


def _check_step(s: Reader, i: int, joints: tuple[str, ...], states: tuple[PlanState, ...]) -> PlanStep:
    s.mapping()
    s.require(*STEP_KEYS, message="missing key")
    finger = s.child("finger").name()
    action = s.child("action").choice(
        ACTIONS, "action", show=lambda a: repr(a[:20]) if isinstance(a, str) else shown(a))
    frm = s.child("from_state").integer(0, len(states) - 1, expected=f"a state index in 0..{len(states) - 1}")
    to = s.child("to_state").integer(0, len(states) - 1, expected=f"a state index in 0..{len(states) - 1}")
    if (frm, to) != (i, i + 1):
        raise s.fail(f"step {i} goes from state {frm} to {to}; steps must chain the states "
                     f"in order ({i} -> {i + 1})", "from_state")
    joints_r = s.child("joints").seq(MAX_JOINTS, 1)
    sj = tuple(joints_r.at(j).name() for j in joints_r.value)
    unknown = [j for j in sj if j not in joints]
    if unknown:
        raise joints_r.fail(f"joints {unknown[:5]} are not in the plan's joints")
    path = s.child("path").rows(MAX_WAYPOINTS, len(sj), MAX_JOINT_VALUE)
    if not len(path):
        raise s.fail("expected at least one waypoint", "path")
    a, b = states[frm], states[to]
    idx = [joints.index(j) for j in sj]
    qa, qb = np.asarray(a.q), np.asarray(b.q)
    if np.max(np.abs(path[0] - qa[idx])) > PATH_END_TOL or np.max(np.abs(path[-1] - qb[idx])) > PATH_END_TOL:
        raise s.fail(f"does not start at state {frm} and end at state {to}", "path")
    others = np.ones(len(joints), bool)
    others[idx] = False
    if np.any(np.abs(qa[others] - qb[others]) > PATH_END_TOL):
        raise s.fail(f"states {frm} and {to} differ in joints outside the step's joints")
    on_a, on_b = finger in a.patches, finger in b.patches
    expect = {"lift": (True, False), "land": (False, True), "move": (False, False)}[action]
    if (on_a, on_b) != expect:
        raise s.fail(f"{action} of {finger}, but the finger is "
                     f"{'on' if on_a else 'off'} the object in state {frm} and "
                     f"{'on' if on_b else 'off'} in state {to}", "action")
    if set(a.patches) - {finger} != set(b.patches) - {finger}:
        raise s.fail(f"fingers other than {finger} change contact between states {frm} and {to}")
    return PlanStep(finger, action, frm, to, sj, tuple(tuple(float(v) for v in wp) for wp in path))


# ``planner.plan`` is this module and, called, the one-call planner: the package root's
# module class (the root is the layer above every module, so no module imports the API)
sys.modules[__name__].__class__ = planner.CallablePlanModule
