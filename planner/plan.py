"""Reading a plan file: `read_plan`, the one plan parser, and its checks.

The types and the export are `planner.plan_data`. `read_plan` refuses a file whose
integrity record is missing (e.g. truncated), whose counts or digest do not match, or
whose structure is inconsistent (`plan_from_data`: steps chained in order, each step's
finger lifted, moved or landed as its action says, the other joints unchanged, paths
starting and ending at their states, finite numbers within the documented ranges), and
re-checks every state's force closure from its patches. Version 1 files (no integrity
record) are still read, with a `PlannerWarning`.

``planner.plan`` is this module and, called, the one-call planner (`planner.api.plan`).
"""

from __future__ import annotations

import math
import os
import sys
import warnings
from pathlib import Path
from typing import Any, Mapping

import numpy as np

import planner
from planner.closure import CONTACT_MODELS, grasp_closure
from planner.errors import IntegrityError, PlannerError, PlannerWarning, SpecError, UnknownNameError
from planner.fileio import (MAX_GRASP_BYTES, MAX_PLAN_BYTES, Reader, as_path, load_json, load_yaml, read_limited, repr_short,
                            sha256_file, shown)
from planner.model import PALM, Friction, Patch
from planner.objects import MeshFileError, check_object_block
from planner.plan_data import (ACTIONS, OBJECT, PLAN_KIND, SCHEMA_VERSION, Alternative, Plan, PlanState, PlanStep,
                               canonical_sha256, plan_file, plan_format)
from planner.resources import bundled_grasp

#: Versions `read_plan` reads (1: no integrity record, read with a warning).
READABLE_VERSIONS = (1, 2, 3, 4)

#: Ranges a plan file must respect (README "Hardening / plan integrity").
MAX_STATES = 10_000          # states (and steps) per plan
MAX_WAYPOINTS = 10_000       # waypoints per step path
MAX_POINTS = 10_000          # points per contact patch
MAX_JOINTS = 256             # joints per hand
MAX_JOINT_VALUE = 100.0      # |joint value|, rad or m (the hand's limits are checked by the replay)
MAX_COORD_M = 10.0           # |contact point|, m (the object's ranges: planner.objects)
#: A path's ends must equal its states' joint values within this (rad or m).
PATH_END_TOL = 1e-6
#: A reposing step's object poses must equal its states' poses within this (m, and quaternion
#: components).
POSE_END_TOL = 1e-6
#: Recorded closure metrics are re-computed within this (relative, absolute).
METRIC_RTOL, METRIC_ATOL = 1e-6, 1e-9


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
    path = as_path(path, "plan", "a plan file path")
    fmt = plan_format(path)
    text = read_limited(path, MAX_PLAN_BYTES, "plan")
    data = load_json(text, path) if fmt == "json" else _json_like(load_yaml(text, path, "plan"), str(path))
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


def _json_like(data, src: str):
    """A YAML plan holds what its JSON form can (its digest is that JSON's): strings,
    numbers, true/false, null, lists and mappings keyed by strings. A date, binary, set or a
    non-string key (``7:``, ``null:``) in a part no other check reads (summary, parameters)
    reached the digest as a TypeError."""
    stack = [(data, "")]
    while stack:
        value, key = stack.pop()
        if isinstance(value, dict):
            for k, v in value.items():
                if not isinstance(k, str):
                    got = "null" if k is None else f"{type(k).__name__} {repr_short(k, 40)}"
                    raise SpecError(src, key, f"keys must be strings (the plan's JSON form), got {got}")
                stack.append((v, f"{key}.{k}" if key else k))
        elif isinstance(value, list):
            stack.extend((v, f"{key}[{i}]") for i, v in enumerate(value))
        elif not (value is None or isinstance(value, (bool, int, float, str))):
            raise SpecError(src, key, f"expected a string, number, true/false or null (the plan's JSON form), "
                                      f"got {type(value).__name__}")
    return data


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


def plan_files(plan: Plan, hand=None) -> list[str]:
    """Every file a command reading this plan reads, which no output may be: the plan itself,
    its recorded input grasps, its hand's files (hand.yaml, URDF, meshes: ``hand.files``,
    ``hand`` the plan's `planner.hand.Hand`) and the object's mesh."""
    out = [plan.source]
    for rec in plan.inputs.values():
        found = recorded_input(rec, plan.source)
        if found is not None:
            out.append(found[0])
    out += list(getattr(hand, "files", ()))
    out.append(getattr(plan.object, "mesh_path", None))
    return [str(p) for p in out if p is not None]


