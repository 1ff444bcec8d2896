"""Grasp files: the YAML schema and its validation.

A grasp file (``grasps/**/*.yaml``, schema_version 1)::

    schema_version: 1
    name: box_parallel_extension          # optional, defaults to the file stem
    description: free text                # optional
    hand: icub_right                      # a bundled hand's name or a path to a hand.yaml
                                          # (relative to this file)
    object:
      shape: box                          # box | cylinder | sphere | mesh
      size: [0.03, 0.06, 0.06]            # metres. box: full extents [x, y, z];
                                          # cylinder: [radius, length], axis = object z;
                                          # sphere: [radius]; mesh: [s] or [sx, sy, sz] (scale)
      position: [0.0, 0.0, 0.05]          # object centre in the palm frame, metres
      quat_xyzw: [0, 0, 0, 1]             # object orientation in the palm frame
      mesh: meshes/mug.obj                # only for shape mesh, relative to this file
      mass_kg: 0.05                       # optional
    friction: {mu: 0.9, gamma: 0.003, edges: 5}   # gamma in metres; edges optional (5)
    fingers:
      thumb: {contact: {point: [x, y, z]}}          # object frame, on the surface;
      index: {contact: {point: [..], link: index_2}} # link optional: default the fingertip pad
      middle: {posture: [0.0, 0.6, 0.4, 0.3]}        # the finger's joints in hand.yaml order,
                                                     # then closed onto the object
      little: free                                   # open posture, not touching
    palm: hold                            # optional: hold | free | auto (default auto)

Fingers of the hand that the file does not list are free (open posture).

``palm`` says what the palm (the links of the hand's base) does: ``auto`` (default) counts
it as a contact when it touches the object (within the touch tolerance, 1 mm), like any
finger link; ``hold`` requires it to touch (the object rests on or is pressed against it:
`check` fails when it does not); ``free`` requires it not to touch (a fingertip grasp: `check`
fails when it does). A touching palm holds like a rigid link: it pushes only, inside its
friction cone, with no joint limit, and is never lifted.

A validated file is a `GraspSpec`; `planner.realization` turns it into a hand configuration
(`realize` -> `RealizedGrasp`).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from planner.errors import PlannerError, SpecError, UnknownNameError
from planner.fileio import Reader, as_path, check_grasp_file, describe, sha256_file
from planner.hand import Hand
from planner.model import EDGES_MAX, GAMMA_MAX_M, MU_MAX, Friction
from planner.objects import GraspObject, read_object
from planner.plan_data import PLAN_KIND

SCHEMA_VERSION = 1
#: A contact point may lie this far from the object surface (it is projected onto it).
SURFACE_TOL_M = 0.002
#: Joint values in a posture may exceed the limits by this much (rounding in files).
LIMIT_TOL_RAD = 1e-6

_TOP_KEYS = ("schema_version", "name", "description", "hand", "object", "friction", "fingers", "palm")
#: Values of a grasp file's ``palm:`` key (module docstring).
PALM_MODES = ("auto", "hold", "free")
_FRICTION_KEYS = ("mu", "gamma", "edges")


# --------------------------------------------------------------------------- data


@dataclass(frozen=True)
class FingerSpec:
    """What one finger does in a grasp file.

    Attributes:
        name: finger name (as in the hand spec).
        kind: ``contact``, ``posture`` or ``free``.
        point_obj: contact point in the object frame (kind contact), metres.
        link: contact link (kind contact); None means the finger's fingertip pad.
        posture: joint values in the finger's joint order (kind posture), radians.
    """

    name: str
    kind: str
    point_obj: tuple[float, float, float] | None = None
    link: str | None = None
    posture: tuple[float, ...] | None = None


@dataclass(frozen=True)
class GraspSpec:
    """A validated grasp file.

    Attributes:
        path: the file it came from (absolute), or "" when built in code.
        name: grasp name.
        hand: the hand reference as written in the file.
        hand_ref: a bundled hand's name (`planner.resources`) or an absolute path to a hand.yaml.
        object: the object (`planner.objects.GraspObject`, its geometry built).
        friction: `planner.model.Friction` (mu, gamma in metres, edges).
        fingers: one `FingerSpec` per finger of the hand, in the hand's finger order
            (fingers the file does not list are ``free``).
        palm: ``auto``, ``hold`` or ``free`` (`PALM_MODES`, module docstring).
        description: free text from the file.
    """

    path: str
    name: str
    hand: str
    hand_ref: str
    object: GraspObject
    friction: Any
    fingers: tuple[FingerSpec, ...]
    description: str = ""
    schema_version: int = SCHEMA_VERSION
    palm: str = "auto"

    def finger(self, name: str) -> FingerSpec:
        """The spec of finger `name` (UnknownNameError if the hand has none)."""
        for f in self.fingers:
            if f.name == name:
                return f
        raise UnknownNameError("finger", name, [f.name for f in self.fingers])

    @property
    def contact_fingers(self) -> tuple[str, ...]:
        """Fingers meant to touch the object (kind contact or posture)."""
        return tuple(f.name for f in self.fingers if f.kind != "free")


# --------------------------------------------------------------------------- loading


def resolve_hand_ref(hand: str, base_dir: Path) -> str:
    """A hand name stays a name (`Hand.load` finds the bundled hands from any directory);
    anything else is a path relative to `base_dir`.

    A reference is a path when it contains a path separator or ends in .yaml/.yml.
    """
    if "/" in hand or "\\" in hand or hand.endswith((".yaml", ".yml")):
        p = Path(hand)
        if not p.is_absolute():
            p = (base_dir / p).resolve()
        return str(p)
    return hand


@lru_cache(maxsize=8)
def _cached_hand(ref: str):
    return Hand.load(ref)


def load_hand(ref: str):
    """`Hand.load(ref)`, cached: hands are read-only once loaded (no pinocchio.Data, no
    per-query state: every kinematic query runs on a state of its own, `planner.kinematics`)."""
    return _cached_hand(ref)


def load_grasp(path) -> GraspSpec:
    """Read and validate a grasp file.

    Validation checks the schema, the hand's finger and link names, the lengths of all
    vectors, the joint limits of postures, and that contact points lie on the object
    surface (within `SURFACE_TOL_M`).

    Args:
        path: the YAML file.

    Returns:
        The validated `GraspSpec`.

    Raises:
        SpecError: naming the file, the key path and what was expected.
    """
    path = as_path(path, "grasp file")
    path = path.resolve() if path.exists() else path
    data = check_grasp_file(path)  # size, nesting, aliases, duplicate keys, integer digits, hand: path
    Reader(path, data).mapping("a YAML mapping at the top level", string_keys=True)
    return parse_grasp(data, path)


def parse_grasp(data: Mapping, path) -> GraspSpec:
    """Validate already-parsed grasp data; `path` names the source in errors and anchors
    relative paths (hand, mesh). See `load_grasp`."""
    path = Path(path)
    r = Reader(path, data).mapping("a YAML mapping at the top level", string_keys=True)
    if data.get("kind") == PLAN_KIND:  # say what it is, not that its first key is unknown
        raise r.fail("is a plan file (kind: regrasp-plan), not a grasp file: give the grasps it was planned "
                     "between (its inputs), or regrasp verify / replay / view the plan", "kind")
    r.keys(_TOP_KEYS, required=("schema_version", "hand", "object", "friction", "fingers"))

    version = data["schema_version"]
    if isinstance(version, bool) or version != SCHEMA_VERSION:
        raise r.fail(f"unsupported schema version {version!r}; this planner reads {SCHEMA_VERSION}", "schema_version")

    name = r.child("name").string() if "name" in r else path.stem
    description = data.get("description", "")
    if description is None:
        description = ""
    if not isinstance(description, str):
        raise r.fail(f"expected a string, got {describe(description)}", "description")

    # -- hand
    hand_text = r.child("hand").string()
    hand_ref = resolve_hand_ref(hand_text, path.parent)
    try:
        hand = load_hand(hand_ref)
    except (PlannerError, OSError, ValueError) as err:
        raise r.fail(f"cannot load hand {hand_text!r}: {err}", "hand") from err

    # -- object
    obj = parse_object(r, data["object"], path.parent)

    friction = parse_friction(r.child("friction"))

    # -- fingers
    fingers_data = r.child("fingers").mapping(string_keys=True)
    valid = list(hand.fingers)
    for fname in fingers_data.value:
        if fname not in hand.fingers:
            raise fingers_data.fail(f"unknown finger {fname!r}; fingers of {hand.name} are {', '.join(valid)}", fname)
    fingers = []
    for fname, finger in hand.fingers.items():
        if fname not in fingers_data:
            fingers.append(FingerSpec(fname, "free"))
            continue
        fingers.append(_parse_finger(fingers_data.child(fname), hand, finger, obj))
    if not any(f.kind != "free" for f in fingers):
        raise r.fail("no finger touches the object; give at least one contact or posture", "fingers")
    palm = r.child("palm").choice(PALM_MODES, "palm mode", valid="valid:") if r.get("palm") is not None else "auto"

    return GraspSpec(
        path=str(path),
        name=name,
        hand=hand_text,
        hand_ref=hand_ref,
        object=obj,
        friction=friction,
        fingers=tuple(fingers),
        description=description,
        palm=palm,
    )


def parse_object(r: Reader, value, base_dir: Path) -> GraspObject:
    """The object of the ``object:`` block ``value`` of the file `r` reads
    (`planner.fileio.Reader`), key path ``object``, checked by the one object-block validator
    (`planner.objects.check_object_block`) and its geometry built; a relative mesh path is
    relative to ``base_dir``."""
    return read_object(r.at(value, "object"), base_dir)


def parse_friction(r: Reader) -> Friction:
    """The ``friction:`` block `r` reads (grasp files, synth object files): ``mu`` in
    (0, `MU_MAX`], ``gamma`` in [0, `GAMMA_MAX_M`] m, ``edges`` an integer in [3, `EDGES_MAX`]
    (default 5); errors name the file and the key path (``friction.mu``) and the range."""
    fr = r.mapping(string_keys=True)
    fr.keys(_FRICTION_KEYS, required=("mu", "gamma"))
    mu = fr.child("mu").quantity(0.0, MU_MAX, "(friction coefficient)", open_low=True)
    gamma = fr.child("gamma").quantity(0.0, GAMMA_MAX_M, "m (torsional friction)")
    edges = fr.child("edges", 5).integer(3, EDGES_MAX, expected=f"an integer in [3, {EDGES_MAX}] (friction cone sides)")
    return Friction(mu=mu, gamma=gamma, edges=edges)


def _parse_finger(r: Reader, hand, finger, obj) -> FingerSpec:
    value = r.value
    if value == "free" or value is None:
        return FingerSpec(finger.name, "free")
    if isinstance(value, str):
        raise r.fail(f"expected 'free', {{contact: ...}} or {{posture: [...]}}, got {value!r}")
    v = r.mapping("'free', {contact: {point: [x, y, z]}} or {posture: [joint values]}", string_keys=True)
    if len(value) != 1 or next(iter(value)) not in ("contact", "posture"):
        extra = [k for k in value if k not in ("contact", "posture")]
        if extra:
            raise r.fail(f"unknown key {extra[0]!r}; a finger is 'free', contact or posture", extra[0])
        raise r.fail("give either contact or posture, not both")
    kind = next(iter(value))
    if kind == "posture":
        joints = finger.joints
        posture = v.child("posture")
        q = posture.vector((len(joints),), f"values of {', '.join(joints)} in radians")
        lo = np.asarray(hand.lower)[list(finger.q_index)]
        hi = np.asarray(hand.upper)[list(finger.q_index)]
        for i, (x, a, b) in enumerate(zip(q, lo, hi)):
            if x < a - LIMIT_TOL_RAD or x > b + LIMIT_TOL_RAD:
                raise posture.fail(f"joint {joints[i]} = {x:.4g} rad is outside its limits [{a:.4g}, {b:.4g}]", i)
        for fl, d, m, o in finger.coupled:  # a follower is set by its driver (planner.hand.Coupling)
            if abs(q[fl] - (m * q[d] + o)) > LIMIT_TOL_RAD:
                raise posture.fail(f"joint {joints[fl]} = {q[fl]:.4g} rad breaks its coupling {joints[fl]} = {m:g} "
                                   f"{joints[d]} + {o:g}: give {m * q[d] + o:.6g}", fl)
        return FingerSpec(finger.name, "posture", posture=q)
    c = v.child("contact").mapping(string_keys=True)
    c.keys(("point", "link"), required=("point",))
    point = c.child("point").vector((3,), "[x, y, z] in metres, object frame")
    link = c.get("link")
    if link is not None:
        link = c.child("link").string()
        if link not in finger.contact_links:
            raise c.fail(
                f"unknown contact link {link!r} of finger {finger.name}; valid links are {', '.join(finger.contact_links)}",
                "link",
            )
    _, _, dist = obj.closest_surface(np.asarray(point, dtype=float))
    if abs(dist) > SURFACE_TOL_M:
        side = "outside" if dist > 0 else "inside"
        raise c.fail(
            f"point {list(point)} is {abs(dist) * 1000:.1f} mm {side} the object surface; "
            f"expected a point on the surface (within {SURFACE_TOL_M * 1000:.1f} mm, object frame)",
            "point",
        )
    return FingerSpec(finger.name, "contact", point_obj=point, link=link)


def grasp_files(spec, hand=None, path=None) -> list[str]:
    """Every file reading this grasp reads, which no output may be: the grasp file (``path``,
    when it was given as one), its hand's files (hand.yaml, URDF, meshes: ``Hand.files``) and
    the object's mesh. ``hand``: the loaded hand (default `load_hand` of the spec's)."""
    hand = load_hand(spec.hand_ref) if hand is None else hand
    return [str(p) for p in (path, *getattr(hand, "files", ()), spec.object.mesh_path) if p is not None]


def input_record(path) -> dict:
    """How a plan records an input grasp file: its path and sha256 (read in chunks,
    `planner.fileio.sha256_file`). SpecError when it is not a readable regular file."""
    digest = sha256_file(path)
    if digest is None:
        raise SpecError(str(path), "", "cannot be read as a regular file to record its sha256")
    return {"path": str(path), "sha256": digest}
