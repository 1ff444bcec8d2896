"""The URDF check: every hand URDF is read and checked here, by our own code, before
pinocchio, coal or pybullet see it (`check_urdf`; `planner.hand.Hand` and ``regrasp hand
init`` call it first). Those libraries hang on a FIFO, run out of memory on ``/dev/zero``,
crash (a segmentation fault in pybullet's loader) on a link with two parents or a
10 MB name, and take a NaN radius, a zero joint axis or a negative mass without a word.

The file:

* a regular file of at most `MAX_URDF_BYTES`, UTF-8 XML (`planner.fileio.read_limited`);
  no DOCTYPE (so no entity can be declared or expanded), at most `MAX_XML_DEPTH` levels of
  elements, attribute values of at most `MAX_ATTRIBUTE_CHARS` characters;
* a ``<robot>`` named like its links and joints: names non-empty, at most `MAX_NAME_CHARS`
  characters, link names unique, joint names unique; at most `MAX_LINKS` links and
  `MAX_SHAPES` collision and visual shapes;
* numbers are decimal numbers (``1``, ``-0.5``, ``2e-3``); ``nan``, ``inf`` and text are
  refused where a number is read: origins, axes, limits, masses, inertias, shape sizes.

The robot:

* shapes: a sphere's radius, a cylinder's (capsule's) radius and length, a box's three
  sizes are finite, > 0 and at most `MAX_LENGTH_M` (origins' offsets too); a mesh's scale
  is three finite non-zero numbers (a negative one mirrors the mesh: published models do);
* masses finite and >= 0, inertias finite with moments ixx, iyy, izz >= 0;
* joints: a known type, parent and child naming existing links and not the same one,
  a finite non-zero axis (``|axis| >= MIN_AXIS_NORM``) for revolute, continuous,
  prismatic and planar joints, a ``<limit>`` with finite effort and velocity >= 0 and
  finite ``lower <= upper`` for revolute and prismatic ones;
* the links form one tree: exactly one root (a link that is no joint's child), no link
  with two parents, no cycle;
* meshes (``package://``, ``file://``, absolute, or relative to the URDF's folder, then to
  the package dirs) are regular files of at most `MAX_MESH_BYTES` each and
  `MAX_MESH_BYTES_TOTAL` together, in a format pybullet reads (`MESH_SUFFIXES`: STL, OBJ,
  COLLADA) whose counts the file can hold; a collision mesh has at most
  `MAX_MESH_TRIANGLES` triangles (counted from the file; `planner.hand` counts the loaded
  mesh again). A mesh past the limit is refused, not decimated: the message says to
  simplify it.

Every problem is one `SpecError` naming the URDF, the line and the element
(``hand.urdf: line 52: link 'index_tip': collision sphere radius must be a finite number
> 0, got nan``); it never quotes text of the file other than a name.
"""

from __future__ import annotations

import contextlib
import math
import os
import re
import stat
import threading
from dataclasses import dataclass
from pathlib import Path

import pyexpat

from planner.errors import SpecError
from planner.fileio import read_limited

#: Largest URDF read, bytes (published robots' URDFs are at most ~0.2 MB).
MAX_URDF_BYTES = 5_000_000
#: Deepest element nesting accepted (a URDF needs 5: robot/link/collision/geometry/mesh;
#: ``<gazebo>`` plugin blocks a few more).
MAX_XML_DEPTH = 32
#: Longest robot, link or joint name, characters.
MAX_NAME_CHARS = 256
#: Longest attribute value of any element, characters (mesh paths included).
MAX_ATTRIBUTE_CHARS = 4096
#: Most links of one URDF (a hand has ~25, a humanoid ~100); the collision model pairs links.
MAX_LINKS = 1000
#: Most collision and visual shapes together.
MAX_SHAPES = 4000
#: Largest mesh file, bytes (published robots' largest, a COLLADA trunk, is 29 MB).
MAX_MESH_BYTES = 64_000_000
#: Most mesh bytes one URDF may name, each file counted once.
MAX_MESH_BYTES_TOTAL = 256_000_000
#: Most triangles of a collision mesh: the planner uses its convex hull, for which a few
#: thousand triangles are plenty; coal gives up on a hull vertex with more than 255
#: neighbours, which a finely meshed sphere's pole has.
MAX_MESH_TRIANGLES = 200_000
#: Largest shape size and origin offset, m (published robots: at most ~2 m); a 1e30 m
#: palm box loads in every library and makes every posture a collision.
MAX_LENGTH_M = 100.0
#: Shortest joint axis accepted (it is normalised).
MIN_AXIS_NORM = 1e-6
#: A moment of inertia below minus this is negative, not a rounded zero, kg m^2 (1e-12: a 1 g
#: sphere of 0.05 mm radius).
INERTIA_TOL = 1e-12
JOINT_TYPES = ("revolute", "continuous", "prismatic", "fixed", "floating", "planar")
#: Joint types whose axis is used (a planar joint's is the plane's normal; fixed and
#: floating joints ignore theirs).
AXIS_JOINTS = ("revolute", "continuous", "prismatic", "planar")
LIMITED_JOINTS = ("revolute", "prismatic")
#: Primitive shapes -> their size attributes and how many numbers each holds.
SHAPE_SIZES = {"sphere": (("radius", 1),), "cylinder": (("radius", 1), ("length", 1)),
               "capsule": (("radius", 1), ("length", 1)), "box": (("size", 3),)}