def _check_inputs(plan: Plan, src: str, strict: bool) -> None:
    """Recorded inputs gone or changed: an error with ``strict``, else one warning line for all
    of them (the plan's own states are used)."""
    problems = []
    for name, rec in plan.inputs.items():
        found = recorded_input(rec, src)
        problem = found[2] if found is not None else None
        if problem and strict:
            raise SpecError(src, f"inputs.{name}", problem)
        if problem:
            problems.append(f"inputs.{name}: {problem}")
    if problems:
        warnings.warn(f"{src}: {'; '.join(problems)}; the plan's own states are used (--strict refuses it)",
                      PlannerWarning, stacklevel=3)


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
    if "fingers" in data and "states" not in data and "kind" not in data:  # say what it is
        raise r.fail("is a grasp file (it has fingers:), not a plan: regrasp plan INITIAL FINAL -o PLAN writes a "
                     "plan (regrasp check or view takes a grasp file)", "states")
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
    if hand.get("files") is not None:  # schema 3 plans since 2026-12-05: path -> sha256 of the hand's files
        files = hand.child("files").mapping()
        for name in files.value:
            files.child(name).name()
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

    _check_parameters(parameters)
    joints = tuple(j.name() for _, j in r.child("joints").seq(MAX_JOINTS, 1).items())
    if len(set(joints)) != len(joints):
        raise r.fail("joint names repeat", "joints")
    states = tuple(_check_state(s, i, joints) for i, s in r.child("states").seq(MAX_STATES, 1).items())
    raw_steps = r.child("steps").seq(MAX_STATES).items()
    if len(raw_steps) != len(states) - 1:
        raise r.fail(f"{len(raw_steps)} steps for {len(states)} states: a plan has one step less than "
                     f"states (truncated or edited)", "steps")
    base_pose = (*obj["position"], *obj["quat_xyzw"]) if obj.get("position") is not None else None
    if states[0].object_pose is not None and (base_pose is None or not _same_pose(states[0].object_pose, base_pose)):
        raise r.fail("the first state's object_pose differs from the object block's pose (a plan starts where its "
                     "object is; only repose steps move it)", "states[0].object_pose")
    if version < 4 and (states[0].object_pose is not None or any(st.object_pose is not None for st in states)):
        raise r.fail(f"object_pose is a schema 4 key; this plan says schema {version}", "schema_version")
    steps = tuple(_check_step(s, i, joints, states, base_pose) for i, s in raw_steps)
    if version < 4 and any(st.action == "repose" for st in steps):
        raise r.fail(f"repose steps are schema 4; this plan says schema {version}", "schema_version")
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
    except MeshFileError as err:  # the object's mesh file (relative to the plan): missing, too large, malformed
        raise r.fail(str(err), "object.mesh") from None
    except PlannerError as err:  # the default mass needs the object
        raise r.fail(str(err), "object") from None


def _check_parameters(parameters: Reader) -> None:
    """The parameters the planner writes as names or flags: one of the planner's own choices
    (a forged or mistyped one would change what `verify` checks a plan against: the contact
    model its closures use, the gravity set its hold factors are recomputed for). Absent or
    null: the planner's default (plans older than a parameter)."""
    from planner.gait_search import RANKS
    from planner.gravity import GRAVITY_SET_SIZES
    from planner.options import PLAN_OPTION_LIMITS, STRATEGIES, SWITCHES

    def show(v) -> str:
        return repr_short(v, 40) if isinstance(v, str) else shown(v)

    parameters.child("contact_model", "patch").choice(CONTACT_MODELS, "contact model", valid="valid:", show=show)
    for key, choices, what in (("strategy", STRATEGIES, "strategy"), ("rank", RANKS, "rank")):
        if parameters.get(key) is not None:
            parameters.child(key).choice(choices, what, valid="valid:", show=show)
    size = parameters.get("gravity_set")  # (a number: true would pass for 1)
    if size is not None and (isinstance(size, bool) or size not in GRAVITY_SET_SIZES):
        raise parameters.fail(f"unknown gravity set {show(size)}; valid: {', '.join(map(str, GRAVITY_SET_SIZES))}",
                              "gravity_set")
    for key in SWITCHES:
        value = parameters.get(key)
        if value is not None and not isinstance(value, bool):
            raise parameters.fail(f"expected true or false, got {show(value)}", key)
    if parameters.get("gravity") is not None:  # (--gravity: 3 numbers, m/s^2 in the palm frame)
        low, high, _ = PLAN_OPTION_LIMITS["gravity"]
        parameters.child("gravity").vector((3,), "gravity, m/s^2 in the palm frame", low=low, high=high)


REQUIRED_KEYS = ("schema_version", "hand", "object", "friction", "joints", "states", "steps")
STATE_KEYS = ("patches", "closure", "removable", "q")
STEP_KEYS = ("finger", "action", "from_state", "to_state", "joints", "path")


def _check_object(r: Reader) -> dict:
    """The plan's object block by the one object-block validator (`check_object_block`: the
    grasp files' ranges and quaternion rule; a recorded quaternion is kept bit for bit)."""
    return check_object_block(r.mapping())


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
        links = None
        if patch.get("links") is not None:
            links_r = patch.child("links").seq(MAX_POINTS)
            links = tuple(links_r.at(link).name() for link in links_r.value)
            if len(links) != len(pts):
                raise links_r.fail(f"expected one link per point ({len(pts)}), got {len(links)}")
        patches[f] = Patch(pts, nrm, links)
    owners = set(patches) - {PALM}
    if fingers and not owners <= set(fingers):
        raise s.fail(f"fingers {sorted(owners - set(fingers))} are not in {key}.fingers", "patches")
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
    pose = None
    if s.get("object_pose") is not None:  # schema 4: a reposing step moved the object here
        pose = _pose_of(s.child("object_pose").mapping())
    return PlanState(fingers, patches, fc, metric, removable, qv,
                     None if grip is None else float(grip), by_g, hold, pose)