#: Mesh formats: those pybullet (the replay) reads; it skips another one's shape, so the
#: replay would simulate a link without its collision shape.
MESH_SUFFIXES = (".stl", ".obj", ".dae")

_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?\Z")


@dataclass(frozen=True)
class Mimic:
    """A URDF ``<mimic>``: joint ``joint`` follows ``follows``,
    ``q_joint = multiplier * q_follows + offset`` (rad, or m for a prismatic joint), declared
    on line ``line`` of the URDF."""

    joint: str
    follows: str
    multiplier: float
    offset: float
    line: int
    joint_type: str = "revolute"
    follows_type: str | None = "revolute"   # None: no joint of that name
    follows_follows: str = ""               # the joint the followed joint mimics, if any

    def problem(self) -> str:
        """Why this coupling cannot be used by a hand ("" when it can): the joint followed is
        itself, missing, not moving or a follower itself (no chains); a multiplier of 0."""
        moving = ("revolute", "continuous", "prismatic")
        if self.follows == self.joint:
            return "a joint cannot follow itself"
        if self.follows_type is None:
            return f"follows {name_shown(self.follows)}, which is not a joint of the URDF"
        if self.follows_follows:
            return (f"follows {name_shown(self.follows)}, which follows {name_shown(self.follows_follows)} itself: "
                    "make both follow the same driver")
        for joint, kind, label in ((self.joint, self.joint_type, "the follower"),
                                   (self.follows, self.follows_type, "the joint it follows")):
            if kind not in moving:
                return (f"{label} {name_shown(joint)} is a {kind} joint; a coupling joins revolute, continuous or "
                        "prismatic joints")
        if self.multiplier == 0:
            return "multiplier 0 holds the joint at its offset: make it a fixed joint"
        return ""


@dataclass(frozen=True)
class UrdfSummary:
    """What `check_urdf` read: the robot's name, its root link, its links and joints (file
    order), the mesh files it names (resolved) and its ``<mimic>`` couplings (`Mimic`, file
    order; each checked: the joint it follows exists, moves, is no follower itself)."""

    path: str
    robot: str
    root: str
    links: tuple[str, ...]
    joints: tuple[str, ...]
    meshes: tuple[str, ...]
    mimics: tuple[Mimic, ...] = ()


class _Element:
    """An XML element with the line it starts on (xml.etree keeps no line numbers)."""

    __slots__ = ("tag", "attrib", "children", "line")

    def __init__(self, tag: str, attrib: dict, line: int):
        self.tag, self.attrib, self.children, self.line = tag, attrib, [], line

    def find(self, tag: str) -> "_Element | None":
        return next((c for c in self.children if c.tag == tag), None)

    def findall(self, tag: str) -> list["_Element"]:
        return [c for c in self.children if c.tag == tag]


def _shown(values) -> str:
    """Numbers for a message: ``0.079 -0.067 0.03``, ``nan``."""
    return " ".join(f"{v:g}" for v in values)


def name_shown(name: str, limit: int = 60, *, path: bool = False) -> str:
    """A name from a file for a message: quoted, at most ``limit`` characters (a long
    ``path`` keeps its end, the file's name)."""
    if len(name) <= limit:
        return repr(name)
    return repr("..." + name[3 - limit:] if path else name[: limit - 3] + "...")


def _parse(text: str, path: str) -> _Element:
    """The element tree of ``text`` (expat, the parser under xml.etree), refusing a DOCTYPE
    (hence any entity declaration), deep nesting and long attribute values."""

    def refuse(line: int, message: str):
        raise SpecError(path, f"line {line}", message)

    parser = pyexpat.ParserCreate()
    parser.SetParamEntityParsing(pyexpat.XML_PARAM_ENTITY_PARSING_NEVER)
    stack: list[_Element] = []
    top: list[_Element] = []

    def start(tag, attrib):
        line = parser.CurrentLineNumber
        if len(stack) >= MAX_XML_DEPTH:
            refuse(line, f"elements nested deeper than {MAX_XML_DEPTH} levels")
        for key, value in attrib.items():
            if len(value) > MAX_ATTRIBUTE_CHARS:
                refuse(line, f"<{tag[:40]}> attribute {name_shown(key, 40)} is {len(value)} characters long; "
                             f"at most {MAX_ATTRIBUTE_CHARS}")
        el = _Element(tag, attrib, line)
        (stack[-1].children if stack else top).append(el)
        stack.append(el)

    def doctype(*_):
        refuse(parser.CurrentLineNumber, "a DOCTYPE (entity declarations) is not accepted in a URDF")

    parser.StartElementHandler = start
    parser.EndElementHandler = lambda tag: stack.pop()
    parser.StartDoctypeDeclHandler = doctype
    parser.EntityDeclHandler = lambda *_: doctype()
    try:
        parser.Parse(text, True)
    except pyexpat.ExpatError as err:
        raise SpecError(path, f"line {err.lineno}", f"not well-formed XML: {pyexpat.ErrorString(err.code)}") from None
    except RecursionError:  # (expat does not recurse; kept for a future parser)
        raise SpecError(path, "", "elements nested too deeply") from None
    if not top:
        raise SpecError(path, "", "no XML element: not a URDF")
    return top[0]