def _pose_of(r: Reader) -> tuple[float, ...]:
    """{position, quat_xyzw} as (x, y, z, qx, qy, qz, qw), the quaternion a unit one."""
    r.require("position", "quat_xyzw", message="missing key")
    p = r.child("position").numbers(3, -MAX_COORD_M, MAX_COORD_M)
    q = r.child("quat_xyzw").numbers(4, -1.0 - 1e-6, 1.0 + 1e-6)
    if abs(float(np.linalg.norm(q)) - 1.0) > 1e-6:
        raise r.fail(f"expected a unit quaternion (norm {float(np.linalg.norm(q)):.6g})", "quat_xyzw")
    return tuple(float(v) for v in (*p, *q))


def _same_pose(a, b) -> bool:
    """Two optional state poses equal (None: the plan's object pose); q and -q are one rotation."""
    if a is None or b is None:
        return a is None and b is None
    a, b = np.asarray(a, float), np.asarray(b, float)
    return bool(np.max(np.abs(a[:3] - b[:3])) <= POSE_END_TOL
                and min(np.max(np.abs(a[3:] - b[3:])), np.max(np.abs(a[3:] + b[3:]))) <= POSE_END_TOL)


def _check_step(s: Reader, i: int, joints: tuple[str, ...], states: tuple[PlanState, ...], base_pose=None) -> PlanStep:
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
    if action == "repose":
        return _check_repose(s, i, joints, states, sj, path, base_pose)
    if s.get("object_path") is not None:
        raise s.fail(f"only a repose step moves the object; this is a {action}", "object_path")
    if not _same_pose(a.object_pose, b.object_pose):
        raise s.fail(f"the object's pose differs between states {frm} and {to}, but only a repose step moves it")
    on_a, on_b = finger in a.patches, finger in b.patches
    expect = {"lift": (True, False), "land": (False, True), "move": (False, False)}[action]
    if (on_a, on_b) != expect:
        raise s.fail(f"{action} of {finger}, but the finger is "
                     f"{'on' if on_a else 'off'} the object in state {frm} and "
                     f"{'on' if on_b else 'off'} in state {to}", "action")
    if set(a.patches) - {finger} != set(b.patches) - {finger}:
        raise s.fail(f"fingers other than {finger} (or the palm) change contact between states {frm} and {to}")
    return PlanStep(finger, action, frm, to, sj, tuple(tuple(float(v) for v in wp) for wp in path))


def _check_repose(s: Reader, i: int, joints, states, sj, path, base_pose=None) -> PlanStep:
    """A reposing step: ``finger: object``, one object pose per waypoint from the from-state's
    pose to the to-state's; a finger touching in only one of its states (the palm, or a finger
    the object is carried away from or onto) keeps its joints (not the step's joints)."""
    if s.get("finger") != OBJECT:
        raise s.fail(f"a repose step moves the object: expected finger {OBJECT!r}, got {repr_short(s.get('finger'))}",
                     "finger")
    if s.get("object_path") is None:
        raise s.fail("a repose step needs object_path (one pose per waypoint)", "object_path")
    poses = s.child("object_path").rows(MAX_WAYPOINTS, 7, MAX_COORD_M)
    if len(poses) != len(path):
        raise s.fail(f"{len(poses)} object poses for {len(path)} waypoints: expected one per waypoint", "object_path")
    if np.any(np.abs(np.linalg.norm(poses[:, 3:], axis=1) - 1.0) > 1e-6):
        raise s.fail("expected unit quaternions [x, y, z, qx, qy, qz, qw]", "object_path")
    frm, to = i, i + 1
    a, b = states[frm], states[to]
    for end, st in ((poses[0], a), (poses[-1], b)):
        want = st.object_pose if st.object_pose is not None else base_pose  # none: the object block's
        if want is None or not _same_pose(tuple(end), want):
            raise s.fail(f"does not start at state {frm}'s object pose and end at state {to}'s", "object_path")
    # the touching fingers may differ: a finger released (the object carried away from it) or
    # carried onto keeps still, its joints outside the step's (the audit checks it with the hand)
    return PlanStep(OBJECT, "repose", frm, to, sj, tuple(tuple(float(v) for v in wp) for wp in path),
                    tuple(tuple(float(v) for v in p) for p in poses))


# ``planner.plan`` is this module and, called, the one-call planner: the package root's
# module class (the root is the layer above every module, so no module imports the API)
sys.modules[__name__].__class__ = planner.CallablePlanModule