class _Checker:
    """The checks of one URDF; `fail` builds the error naming the line and the element."""

    def __init__(self, path: str, package_dirs):
        self.path = path
        self.folder = Path(path).parent
        self.package_dirs = package_search_dirs(package_dirs)
        self.mesh_bytes: dict[str, int] = {}

    def fail(self, el: _Element, what: str, message: str) -> SpecError:
        return SpecError(self.path, f"line {el.line}: {what}" if what else f"line {el.line}", message)

    # -- values
    def name(self, el: _Element, kind: str, attr: str = "name") -> str:
        value = el.attrib.get(attr)
        if value is None or not value.strip():
            raise self.fail(el, f"<{kind}>", f"has no {attr}" if value is None else f"its {attr} is empty")
        if len(value) > MAX_NAME_CHARS:
            raise self.fail(el, f"<{kind}>", f"its {attr} is {len(value)} characters long; at most {MAX_NAME_CHARS}")
        return value

    def values(self, el: _Element, attr: str, count: int, what: str, label: str,
               default: tuple[float, ...] | None = None) -> tuple[float, ...]:
        """``count`` numbers of attribute ``attr`` (``default`` when absent, refused when
        there is no default): decimal numbers, or nan and inf (for a message saying what
        they break); text is refused without being quoted."""
        text = el.attrib.get(attr)
        if text is None:
            if default is None:
                raise self.fail(el, what, f"{label}: missing (<{el.tag} {attr}=...>)")
            return default
        parts = text.split()
        if len(parts) != count:
            raise self.fail(el, what, f"{label}: expected {count} number{'s' if count > 1 else ''}, "
                                      f"got {len(parts)} value{'' if len(parts) == 1 else 's'}")
        out = []
        for part in parts:
            try:
                x = float(part)
            except ValueError:
                x = None
            if x is None or (math.isfinite(x) and not _NUMBER.match(part)):  # text, or 1_0 that only Python reads
                raise self.fail(el, what, f"{label}: expected a decimal number, got a value that is not one")
            out.append(x)
        return tuple(out)

    def named(self, elements: list[_Element], kind: str) -> dict[str, _Element]:
        """name -> element of ``elements`` (the links or the joints), each name checked and once."""
        out: dict[str, _Element] = {}
        for el in elements:
            name = self.name(el, kind)
            if name in out:
                raise self.fail(el, f"{kind} {name_shown(name)}", f"a second {kind} of that name (the first is on "
                                                                  f"line {out[name].line})")
            out[name] = el
        return out

    def numbers(self, el: _Element, attr: str, count: int, what: str, label: str,
                default: tuple[float, ...] | None = None) -> tuple[float, ...]:
        """`values`, each finite."""
        values = self.values(el, attr, count, what, label, default)
        if not all(math.isfinite(v) for v in values):
            raise self.fail(el, what, f"{label} must be a finite number, got {_shown(values)}" if count == 1
                            else f"{label} must be finite numbers, got {_shown(values)}")
        return values

    def positive(self, el: _Element, attr: str, count: int, what: str, label: str, *, nonzero: bool = False,
                 high: float = math.inf):
        """`values`, each finite and > 0 (``nonzero``: != 0), at most ``high`` (metres)."""
        values = self.values(el, attr, count, what, label)
        if not all(math.isfinite(v) for v in values):
            rule = "finite non-zero numbers" if nonzero else ("a finite number > 0" if count == 1 else "finite numbers > 0")
            raise self.fail(el, what, f"{label} must be {rule}, got {_shown(values)}")
        if nonzero and not all(values):
            raise self.fail(el, what, f"{label} must be non-zero, got {_shown(values)}")
        if not nonzero and not all(v > 0 for v in values):
            raise self.fail(el, what, f"{label} must be > 0, got {_shown(values)}")
        if not all(abs(v) <= high for v in values):
            raise self.fail(el, what, f"{label} must be at most {high:g} m, got {_shown(values)}")
        return values

    def origin(self, parent: _Element, what: str) -> None:
        el = parent.find("origin")
        if el is not None:
            xyz = self.numbers(el, "xyz", 3, what, "<origin> xyz", (0.0, 0.0, 0.0))
            if not all(abs(v) <= MAX_LENGTH_M for v in xyz):
                raise self.fail(el, what, f"<origin> xyz must be within {MAX_LENGTH_M:g} m, got {_shown(xyz)}")
            self.numbers(el, "rpy", 3, what, "<origin> rpy", (0.0, 0.0, 0.0))

    def optional(self, el: _Element | None, attrs, what: str, *, nonnegative: bool = False) -> dict:
        """The attributes ``attrs`` present on ``el``, each one finite number."""
        out = {}
        if el is None:
            return out
        for attr in attrs:
            if attr in el.attrib:
                x = self.numbers(el, attr, 1, what, f"<{el.tag}> {attr}")[0]
                if nonnegative and x < 0:
                    raise self.fail(el, what, f"<{el.tag}> {attr} must be >= 0, got {x:g}")
                out[attr] = x
        return out

    # -- links
    def link(self, el: _Element, name: str, shapes: list) -> None:
        what = f"link {name_shown(name)}"
        inertial = el.find("inertial")
        if inertial is not None:
            self.origin(inertial, what)
            mass = inertial.find("mass")
            if mass is None:
                raise self.fail(inertial, what, "<inertial> has no <mass>")
            m = self.numbers(mass, "value", 1, what, "mass")[0]
            if m < 0:
                raise self.fail(mass, what, f"mass must be >= 0, got {m:g}")
            inertia = inertial.find("inertia")
            if inertia is None:
                raise self.fail(inertial, what, "<inertial> has no <inertia>")
            i = {attr: self.numbers(inertia, attr, 1, what, f"inertia {attr}")[0]
                 for attr in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")}
            # a body's moments about its axes are >= 0 (the diagonal of a positive semi-definite
            # matrix); published robots (tiago, romeo) have products of inertia that make the
            # matrix slightly indefinite, which the simulators accept, so only the diagonal is held
            tol = INERTIA_TOL + 1e-9 * max(abs(i["ixx"]), abs(i["iyy"]), abs(i["izz"]))  # -5e-20 in iCub's: rounding
            negative = [a for a in ("ixx", "iyy", "izz") if i[a] < -tol]
            if negative:
                raise self.fail(inertia, what, f"inertia {negative[0]} must be >= 0 (a moment of inertia), "
                                               f"got {i[negative[0]]:g}")
        for kind in ("collision", "visual"):
            for shape in el.findall(kind):
                shapes.append((kind, name, shape))
                self.origin(shape, what)
                geometry = shape.find("geometry")
                if geometry is None:
                    raise self.fail(shape, what, f"<{kind}> has no <geometry>")
                known = [g for g in geometry.children if g.tag in SHAPE_SIZES or g.tag == "mesh"]
                if not known:
                    raise self.fail(geometry, what, f"<{kind}> <geometry> holds no box, cylinder, sphere or mesh")
                g = known[0]
                if g.tag == "mesh":
                    self.mesh(g, kind, what)
                    continue
                for attr, count in SHAPE_SIZES[g.tag]:
                    self.positive(g, attr, count, what, f"{kind} {g.tag} {attr}", high=MAX_LENGTH_M)

    def mesh(self, el: _Element, kind: str, what: str) -> None:
        filename = el.attrib.get("filename")
        if filename is None or not filename.strip():
            raise self.fail(el, what, f"{kind} <mesh> has no filename")
        if "scale" in el.attrib:
            self.positive(el, "scale", 3, what, f"{kind} mesh scale", nonzero=True)
        label = f"{kind} mesh {name_shown(filename, path=True)}"
        path = self.mesh_file(el, what, label, filename, required=kind == "collision")
        if path is None:
            return
        try:
            st = os.stat(path)
        except OSError as err:
            raise self.fail(el, what, f"{label}: cannot read it: {err.strerror}") from None
        if not stat.S_ISREG(st.st_mode):
            raise self.fail(el, what, f"{label}: not a regular file")
        if st.st_size > MAX_MESH_BYTES:
            raise self.fail(el, what, f"{label} is {st.st_size} bytes; at most {MAX_MESH_BYTES} are read")
        self.mesh_bytes[str(path)] = st.st_size
        if sum(self.mesh_bytes.values()) > MAX_MESH_BYTES_TOTAL:
            raise self.fail(el, what, f"{label}: the URDF's meshes hold more than {MAX_MESH_BYTES_TOTAL} bytes together")
        try:
            n = mesh_triangles(path, st.st_size)
        except ValueError as err:
            raise self.fail(el, what, f"{label}: {err}") from None
        except OSError as err:
            raise self.fail(el, what, f"{label}: cannot read it: {err.strerror}") from None
        if kind == "collision" and n > MAX_MESH_TRIANGLES:
            raise self.fail(el, what, too_many_triangles(label, n))

    def mesh_file(self, el: _Element, what: str, label: str, filename: str, required: bool) -> Path | None:
        """Where pinocchio and pybullet find a mesh (`resolve_mesh`). A missing visual mesh is
        None (pybullet and the pictures go without it; published models name meshes of their
        authors' machines)."""
        found = resolve_mesh(filename, self.folder, self.package_dirs)
        if found is not None:
            return found
        if not required:
            return None
        where = "in the package dirs" if filename.startswith("package://") else "beside the URDF or in the package dirs"
        raise self.fail(el, what, f"{label}: file not found {where}")

    # -- joints
    def joint(self, el: _Element, name: str, links: dict) -> tuple[str, str]:
        what = f"joint {name_shown(name)}"
        kind = el.attrib.get("type")
        if kind not in JOINT_TYPES:
            raise self.fail(el, what, ("has no type" if kind is None else "unknown type")
                            + f"; types are {', '.join(JOINT_TYPES)}")
        ends = []
        for end in ("parent", "child"):
            tag = el.find(end)
            if tag is None:
                raise self.fail(el, what, f"has no <{end} link=...>")
            link = self.name(tag, end, "link")
            if link not in links:
                raise self.fail(tag, what, f"its {end} link {name_shown(link)} is not a link of the URDF")
            ends.append(link)
        if ends[0] == ends[1]:
            raise self.fail(el, what, f"link {name_shown(ends[0])} is both its parent and its child")
        self.origin(el, what)
        axis = el.find("axis")
        if axis is not None and kind in AXIS_JOINTS:
            xyz = self.numbers(axis, "xyz", 3, what, "<axis> xyz", (1.0, 0.0, 0.0))
            if math.sqrt(sum(v * v for v in xyz)) < MIN_AXIS_NORM:
                raise self.fail(axis, what, f"<axis> xyz must be a non-zero direction (length >= {MIN_AXIS_NORM:g}), "
                                            f"got {_shown(xyz)}")
        limit = el.find("limit")
        if kind in LIMITED_JOINTS and limit is None:
            raise self.fail(el, what, f"a {kind} joint needs <limit lower upper effort velocity>")
        if limit is not None:
            lower = self.numbers(limit, "lower", 1, what, "<limit> lower", (0.0,))[0]
            upper = self.numbers(limit, "upper", 1, what, "<limit> upper", (0.0,))[0]
            for attr in ("effort", "velocity"):
                default = None if kind in LIMITED_JOINTS else (0.0,)
                x = self.numbers(limit, attr, 1, what, f"<limit> {attr}", default)[0]
                if x < 0:
                    raise self.fail(limit, what, f"<limit> {attr} must be >= 0, got {x:g}")
            if kind in LIMITED_JOINTS and lower > upper:
                raise self.fail(limit, what, f"<limit> lower {lower:g} > upper {upper:g}")
        self.optional(el.find("dynamics"), ("damping", "friction"), what, nonnegative=True)
        self.optional(el.find("safety_controller"), ("soft_lower_limit", "soft_upper_limit", "k_position",
                                                     "k_velocity"), what)
        self.optional(el.find("calibration"), ("rising", "falling", "reference_position"), what)
        return ends[0], ends[1]

    def mimic(self, el: _Element, name: str, joints: dict) -> Mimic | None:
        """The joint's ``<mimic joint multiplier offset>`` (URDF defaults 1 and 0): its numbers
        finite, the joint it follows named. What makes a coupling usable (the joint followed
        exists, moves, is no follower itself) is checked where a hand uses it (`Mimic.problem`):
        published robots carry mimics on fixed or unused joints that pinocchio reads."""
        el_m = el.find("mimic")
        if el_m is None:
            return None
        what = f"joint {name_shown(name)}: <mimic>"
        if not el_m.attrib.get("joint", "").strip():
            raise self.fail(el_m, what, "has no joint=\"...\" (the joint it follows)")
        driver = self.name(el_m, "mimic", "joint")
        values = self.optional(el_m, ("multiplier", "offset"), what)
        d = joints.get(driver)
        return Mimic(name, driver, float(values.get("multiplier", 1.0)), float(values.get("offset", 0.0)), el_m.line,
                     el.attrib.get("type", ""), None if d is None else d.attrib.get("type", ""),
                     "" if d is None or d.find("mimic") is None else d.find("mimic").attrib.get("joint", ""))


def installed_share_dirs() -> list[str]:
    """Directories that may hold ROS packages of installed wheels: cmeel wheels
    (example-robot-data, under ``site-packages/cmeel.prefix/share``) and wheels installing
    data files under the environment's ``share`` (icub-models: ``<prefix>/share/iCub``)."""
    import glob
    import site
    import sys

    roots = list(site.getsitepackages()) + [site.getusersitepackages(), sys.prefix, site.getuserbase()]
    roots += [p for p in sys.path if p.endswith("site-packages")]
    out = []
    for root in roots:
        for cand in (os.path.join(root, "cmeel.prefix", "share"), os.path.join(root, "share")):
            if os.path.isdir(cand) and cand not in out and (
                    os.path.isdir(os.path.join(cand, "example-robot-data")) or root in (sys.prefix, site.getuserbase())):
                out.append(cand)
    for cand in glob.glob(os.path.join(sys.prefix, "lib", "python3*", "site-packages", "cmeel.prefix", "share")):
        if os.path.isdir(cand) and cand not in out:
            out.append(cand)
    return out


def package_search_dirs(package_dirs=(), installed: bool = False) -> list[str]:
    """The folders ``package://`` (and relative) mesh paths are looked up in, in order: the
    given ones (a hand.yaml's ``package_dirs``, ``--package-dir``), then ``ROS_PACKAGE_PATH``
    and ``AMENT_PREFIX_PATH``'s ``share`` folders (read now), then (``installed``) the
    installed wheels' (`installed_share_dirs`). The one list every library is given.

    An environment entry that is no folder (missing, a file, a symbolic link loop) is left
    out, as ROS's own tools skip it: pinocchio's loader stopped on a loop there ("Too many
    levels of symbolic links" naming the folder, not the variable)."""
    env = [d for v in PACKAGE_PATH_VARIABLES for d in _package_path_entries(v) if os.path.isdir(d)]
    out: list[str] = []
    for d in [str(d) for d in package_dirs] + env + (installed_share_dirs() if installed else []):
        if d not in out:
            out.append(d)
    return out


#: The environment variables pinocchio reads package folders from by itself (its ``rosPaths``).
PACKAGE_PATH_VARIABLES = ("ROS_PACKAGE_PATH", "AMENT_PREFIX_PATH")


_ENVIRON_LOCK = threading.Lock()


def _package_path_entries(variable: str) -> list[str]:
    """The folders a package path variable names, now (``AMENT_PREFIX_PATH``: their ``share``)."""
    entries = [d for d in os.environ.get(variable, "").split(os.pathsep) if d]
    return [os.path.join(d, "share") for d in entries] if variable == "AMENT_PREFIX_PATH" else entries


def _unusable(variable: str) -> bool:
    """An entry of a package path variable that is no folder (missing, a file, a link loop)."""
    return any(not os.path.isdir(d) for d in _package_path_entries(variable))


@contextlib.contextmanager
def given_package_dirs_only():
    """While pinocchio loads geometry it is given every package folder (`package_search_dirs`:
    the environment's usable ones included) and reads none from a package path variable with
    an entry that is no folder: a symbolic link loop there stopped its loader ("Too many levels
    of symbolic links"). Such a variable is taken out of the environment for the load (under a
    lock: one thread at a time) and put back; a usable one is left alone."""
    with _ENVIRON_LOCK:
        saved = {k: os.environ.pop(k) for k in PACKAGE_PATH_VARIABLES if _unusable(k)}
        try:
            yield
        finally:
            os.environ.update(saved)


#: URDF (resolved path) -> the mesh folders the hand loaded from it was given (`register_mesh_dirs`):
#: a pybullet scene built from the URDF's path alone (`planner.sim.scene.hand_body`) finds
#: the meshes in the same folders as pinocchio and coal did.
_MESH_DIRS: dict[str, tuple[str, ...]] = {}


def register_mesh_dirs(urdf_path, dirs) -> None:
    """Record the folders a hand's meshes were found in (`planner.hand.Hand` does, on loading)."""
    _MESH_DIRS[str(Path(urdf_path).resolve())] = tuple(str(d) for d in dirs)


def mesh_dirs_of(urdf_path) -> tuple[str, ...]:
    """The folders `register_mesh_dirs` recorded for this URDF (none: ())."""
    return _MESH_DIRS.get(str(Path(urdf_path).resolve()), ())


def resolve_mesh(filename: str, folder, package_dirs) -> Path | None:
    """The file a URDF mesh path names, or None: ``package://pkg/x`` under a package dir,
    ``file://`` or an absolute path as is, a relative path in the URDF's ``folder``, then in
    a package dir. The one resolution every command uses (pinocchio and coal are given the
    same folders; pybullet and the viewer a copy of the URDF with these paths written in,
    `rewritten_urdf`)."""
    if filename.startswith("package://"):
        rel = filename[len("package://"):].lstrip("/")
        candidates = [Path(d) / rel for d in package_dirs]
    elif filename.startswith("file://"):
        candidates = [Path(filename[len("file://"):])]
    elif os.path.isabs(filename):
        candidates = [Path(filename)]
    else:
        candidates = [Path(folder) / filename] + [Path(d) / filename for d in package_dirs]
    for cand in candidates:
        if os.path.lexists(cand):
            return cand
    return None


#: Density of the stated inertia of a link without ``<inertial>`` (`stated_inertias`), kg/m^3:
#: a plastic or aluminium-shelled finger part is 1000-1500.
STATED_DENSITY_KG_M3 = 1000.0
#: Least mass a link without ``<inertial>`` is given (all of it when it has no collision
#: geometry, e.g. a fingertip frame's link), kg. pybullet alone gives such a link 1 kg.
MIN_STATED_MASS_KG = 1e-3
#: Size of the box whose inertia a link without geometry gets, m.
STATED_EMPTY_SIZE_M = 0.01


def _rpy_matrix(rpy):
    import numpy as np

    r, pch, y = rpy
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(pch), math.sin(pch), math.cos(y), math.sin(y)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def _numbers(el, attr, default):
    return tuple(float(v) for v in el.get(attr).split()) if el is not None and el.get(attr) else default


def stated_inertias(path: str | os.PathLike, package_dirs=()) -> dict[str, tuple[float, tuple[float, float, float]]]:
    """The inertia every command gives a link that has none (no ``<inertial>``, or a mass of
    0; the root link, fixed to the world, excepted): link -> (mass kg, principal moments kg m^2
    about the link's own origin and axes). The mass is `STATED_DENSITY_KG_M3` times the volume
    of its collision shapes (a mesh: its convex hull's), at least `MIN_STATED_MASS_KG`; the
    moments a solid box's of that mass and the size of the box holding its collision shapes
    (`STATED_EMPTY_SIZE_M` without geometry). pinocchio (`planner.hand.Hand`) and pybullet
    (`planner.sim.scene.hand_body`) both take it from here; ``regrasp hand check`` lists them.
    The URDF has passed `check_urdf`."""
    import xml.etree.ElementTree as ET

    import numpy as np

    path = str(path)
    dirs = package_search_dirs([*package_dirs, *mesh_dirs_of(path)], installed=True)
    tree = ET.fromstring(read_limited(path, MAX_URDF_BYTES, "URDF"))
    children = {j.find("child").get("link") for j in tree.findall("joint") if j.find("child") is not None}
    out = {}
    for link in tree.findall("link"):
        name = link.get("name")
        inertial = link.find("inertial")
        if name not in children:
            continue
        if inertial is not None:
            mass_el = inertial.find("mass")
            if mass_el is None or float(mass_el.get("value", "0")) > 0:
                continue
        volume, points = 0.0, []
        for col in link.findall("collision"):
            geometry = col.find("geometry")
            shape = next((g for g in geometry if g.tag in SHAPE_SIZES or g.tag == "mesh"), None) if geometry is not None else None
            if shape is None:
                continue
            origin = col.find("origin")
            R, t = _rpy_matrix(_numbers(origin, "rpy", (0.0, 0.0, 0.0))), np.array(_numbers(origin, "xyz", (0.0, 0.0, 0.0)))
            if shape.tag == "mesh":
                found = resolve_mesh(shape.get("filename", ""), Path(path).parent, dirs)
                if found is None:
                    continue
                import coal  # coal: loaded only for a link without inertia

                scale = np.array(_numbers(shape, "scale", (1.0, 1.0, 1.0)))
                bvh = coal.MeshLoader().load(str(found), scale)
                V = np.asarray(bvh.vertices(), float)
                if len(V) < 4:
                    continue
                from scipy.spatial import ConvexHull, QhullError

                try:
                    volume += float(ConvexHull(V).volume)
                except QhullError:  # flat (coplanar vertices): no volume
                    pass
            else:
                size = {a: _numbers(shape, a, (0.0,)) for a, _ in SHAPE_SIZES[shape.tag]}
                if shape.tag == "box":
                    h = np.array(size["size"]) / 2.0
                    volume += float(np.prod(2.0 * h))
                elif shape.tag == "sphere":
                    r = size["radius"][0]
                    h = np.array([r, r, r])
                    volume += 4.0 / 3.0 * math.pi * r ** 3
                else:
                    r, length = size["radius"][0], size["length"][0]
                    cap = r if shape.tag == "capsule" else 0.0
                    h = np.array([r, r, length / 2.0 + cap])
                    volume += math.pi * r * r * length + (4.0 / 3.0 * math.pi * r ** 3 if cap else 0.0)
                V = np.array([[a, b, c] for a in (-h[0], h[0]) for b in (-h[1], h[1]) for c in (-h[2], h[2])])
            points.append(V @ R.T + t)
        if points:
            P = np.vstack(points)
            size = np.maximum(np.ptp(P, axis=0), 1e-3)
        else:
            size = np.full(3, STATED_EMPTY_SIZE_M)
        mass = max(MIN_STATED_MASS_KG, STATED_DENSITY_KG_M3 * volume)
        x, y, z = (float(v) for v in size)
        out[name] = (float(mass), (mass / 12.0 * (y * y + z * z), mass / 12.0 * (x * x + z * z), mass / 12.0 * (x * x + y * y)))
    return out


#: Top-level URDF elements a cut sub-tree keeps besides its links and joints (a
#: ``<transmission>`` or ``<gazebo>`` block may name what was cut away; the planner reads neither).
_KEPT_TOP = ("material",)


def rewritten_urdf(path: str | os.PathLike, package_dirs=(), *, root: str | None = None,
                   dest_dir: str | os.PathLike | None = None, comment: str = "") -> str:
    """The text of a URDF (checked by `check_urdf` first) rewritten for a reader that is
    not in its folder:

    * ``root``: only the sub-tree below that link (it becomes the root link; the joints
      above it, their links and everything else of the robot are left out);
    * mesh paths: with ``dest_dir``, a relative path is rewritten relative to ``dest_dir``
      (where the new file is written) and ``package://`` paths are kept; without it, every
      mesh path that resolves (`resolve_mesh`) is written as an absolute path (pybullet
      knows no ``package://`` and one search path only).

    Raises:
        SpecError: the URDF fails `check_urdf`, or ``root`` is not one of its links.
    """
    import xml.etree.ElementTree as ET

    from planner.errors import UnknownNameError

    path = str(path)
    dirs = package_search_dirs([*package_dirs, *mesh_dirs_of(path)], installed=True)
    summary = check_urdf(path, dirs)  # our checks first: no DOCTYPE, bounded sizes, one tree
    tree = ET.fromstring(read_limited(path, MAX_URDF_BYTES, "URDF"))
    if root is not None:
        if root not in summary.links:
            raise SpecError(path, "root", str(UnknownNameError("link", root, summary.links)))
        children: dict[str, list] = {}
        for j in tree.findall("joint"):
            children.setdefault(j.find("parent").get("link"), []).append(j)
        keep_links, keep_joints, todo = {root}, set(), [root]
        while todo:
            for j in children.get(todo.pop(), []):
                keep_joints.add(j.get("name"))
                child = j.find("child").get("link")
                keep_links.add(child)
                todo.append(child)
        for el in list(tree):
            if ((el.tag == "link" and el.get("name") not in keep_links)
                    or (el.tag == "joint" and el.get("name") not in keep_joints)
                    or el.tag not in ("link", "joint", *_KEPT_TOP)):
                tree.remove(el)
        for j in tree.findall("joint"):  # a mimic of a joint cut away would refer to nothing
            m = j.find("mimic")
            if m is not None and m.get("joint") not in keep_joints:
                j.remove(m)
    folder = Path(path).parent
    for mesh in tree.iter("mesh"):
        name = mesh.get("filename", "")
        found = resolve_mesh(name, folder, dirs)
        if found is None:
            continue
        if dest_dir is None:
            mesh.set("filename", str(Path(found).resolve()))
        elif not name.startswith(("package://", "file://")) and not os.path.isabs(name):
            mesh.set("filename", os.path.relpath(Path(found).resolve(), Path(dest_dir).resolve()))
    head = f"<?xml version=\"1.0\"?>\n<!-- {comment.replace('--', '- -')} -->\n" if comment else "<?xml version=\"1.0\"?>\n"
    return head + ET.tostring(tree, encoding="unicode") + "\n"


def too_many_triangles(label: str, n: int, limit: int = MAX_MESH_TRIANGLES) -> str:
    """The message for a collision mesh of ``n`` triangles, past ``limit``."""
    return (f"{label} has {n} triangles; at most {limit} in a collision mesh "
            "(the planner uses its convex hull): simplify it, or give the link a primitive shape")


def mesh_triangles(path: str | os.PathLike, size: int) -> int:
    """Triangles (faces, for polygons) of an STL (binary or ASCII), OBJ or COLLADA file,
    read from the file itself.

    Raises:
        ValueError: another format, or a count the file cannot hold (a binary STL's header,
            a COLLADA ``count``): the mesh loader would allocate or wait for what it claims.
    """
    suffix = Path(path).suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise ValueError(f"a {suffix or 'suffix-less'} file: meshes are STL, OBJ or COLLADA (.dae), the formats "
                         "pybullet reads")
    with open(path, "rb") as fh:
        if suffix == ".stl":
            head = fh.read(84)
            if head[:5].lower() == b"solid":  # ASCII, unless a binary header begins so
                data = head + fh.read(MAX_MESH_BYTES)
                if b"endfacet" in data[:4096] or size < 84:
                    return data.count(b"endfacet")
            if len(head) < 84:
                raise ValueError("not an STL file: shorter than a binary STL's header")
            n = int.from_bytes(head[80:84], "little")
            if 84 + 50 * n > size:
                raise ValueError(f"binary STL header counts {n} triangles, the file holds {max(0, size - 84) // 50}")
            return n
        data = fh.read(MAX_MESH_BYTES)
    if suffix == ".obj":  # (plain substring counts: a regex takes seconds on published meshes)
        return data.startswith((b"f ", b"f\t")) + data.count(b"\nf ") + data.count(b"\nf\t")
    faces = 0
    for m in re.finditer(rb'count="(\d+)"', data):  # each counted item takes a byte at least
        count = m.group(1)
        if len(count) > 12 or int(count) > size:
            raise ValueError(f"a COLLADA count of {int(count) if len(count) <= 12 else 'over 1e12'} items "
                             f"in a file of {size} bytes")
        tag = re.match(rb"<(\w+)", data[data.rfind(b"<", 0, m.start()):m.start()])
        if tag and tag.group(1) in (b"triangles", b"polylist", b"polygons", b"tristrips", b"trifans"):
            faces += int(count)
    return faces


def check_urdf(path: str | os.PathLike, package_dirs=()) -> UrdfSummary:
    """Read a URDF within the limits of this module and check it (see the module's
    docstring) before any library reads it.

    Args:
        path: the URDF.
        package_dirs: folders ``package://`` (and relative) mesh paths are looked up in.

    Raises:
        SpecError: the file (as given), the line and the element, one line.
    """
    path = str(path)
    text = read_limited(path, MAX_URDF_BYTES, "URDF")
    robot = _parse(text, path)
    if robot.tag != "robot":
        raise SpecError(path, f"line {robot.line}", f"the top element is <{robot.tag[:40]}>, not <robot>: not a URDF")
    if any(c.tag.startswith("xacro:") for c in robot.children):  # (expanded files keep the xmlns)
        raise SpecError(path, f"line {robot.line}", "a xacro file, not a URDF: expand it first "
                                                    "(xacro model.urdf.xacro > model.urdf)")
    ck = _Checker(path, package_dirs)
    robot_name = ck.name(robot, "robot")
    link_els = robot.findall("link")
    joint_els = robot.findall("joint")
    if len(link_els) > MAX_LINKS:
        raise ck.fail(robot, "<robot>", f"{len(link_els)} links; at most {MAX_LINKS}")
    links = ck.named(link_els, "link")
    if not links:
        raise ck.fail(robot, "<robot>", "no <link>")
    shapes: list = []
    for name, el in links.items():
        ck.link(el, name, shapes)
        if len(shapes) > MAX_SHAPES:
            raise ck.fail(el, f"link {name_shown(name)}", f"more than {MAX_SHAPES} collision and visual shapes "
                                                          "in the URDF")
    joints = ck.named(joint_els, "joint")
    parent_of: dict[str, tuple[str, str]] = {}  # child link -> (parent link, joint)
    children: dict[str, list[str]] = {n: [] for n in links}
    for name, el in joints.items():
        parent, child = ck.joint(el, name, links)
        if child in parent_of:
            raise ck.fail(el, f"joint {name_shown(name)}", f"link {name_shown(child)} has two parents: it is the "
                                                           f"child of joint {name_shown(parent_of[child][1])} too")
        parent_of[child] = (parent, name)
        children[parent].append(child)
    mimics = tuple(m for m in (ck.mimic(el, name, joints) for name, el in joints.items()) if m is not None)
    roots = [n for n in links if n not in parent_of]
    if len(roots) > 1:
        raise ck.fail(robot, "<robot>", f"{len(roots)} root links ({', '.join(name_shown(r) for r in roots[:4])}"
                                        f"{', ...' if len(roots) > 4 else ''}): a URDF's links form one tree, "
                                        "with one link that is no joint's child")
    if not roots:
        raise ck.fail(robot, "<robot>", "every link is a joint's child: the joints form a cycle")
    reached, todo = set(), [roots[0]]
    while todo:
        link = todo.pop()
        reached.add(link)
        todo.extend(children[link])
    lost = [n for n in links if n not in reached]
    if lost:
        raise ck.fail(links[lost[0]], f"link {name_shown(lost[0])}", f"not connected to the root link "
                                                                     f"{name_shown(roots[0])}: the joints form a cycle")
    return UrdfSummary(path, robot_name, roots[0], tuple(links), tuple(joints), tuple(ck.mesh_bytes), mimics)


def library_message(err: BaseException) -> str:
    """A C++ library's exception for a one-line message: its ``message:`` part when it has
    one (coal and pinocchio put the C++ source file, function and line before it), else its
    first line that names no source location; at most 200 characters."""
    text = str(err)
    m = re.search(r"message:\s*(\S.*)", text)
    lines = [m.group(1)] if m else [ln.strip() for ln in text.splitlines()
                                     if ln.strip() and not re.match(r"(From file|in function|at line)\b", ln.strip())]
    line = lines[0] if lines else type(err).__name__
    return line if len(line) <= 200 else line[:197] + "..."
