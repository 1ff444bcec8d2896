"""A dexterous hand: URDF + hand spec (robots/<hand>/hand.yaml), kinematics and geometry.

Pinocchio gives forward kinematics and Jacobians, coal the collision geometry. All poses
are in the palm frame (``T_palm_link``). The hand's ``q`` vector is pinocchio's
configuration vector; ``Hand.joint_names`` gives its order.

Hand spec (schema_version 1)::

    schema_version: 1
    name: icub_right                # optional, default: the folder name
    units: {length: m, angle: rad}  # optional; the only units read (any other key is refused)
    urdf: icub_right.urdf           # relative to the yaml, absolute, or package://pkg/...
    package_dirs: []                # optional, extra dirs holding ROS packages
    palm_frame: palm
    fingers:                        # ordered
      index:
        joints: [index_0, index_1, index_2, index_3]
        close_joints: [index_1, ...]       # optional, default: all joints (closing, eqs. 8-9)
        close_toward: {index_1: lower}     # optional: a closing joint's closing end, lower or
                                           # upper (default upper); it opens toward the other
        contact_links: [index_distal, ...] # optional, default: the finger's links with geometry
        tip_frame: index_tip
        pad: {link: index_distal, point: [x, y, z], normal: [x, y, z]}  # optional, link frame
    open: {joint: value, ...}       # optional, rad; others 0 clipped into the limits
    effort: 0.7                     # optional, N m: joint torque limits, one for all or
                                    # {joint: N m}; default the URDF's <limit effort>
    disabled_collisions: [[link_a, link_b], ...]  # optional, besides the automatic ones
    couplings:                      # optional: coupled joints the URDF has no <mimic> for
      - {joint: index_3, follows: index_2, multiplier: 1.0, offset: 0.0}   # q_3 = 1.0 q_2 + 0.0

Coupled joints (a URDF ``<mimic>`` or a hand.yaml coupling, `Coupling`): the follower is set
from its driver, ``q_follower = multiplier * q_driver + offset``, both of one finger. A plan
commands the drivers; followers move by the coupling. `Hand.lower` and `Hand.upper` are the
limits the planner keeps: a driver's URDF range narrowed to where its followers stay within
theirs, a follower's the image of that range (`Hand.urdf_lower`, `Hand.urdf_upper`: the URDF's).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import coal
import numpy as np
import pinocchio as pin

from planner.collision import CollisionModel, Geometry, HandState
from planner.errors import SpecError, UnknownNameError
from planner.fileio import MAX_GRASP_BYTES, Reader, as_path, read_yaml, repr_short, resolve_path
from planner.ik import IK_TOL_M, IKResult, close_finger, ik_solve
from planner.kinematics import Kinematics, checked_q
from planner.model import PALM
from planner.resources import HAND_SPEC, bundled_hands, hand_dir, robots_dir
from planner.signed_distance import convex_hull
from planner.urdf_check import (MAX_MESH_TRIANGLES, MAX_NAME_CHARS, check_urdf, given_package_dirs_only,
                                 installed_share_dirs, library_message, name_shown, package_search_dirs,
                                 register_mesh_dirs, stated_inertias, too_many_triangles)

#: Why a coupling may not join two fingers (or a finger and a locked joint).
CROSS_FINGER = ("a coupling joins joints of one finger only: a regrasp lifts one finger at a time, and fingers "
                "driven by one actuator (a parallel gripper, an underactuated hand) move together; put both joints "
                "in one finger's joints, or remove the coupling")

ROBOTS_DIR = robots_dir()  # the bundled hands (planner.resources), wherever the package is installed
SCHEMA_VERSION = 1
#: The keys of a hand.yaml (the module docstring), of one of its fingers, and its units.
SPEC_KEYS = ("schema_version", "name", "units", "urdf", "package_dirs", "palm_frame", "palm_normal", "fingers",
             "open", "effort", "disabled_collisions", "couplings")
FINGER_KEYS = ("joints", "close_joints", "close_toward", "contact_links", "tip_frame", "pad")
UNITS = {"length": "m", "angle": "rad"}


_share_dirs = installed_share_dirs  # (the name other modules import)


@dataclass(frozen=True)
class Coupling:
    """A coupled joint: ``q[joint] = multiplier * q[follows] + offset`` (rad, or m for a
    prismatic joint).

    Attributes:
        joint: the follower (it has no actuator of its own).
        follows: its driver, a joint of the same finger that follows nothing.
        multiplier: non-zero.
        offset: rad (m).
        source: where it is declared ("URDF line 12", "hand.yaml couplings[0]").
    """

    joint: str
    follows: str
    multiplier: float
    offset: float
    source: str


@dataclass(frozen=True)
class Finger:
    """One finger: an ordered serial chain of joints of the hand.

    Attributes:
        name: finger name ("index").
        joints: joint names, base to tip.
        q_index: position of each joint in the hand's q vector.
        contact_links: links that may touch the object.
        tip_frame: frame at the fingertip.
        q_open: open posture of the finger's joints (rad), same order as ``joints``.
        close_joints: joints moved by the closing procedure (thesis eqs. 8-9).
        close_lower: the joints the closing procedure moves (closing joints, a coupled one's
            driver) that close toward their lower limit (hand.yaml ``close_toward: {joint:
            lower}``); the others close toward their upper limit.
        links: every link of the finger that has collision geometry.
        pad_link, pad_p_link, pad_n_link: the fingertip pad (default IK point): a link, a point
            on its surface and the outward surface normal there, both in the link frame.
        free: positions in ``joints`` of the finger's free coordinates (its joints that follow
            no other: the drivers and the uncoupled joints), in joint order.
        coupled: (follower position, driver position, multiplier, offset) per coupled joint
            of the finger, positions in ``joints`` (`Coupling`).
    """

    name: str
    joints: tuple[str, ...]
    q_index: tuple[int, ...]
    contact_links: tuple[str, ...]
    tip_frame: str
    q_open: tuple[float, ...]
    close_joints: tuple[str, ...] = ()
    close_lower: tuple[str, ...] = ()
    links: tuple[str, ...] = ()
    pad_link: str = ""
    pad_p_link: tuple[float, float, float] = (0.0, 0.0, 0.0)
    pad_n_link: tuple[float, float, float] | None = None
    free: tuple[int, ...] = ()
    coupled: tuple[tuple[int, int, float, float], ...] = ()

    @property
    def free_index(self) -> tuple[int, ...]:
        """Positions in the hand's q vector of the finger's free coordinates (`free`)."""
        return tuple(self.q_index[k] for k in self.free)

    def closes_toward(self, joint: str) -> str:
        """The limit ("upper" or "lower") a closing joint closes toward (`close_lower`)."""
        return "lower" if joint in self.close_lower else "upper"

    def driver_closing(self) -> dict[str, float]:
        """The joints the closing procedure moves, each with its closing sign (+1.0 toward its
        upper limit, -1.0 toward its lower, `closes_toward`), in joint order: the closing
        joints, a follower replaced by its driver (the followers move by the coupling)."""
        driver = {self.joints[fl]: self.joints[d] for fl, d, _, _ in self.coupled}
        moved = {driver.get(j, j) for j in self.close_joints}
        return {j: (-1.0 if j in self.close_lower else 1.0) for j in self.joints if j in moved}

    @property
    def drivers(self) -> tuple[str, ...]:
        """The finger's free joints (`free`): what a plan commands."""
        return tuple(self.joints[k] for k in self.free)

    def couple(self, q_finger) -> np.ndarray:
        """A copy of ``q_finger`` (..., n_joints) with every follower set from its driver."""
        q = np.array(q_finger, dtype=float)
        for f, d, m, o in self.coupled:
            q[..., f] = m * q[..., d] + o
        return q

    def step(self, q_finger, dz, lo, hi) -> np.ndarray:
        """``q_finger`` (n_joints,) with its free coordinates moved by ``dz`` (n_free,), every
        joint clipped into ``[lo, hi]`` (n_joints,) and the followers set by the coupling: a
        solver's step over the free coordinates (`reduce` gives their Jacobian)."""
        if not self.coupled:
            return np.clip(np.asarray(q_finger, dtype=float) + dz, lo, hi)
        q = np.array(q_finger, dtype=float)
        q[list(self.free)] += dz
        return self.couple(np.clip(q, lo, hi))

    def reduce(self, J) -> np.ndarray:
        """``J`` (..., n_joints), a map from the finger's joint rates (a Jacobian), as a map
        from its free coordinates' rates (..., n_free): a follower's column is added to its
        driver's times the multiplier (chain rule: dq_f = m dq_d). Applied to torques
        ``tau`` (n_joints,) it gives each actuator's load, ``tau_d + m tau_f`` (virtual work)."""
        J = np.asarray(J, dtype=float)
        if not self.coupled:
            return J[..., list(self.free)] if len(self.free) != J.shape[-1] else J
        out = J[..., list(self.free)].copy()
        col = {k: i for i, k in enumerate(self.free)}
        for f, d, m, _ in self.coupled:
            out[..., col[d]] += m * J[..., f]
        return out


def _link_shape(spec_path: str, urdf_path: str, link: str, go):
    """A link's collision shape as the planner uses it: a mesh (STL/OBJ/DAE, a coal BVH) is
    replaced by its convex hull, as pybullet does for the mesh of a moving link. coal then
    measures signed distances (penetration depth, by GJK/EPA) and accepts the negative
    security margins of the collision checks, which it refuses for a BVH ("Negative
    security margin are not handled yet for BVHModel").

    `planner.urdf_check` counted the triangles of the mesh formats it reads; a mesh of
    another format is counted here, before its hull is taken."""
    shape = go.geometry
    if not isinstance(shape, coal.BVHModelBase):
        return shape
    label = f"{urdf_path}: link {name_shown(link)}: collision mesh {name_shown(Path(go.meshPath).name)}"
    if shape.num_tris > MAX_MESH_TRIANGLES:
        raise SpecError(spec_path, "urdf", too_many_triangles(label, shape.num_tris, MAX_MESH_TRIANGLES))
    V = np.asarray(shape.vertices(), dtype=float) if shape.num_vertices else np.zeros((0, 3))
    if len(V) < 4 or np.linalg.matrix_rank(V - V.mean(axis=0), tol=1e-9) < 3:
        raise SpecError(spec_path, "urdf", f"{label} is flat or empty ({len(V)} vertices): "
                                           "give it a solid mesh or a primitive shape")
    try:
        return convex_hull(V)
    except RuntimeError as err:  # coal: a hull vertex with more than 255 neighbours ("Too many neighbors")
        raise SpecError(spec_path, "urdf", f"{label}: coal cannot take its convex hull ({library_message(err)}): "
                                           "simplify the mesh") from None


#: The values of a finger's ``close_toward:`` (the limit a closing joint closes toward).
CLOSE_ENDS = ("upper", "lower")


def _close_lower(r: Reader, close, follows: dict) -> tuple[str, ...]:
    """The joints a finger's ``close_toward: {joint: lower|upper}`` closes toward their lower
    limit (absent: none; every closing joint closes toward its upper limit). A key is one of
    the joints the closing procedure moves: a closing joint, a coupled one's driver (the
    procedure moves drivers; ``follows``: follower -> driver); a follower is refused, naming
    its driver, as in ``open:``."""
    if r.value is None:
        return ()
    r.mapping("a mapping closing joint -> lower or upper", string_keys=True)
    moved = list(dict.fromkeys(follows.get(j, j) for j in close))
    out = []
    for j, v in r.items():
        if j in follows and follows[j] in moved:
            raise r.fail(f"{j} follows {follows[j]} (a coupling): give {follows[j]}'s closing direction", j)
        if j not in moved:
            raise r.fail(str(UnknownNameError("closing joint", j, moved)), j)
        if v.choice(CLOSE_ENDS, "closing end", show=repr) == "lower":
            out.append(j)
    return tuple(j for j in moved if j in out)


def _merge_capsules(entries):
    """Replace cylinder + 2 end spheres of equal radius on one link by one coal.Capsule.

    URDF has no capsule; the authored hands describe capsules this way. One capsule is exact
    and three times cheaper to query.
    """
    by_link: dict[str, list] = {}
    for e in entries:
        by_link.setdefault(e[0], []).append(e)
    out = []
    for link, items in by_link.items():
        cyl = [e for e in items if isinstance(e[2], coal.Cylinder)]
        sph = [e for e in items if isinstance(e[2], coal.Sphere)]
        if len(items) == 3 and len(cyl) == 1 and len(sph) == 2:
            c = cyl[0]
            r, half = float(c[2].radius), float(c[2].halfLength)
            ends = [c[4].act(np.array([0.0, 0.0, s * half])) for s in (-1.0, 1.0)]
            ok = all(abs(float(s[2].radius) - r) < 1e-9 for s in sph)
            ok = ok and all(min(np.linalg.norm(s[4].translation - p) for p in ends) < 1e-7 for s in sph)
            if ok:
                out.append((link, c[1], coal.Capsule(r, 2.0 * half), c[3], c[4]))
                continue
        out.extend(items)
    return out


#: Closings `Hand.close_finger` remembers per hand (the oldest half dropped beyond this).
CLOSE_MEMO = 256


class Hand:
    """A hand model: pinocchio kinematics, coal geometry and the finger structure.

    Use ``Hand.load("icub_right")`` or ``Hand.load("path/to/hand.yaml")``.
    Read-only once loaded: it holds no ``pinocchio.Data``; every kinematic query runs on a
    state of its own (`Hand.kinematics`, `Hand.state`), so one hand can serve many callers.
    """

    def __init__(self, spec_path: Path, spec: dict):
        self.spec_path = Path(spec_path)
        self._load(spec)

    # ------------------------------------------------------------------ loading
    @classmethod
    def load(cls, name_or_path: str | os.PathLike) -> "Hand":
        """Load a hand by name (a bundled hand, `planner.resources.bundled_hands`, from any
        directory) or by the path of its hand.yaml or of the folder holding it.

        A bare name (no folder, no .yaml suffix) is a bundled hand when one has that name,
        else a path.

        Raises:
            UnknownNameError: a bare name that is neither a bundled hand nor a file or folder.
            SpecError: the hand.yaml is missing or invalid (file + key path in the message).
        """
        path = as_path(name_or_path, "hand", "a bundled hand's name or a hand.yaml path")
        bare = path.suffix not in (".yaml", ".yml") and len(path.parts) == 1
        if bare and path.name in bundled_hands():
            path = hand_dir(path.name)
        if path.is_dir():
            path = path / HAND_SPEC
        elif bare and not path.is_file():
            raise UnknownNameError("hand", str(name_or_path), bundled_hands())
        if not path.exists():
            raise SpecError(str(path), "", "file not found")
        # the bounded reader: size, nesting, aliases, integer digits; a FIFO or device refused
        spec = read_yaml(path, MAX_GRASP_BYTES, "hand spec")
        Reader(path, spec).mapping("a mapping at the top level", with_value=False)
        return cls(path, spec)

    def _load(self, spec: dict) -> None:
        sp = str(self.spec_path)
        r = Reader(sp, spec, got=repr_short, got_value=repr_short)
        r.require("schema_version", "urdf", "palm_frame", "fingers", message="missing required key")
        # a misspelt key (close_joint, close_towards) was ignored: the hand then closed all joints
        # upward, silently
        r.allow(SPEC_KEYS)
        if spec.get("units") is not None:
            units = r.child("units").mapping()
            units.allow(UNITS)
            for k, v in spec["units"].items():
                if v != UNITS[k]:
                    raise units.fail(f"the planner reads lengths in m and angles in rad, got {repr_short(v)}", k)
        if spec["schema_version"] != SCHEMA_VERSION:
            raise r.fail(f"unsupported version {spec['schema_version']!r}; supported: {SCHEMA_VERSION}", "schema_version")
        if "name" in spec:
            self.name = r.child("name").name(MAX_NAME_CHARS)
            if "/" in self.name or "\\" in self.name or self.name in (".", ".."):  # it names synth's output files
                raise r.fail(f"expected a name without / or \\ (synth names its files <hand>_<shape>_01.yaml), got "
                             f"{repr_short(self.name)}", "name")
        else:  # the folder's (absolute: '../hand.yaml' is in a folder with a name, not '..')
            self.name = Path(os.path.abspath(self.spec_path)).parent.name
        # the hand.yaml's package_dirs, then ROS_PACKAGE_PATH, then the installed wheels' share
        dirs = []
        for k, d in enumerate(r.child("package_dirs", []).strings()):
            try:
                dirs.append(str(resolve_path(self.spec_path.parent / d)))
            except OSError as err:  # a symlink loop
                raise r.fail(f"cannot resolve {d!r}: {err}", f"package_dirs[{k}]") from None
        self.package_dirs = package_search_dirs(dirs, installed=True)
        self.urdf_path = self._resolve_urdf(r.child("urdf").string())
        # a relative mesh path is relative to the URDF's folder (as pybullet reads it);
        # pinocchio looks for it in package_dirs. `mesh_dirs` is the one list every library
        # is given (pinocchio and coal here, the viewer; pybullet a copy of the URDF with the
        # paths resolved in them, `planner.sim.scene.hand_body`)
        mesh_dirs = [str(Path(self.urdf_path).parent)] + self.package_dirs
        self.mesh_dirs = tuple(mesh_dirs)
        register_mesh_dirs(self.urdf_path, mesh_dirs)
        try:  # our checks first: pinocchio, coal and pybullet hang or crash on some files
            urdf = check_urdf(self.urdf_path, mesh_dirs)
        except SpecError as err:
            raise SpecError(sp, "urdf", str(err)) from None
        #: links without inertia (no <inertial>, or mass 0) -> (mass kg, principal moments kg m^2
        #: about the link's origin and axes): `planner.urdf_check.stated_inertias`, the same
        #: in this model (gravity torques) and in pybullet (`planner.sim.scene.hand_body`)
        self.stated_inertia = stated_inertias(self.urdf_path, mesh_dirs)
        #: every file the hand is read from (its spec, URDF and meshes): no output may be one
        self.files = (str(Path(self.spec_path).resolve()), str(Path(self.urdf_path).resolve()),
                      *(str(Path(m).resolve()) for m in urdf.meshes))
        try:
            full = pin.buildModelFromUrdf(self.urdf_path)
        except (RuntimeError, ValueError) as err:
            raise SpecError(sp, "urdf", f"pinocchio cannot load {self.urdf_path}: {library_message(err)}") from None

        for link, (mass, moments) in self.stated_inertia.items():
            frame = full.frames[full.getFrameId(link, pin.FrameType.BODY)]
            R = frame.placement.rotation
            full.inertias[frame.parentJoint] = full.inertias[frame.parentJoint] + pin.Inertia(
                mass, frame.placement.translation, R @ np.diag(moments) @ R.T)

        fingers_r = r.child("fingers").mapping("a non-empty mapping finger -> spec", nonempty=True, with_value=False)
        fingers_spec = spec["fingers"]
        urdf_joints = [n for n in full.names[1:]]
        used: list[str] = []
        for fname, fr in fingers_r.items():
            if not isinstance(fname, str) or not fname.strip():
                raise fr.fail(f"a finger name must be a word (e.g. index), got {fname!r}")
            if fname == PALM:  # the palm's contacts are keyed by it (planner.model.PALM)
                raise fr.fail(f"{PALM!r} names the hand's base links, not a finger; call the finger something else")
            if fname == "object":  # a plan's reposing steps move it (planner.plan_data.OBJECT)
                raise fr.fail("'object' names what the hand holds (a plan's repose steps), not a finger; call the "
                              "finger something else")
            fr.mapping(with_value=False)
            fr.allow(FINGER_KEYS)
            fr.require("joints", "tip_frame", message="missing required key")
            joints_r = fr.child("joints")
            if not joints_r.strings():
                raise joints_r.fail("expected the finger's joints (base to tip), got an empty list")
            for j in joints_r.strings():
                if j not in urdf_joints:
                    raise joints_r.fail(str(UnknownNameError("joint", j, urdf_joints)))
                if joints_r.value.count(j) > 1:
                    raise joints_r.fail(f"joint {j!r} is named twice")
                if j in used:
                    raise joints_r.fail(f"joint {j!r} belongs to two fingers")
                used.append(j)
        # joints outside every finger are locked at 0 (e.g. a wrist)
        locked = [full.getJointId(n) for n in urdf_joints if n not in used]
        if locked:
            full = pin.buildReducedModel(full, locked, pin.neutral(full))
        self.model = full
        for jid in range(1, self.model.njoints):
            if self.model.joints[jid].nq != 1:
                raise SpecError(sp, "urdf", f"joint {self.model.names[jid]!r} is not 1-dof; "
                                            "only revolute/prismatic joints are supported")
        self.joint_names = tuple(self.model.names[1:])
        self.urdf_lower = np.array(self.model.lowerPositionLimit, dtype=float)
        self.urdf_upper = np.array(self.model.upperPositionLimit, dtype=float)
        finger_of = {j: fname for fname, fs in fingers_spec.items() for j in fs["joints"]}
        self.couplings = self._couplings(r, urdf, finger_of)
        self.lower, self.upper = self._coupled_limits(sp)
        for a in (self.urdf_lower, self.urdf_upper, self.lower, self.upper):
            a.flags.writeable = False
        self.effort, self.effort_source = self._effort_limits(r.child("effort"))
        frame_names = [f.name for f in self.model.frames]
        body_names = sorted({f.name for f in self.model.frames if f.type == pin.FrameType.BODY})

        def frame_id(key, name, kind="frame"):
            if not isinstance(name, str) or not self.model.existFrame(name):
                valid = body_names if kind == "link" else frame_names
                raise SpecError(sp, key, str(UnknownNameError(kind, str(name), valid)))
            return self.model.getFrameId(name)

        self.palm_frame = str(spec["palm_frame"])
        pid = frame_id("palm_frame", self.palm_frame, "link")
        if self.model.frames[pid].parentJoint != 0:
            raise SpecError(sp, "palm_frame", f"{self.palm_frame!r} moves with a joint; "
                                              "the palm must be fixed to the URDF root")
        # grasping face of the palm (unit, palm frame): "palm down" is gravity along it
        self.palm_normal = tuple(float(x) for x in r.child("palm_normal", [0.0, 0.0, 1.0]).array(3))
        if abs(np.linalg.norm(self.palm_normal) - 1.0) > 1e-6:
            raise r.fail(f"expected a unit vector (palm frame), got {list(self.palm_normal)}", "palm_normal")
        self._T_palm_world = self.model.frames[pid].placement.inverse()

        # open posture
        q_open = np.clip(np.zeros(self.model.nq), self.lower, self.upper)
        open_r = r.at(spec.get("open", {}) or {}, "open").mapping("a mapping joint -> angle (rad)", with_value=False)
        for j, v in open_r.items():
            if j not in self.joint_names:
                raise open_r.fail(str(UnknownNameError("joint", str(j), self.joint_names)))
            i = self.joint_names.index(j)
            q_open[i] = v.number(self.lower[i] - 1e-9, self.upper[i] + 1e-9, bools=True,
                                 expected=f"a number in [{self.lower[i]:.4g}, {self.upper[i]:.4g}]")
            c = next((c for c in self.couplings if c.joint == j), None)
            if c is not None:
                raise open_r.fail(f"{j} follows {c.follows} ({c.source}): give {c.follows}'s angle", j)
        q_open = self.couple(q_open)
        q_open.flags.writeable = False
        self.q_open = q_open

        # collision geometry
        try:
            with given_package_dirs_only():
                gm = pin.buildGeomFromUrdf(self.model, self.urdf_path, pin.GeometryType.COLLISION,
                                           package_dirs=mesh_dirs)
        except (RuntimeError, ValueError) as err:
            raise SpecError(sp, "urdf", f"cannot load the collision geometry of {self.urdf_path}: "
                                        f"{library_message(err)}") from None
        joint_finger: dict[int, str] = {}
        for fname, fs in fingers_spec.items():
            for j in fs["joints"]:
                joint_finger[self.model.getJointId(j)] = fname

        def finger_of_joint(jid: int) -> str | None:
            while jid != 0:
                if jid in joint_finger:
                    return joint_finger[jid]
                jid = self.model.parents[jid]
            return None

        entries = []
        for go in gm.geometryObjects:
            link = self.model.frames[go.parentFrame].name
            entries.append((link, finger_of_joint(go.parentJoint), _link_shape(sp, self.urdf_path, link, go), go.parentJoint,
                            pin.SE3(go.placement)))
        geoms: list[Geometry] = []
        for link, fname, shape, jid, plc in _merge_capsules(entries):
            shape.computeLocalAABB()
            center = plc.act(np.asarray(shape.aabb_center, dtype=float))
            geoms.append(Geometry(len(geoms), link, fname, shape, jid, plc, center, float(shape.aabb_radius)))
        link_geoms: dict[str, list[int]] = {}
        for g in geoms:
            link_geoms.setdefault(g.link, []).append(g.index)
        self.links = tuple(link_geoms)

        # fingers
        self.fingers: dict[str, Finger] = {}
        follows = {c.joint: c.follows for c in self.couplings}
        for fname, fr in fingers_r.items():
            fs, key = fr.value, fr.key
            joints = tuple(fs["joints"])
            q_index = tuple(self.joint_names.index(j) for j in joints)
            flinks = tuple(l for l in link_geoms if geoms[link_geoms[l][0]].finger == fname)
            contact_r = fr.child("contact_links", list(flinks))
            contact = contact_r.strings()
            if not contact and "contact_links" in fs:
                raise contact_r.fail(f"expected the links that may touch the object, got an empty list; links are "
                                     f"{', '.join(flinks) or '(none)'} (leave the key out: all of them)")
            for l in contact:
                if l not in flinks:
                    raise contact_r.fail(str(UnknownNameError("link", l, flinks or ["(none)"])))
            close_r = fr.child("close_joints", list(joints))
            close = close_r.strings()
            if not close:
                raise close_r.fail(f"expected the joints that close the finger, got an empty list; joints are "
                                   f"{', '.join(joints)} (leave the key out: all of them)")
            for j in close:
                if j not in joints:
                    raise close_r.fail(str(UnknownNameError("joint", j, joints)))
                if close.count(j) > 1:
                    raise close_r.fail(f"joint {j!r} is named twice")
            close_lower = _close_lower(fr.child("close_toward", {}), close, follows)
            tip = fs["tip_frame"]
            tip_id = frame_id(f"{key}.tip_frame", tip)
            # the tip and the pad move with this finger's joints (another finger's or the palm's
            # frame passed here and each contact point was then refused as out of reach)
            own = [f.name for f in self.model.frames if finger_of_joint(f.parentJoint) == fname]
            if finger_of_joint(self.model.frames[tip_id].parentJoint) != fname:
                raise fr.fail(f"frame {tip!r} does not move with finger {fname}'s joints; its frames are "
                              f"{', '.join(own) or '(none)'}", "tip_frame")
            pad = fs.get("pad")
            if pad is None:
                # default pad: the tip frame origin on the link carrying it; no normal known
                tip_frame = self.model.frames[tip_id]
                pad_link = self.model.frames[tip_frame.parentFrame].name
                pad_p = tuple(tip_frame.placement.translation) if pad_link != tip else (0.0, 0.0, 0.0)
                pad_n = None
            else:
                pad_r = fr.child("pad")
                if not isinstance(pad, dict) or "link" not in pad or "point" not in pad:
                    raise pad_r.fail("expected {link, point, normal}")
                pad_r.allow(("link", "point", "normal"))
                pad_link = pad["link"]
                pad_id = frame_id(f"{key}.pad.link", pad_link, "link")
                if finger_of_joint(self.model.frames[pad_id].parentJoint) != fname:
                    own_links = [f.name for f in self.model.frames
                                 if f.type == pin.FrameType.BODY and finger_of_joint(f.parentJoint) == fname]
                    raise pad_r.fail(f"link {pad_link!r} is not a link of finger {fname}; its links are "
                                     f"{', '.join(own_links) or '(none)'}", "link")
                pad_p = tuple(pad_r.child("point").array(3))
                pad_n = None
                if pad.get("normal") is not None:
                    n = pad_r.child("normal").array(3)
                    if np.linalg.norm(n) < 1e-9:
                        raise pad_r.fail("must be non-zero", "normal")
                    pad_n = tuple(float(x) for x in n / np.linalg.norm(n))
            coupled = tuple((joints.index(c.joint), joints.index(c.follows), c.multiplier, c.offset)
                            for c in self.couplings if c.joint in joints)
            followers = {k for k, *_ in coupled}
            self.fingers[fname] = Finger(
                name=fname, joints=joints, q_index=q_index, contact_links=tuple(contact),
                tip_frame=tip, q_open=tuple(float(q_open[i]) for i in q_index),
                close_joints=tuple(close), close_lower=close_lower, links=flinks, pad_link=pad_link,
                pad_p_link=tuple(float(x) for x in pad_p), pad_n_link=pad_n,
                free=tuple(k for k in range(len(joints)) if k not in followers), coupled=coupled)

        # collision pairs between links: skip adjacent bodies and pairs touching at q = 0 or
        # at the open posture (shapes that overlap by design, like MoveIt's "default" pairs)
        allowed = set()
        disabled_r = r.at(spec.get("disabled_collisions", []) or [], "disabled_collisions")
        if not isinstance(disabled_r.value, list):
            raise disabled_r.fail(f"expected a list of [link_a, link_b] pairs, got {repr_short(disabled_r.value)}")
        for pair in disabled_r.value:
            if not (isinstance(pair, list) and len(pair) == 2):
                raise disabled_r.fail(f"expected [link_a, link_b], got {pair!r}")
            for l in pair:
                if l not in link_geoms:
                    raise disabled_r.fail(str(UnknownNameError("link", l, self.links)))
            allowed.add(frozenset(pair))
        link_joint = {l: geoms[ix[0]].joint_id for l, ix in link_geoms.items()}
        for a in self.links:
            for b in self.links:
                ja, jb = link_joint[a], link_joint[b]
                if a < b and (ja == jb or self.model.parents[ja] == jb or self.model.parents[jb] == ja):
                    allowed.add(frozenset((a, b)))
        self.collision = CollisionModel(
            self.model, self._T_palm_world, geoms, {n: f.q_index for n, f in self.fingers.items()}, allowed,
            by_design_qs=(self.couple(np.clip(np.zeros(self.model.nq), self.lower, self.upper)), self.q_open))

    def _couplings(self, r: Reader, urdf, finger_of: dict) -> tuple[Coupling, ...]:
        """The URDF's ``<mimic>`` joints (checked by `planner.urdf_check`) and the hand.yaml's
        ``couplings:``, each follower and its driver of one finger; a follower follows one
        driver, and a driver follows nothing."""
        sp = str(self.spec_path)
        out: list[Coupling] = []
        declared = r.get("couplings") or []
        declared = {c.get("joint") for c in declared if isinstance(c, dict)} if isinstance(declared, list) else set()
        for m in urdf.mimics:
            where = f"line {m.line}: joint {name_shown(m.joint)}: <mimic>"
            fj, fd = finger_of.get(m.joint), finger_of.get(m.follows)
            if fj is None and (fd is None or m.joint_type == "fixed"):
                continue  # a follower locked (outside every finger) or fixed: nothing to couple
            if m.follows_type is None and m.joint in declared:
                continue  # a <mimic> naming no joint (a published file's typo): the hand.yaml's coupling says it
            if m.problem():
                fix = ": state the coupling in the hand.yaml's couplings:" if m.follows_type is None else ""
                raise SpecError(sp, "urdf", f"{self.urdf_path}: {where}: {m.problem()}{fix}")
            if fj != fd:
                def of(joint, fname):
                    return f"{joint} is {'in no finger (locked)' if fname is None else 'of finger ' + fname}"
                raise SpecError(sp, "urdf", f"{self.urdf_path}: {where}: {of(m.joint, fj)}, {of(m.follows, fd)}: "
                                            f"{CROSS_FINGER}")
            out.append(Coupling(m.joint, m.follows, m.multiplier, m.offset, f"URDF line {m.line}"))
        mimicked = {c.joint: c for c in out}
        cr = r.child("couplings", [])
        if cr.value is None:
            cr = cr.at([])
        cr.seq()
        for i, item in cr.items():
            item.mapping("a mapping {joint, follows, multiplier, offset}")
            item.keys(("joint", "follows", "multiplier", "offset"), ("joint", "follows"))
            names = {}
            for key in ("joint", "follows"):
                kr = item.child(key)
                names[key] = kr.string()
                if names[key] not in self.joint_names:
                    raise kr.fail(str(UnknownNameError("joint", names[key], self.joint_names)))
            joint, driver = names["joint"], names["follows"]
            if joint == driver:
                raise item.fail("a joint cannot follow itself", "follows")
            if joint in mimicked:
                raise item.fail(f"{joint} already follows {mimicked[joint].follows} by the URDF's <mimic> "
                                f"({mimicked[joint].source}): remove one", "joint")
            if finger_of[joint] != finger_of[driver]:
                raise item.fail(f"{joint} is of finger {finger_of[joint]}, {driver} of finger {finger_of[driver]}: "
                                f"{CROSS_FINGER}", "follows")
            m = item.child("multiplier", 1.0).number(-1e3, 1e3, expected="a non-zero number in [-1000, 1000]")
            if m == 0:
                raise item.fail("multiplier 0 holds the joint at its offset: lock it instead (leave it out of the "
                                "finger's joints)", "multiplier")
            o = item.child("offset", 0.0).number(-1e3, 1e3, expected="a number in [-1000, 1000] (rad, or m)")
            c = Coupling(joint, driver, m, o, f"hand.yaml couplings[{i}]")
            mimicked[joint] = c
            out.append(c)
        for c in out:
            if c.follows in mimicked:
                d = mimicked[c.follows]
                raise SpecError(sp, "couplings" if c.source.startswith("hand.yaml") else "urdf",
                                f"{c.joint} follows {c.follows} ({c.source}), which follows {d.follows} itself "
                                f"({d.source}): make both follow {d.follows}")
        return tuple(out)

    def _coupled_limits(self, sp: str) -> tuple[np.ndarray, np.ndarray]:
        """The joint limits the planner keeps under the couplings: a driver's URDF range
        narrowed to where every follower stays within its own URDF range, a follower's the
        image of that range (so sampling the drivers within theirs keeps every joint within
        its URDF limits)."""
        lo, hi = self.urdf_lower.copy(), self.urdf_upper.copy()
        ix = {j: i for i, j in enumerate(self.joint_names)}
        for c in self.couplings:
            f, d = ix[c.joint], ix[c.follows]
            a, b = sorted(((lo_f - c.offset) / c.multiplier for lo_f in (self.urdf_lower[f], self.urdf_upper[f])))
            lo[d], hi[d] = max(lo[d], a), min(hi[d], b)
            if lo[d] > hi[d]:
                raise SpecError(sp, "couplings" if c.source.startswith("hand.yaml") else "urdf",
                                f"{c.joint} = {c.multiplier:g} {c.follows} + {c.offset:g} ({c.source}) leaves "
                                f"{c.follows} no angle within both joints' limits")
        for c in self.couplings:
            f, d = ix[c.joint], ix[c.follows]
            a, b = sorted((c.multiplier * lo[d] + c.offset, c.multiplier * hi[d] + c.offset))
            lo[f], hi[f] = max(a, self.urdf_lower[f]), min(b, self.urdf_upper[f])
        return lo, hi

    # ------------------------------------------------------------- couplings
    def couple(self, q) -> np.ndarray:
        """A copy of ``q`` (..., nq) with every follower set from its driver (`Coupling`)."""
        q = np.array(q, dtype=float)
        for c, f, d in self._coupling_ix():
            q[..., f] = c.multiplier * q[..., d] + c.offset
        return q

    def coupling_errors(self, q) -> np.ndarray:
        """|q_follower - (multiplier q_driver + offset)| per coupling (`couplings` order), of
        ``q`` (nq,); rad (m)."""
        q = np.asarray(q, dtype=float)
        return np.array([abs(q[f] - (c.multiplier * q[d] + c.offset)) for c, f, d in self._coupling_ix()])

    def coupling_tolerances(self) -> np.ndarray:
        """The coupling error a plan may show, per coupling (`couplings` order): the angle
        (rad) of the follower that moves no point of the links it carries by more than the
        IK's accepted error (`planner.ik.IK_TOL_M`), i.e. ``IK_TOL_M / reach`` with ``reach``
        the farthest collision geometry point (bounding spheres at the open posture) from the
        follower's axis origin; ``IK_TOL_M`` itself (m) for a prismatic follower. The planner
        sets followers exactly (the plan files' 10 significant digits differ by ~1e-10)."""
        kin = self.kinematics(self.q_open)
        out = []
        for c, f, _ in self._coupling_ix():
            jid = self.model.getJointId(c.joint)
            if "Prismatic" in self.model.joints[jid].shortname() or self.model.joints[jid].shortname()[-2:] in (
                    "PX", "PY", "PZ"):
                out.append(IK_TOL_M)
                continue
            below = {jid}
            for j in range(jid + 1, self.model.njoints):  # pinocchio orders a joint's subtree after it
                if self.model.parents[j] in below:
                    below.add(j)
            origin = kin.joint_placement(jid).translation
            reach = max((float(np.linalg.norm(kin.joint_placement(g.joint_id).act(g.center) - origin)) + g.radius_m
                         for g in self.collision.geometries if g.joint_id in below), default=0.0)
            out.append(IK_TOL_M / reach if reach > IK_TOL_M else 1.0)
        return np.array(out)

    def _coupling_ix(self):
        ix = {j: i for i, j in enumerate(self.joint_names)}
        return [(c, ix[c.joint], ix[c.follows]) for c in self.couplings]

    def _effort_limits(self, r: Reader) -> tuple[np.ndarray, tuple[str, ...]]:
        """Joint torque limits (N m, inf: none) and where each comes from ("urdf",
        "hand.yaml", "none"). The URDF's ``<limit effort>`` unless the hand.yaml's
        ``effort:`` (one number for every joint, or joint -> N m) overrides it."""
        urdf = np.array(self.model.effortLimit, dtype=float)
        tau = np.where(np.isfinite(urdf) & (urdf > 0), urdf, np.inf)
        source = ["urdf" if np.isfinite(t) else "none" for t in tau]
        spec = r.value
        if spec is not None:
            if isinstance(spec, bool) or not isinstance(spec, (int, float, dict)):
                raise r.fail(f"expected a torque in N m or a mapping joint -> N m, got {type(spec).__name__}")
            items = r.items() if isinstance(spec, dict) else ((j, r) for j in self.joint_names)
            for j, v in items:
                if j not in self.joint_names:
                    raise r.fail(str(UnknownNameError("joint", str(j), self.joint_names)))
                i = self.joint_names.index(j)
                tau[i] = v.number(positive=True, high=1e4, expected="a joint torque limit in (0, 1e4] N m")
                source[i] = "hand.yaml"
        tau.flags.writeable = False
        return tau, tuple(source)

    def _resolve_urdf(self, urdf: str) -> str:
        if urdf.startswith("package://"):
            rel = urdf[len("package://"):]
            for d in self.package_dirs:
                cand = Path(d) / rel
                if cand.exists():  # (a FIFO or a device is refused by check_urdf, naming it)
                    return str(cand)
            raise SpecError(str(self.spec_path), "urdf",
                            f"{urdf} not found in package_dirs {self.package_dirs}")
        path = Path(urdf)
        if not path.is_absolute():
            path = self.spec_path.parent / path
        if not path.exists():
            raise SpecError(str(self.spec_path), "urdf", f"file not found: {path}")
        return str(path.resolve())

    # ------------------------------------------------------------- name lookups
    def finger(self, finger: str | Finger) -> Finger:
        """The Finger named ``finger`` (a Finger is returned as is)."""
        if isinstance(finger, Finger):
            return finger
        try:
            return self.fingers[finger]
        except KeyError:
            raise UnknownNameError("finger", str(finger), self.fingers) from None

    def _fid(self, frame: str) -> int:
        return self.collision.kinematic_model.frame_id(frame)

    def _check_q(self, q) -> np.ndarray:
        return checked_q(self.model.nq, q)

    def state(self, q) -> HandState:
        """The hand at ``q`` (nq,): the state every kinematic and collision query reads
        (`planner.collision.HandState`; FK once, at construction)."""
        return HandState(self.collision, q)

    def kinematics(self, q) -> Kinematics:
        """The hand's kinematics at ``q`` (nq,) (`planner.kinematics.Kinematics`: its own
        ``pinocchio.Data``, FK once; `Kinematics.update` moves it explicitly)."""
        return Kinematics(self.collision.kinematic_model, q)

    # Kinematic and geometric queries (link poses, Jacobians, gravity torques, posed collision
    # shapes) are made on one state, ``hand.state(q)`` (`planner.collision.HandState`: FK once
    # at construction), never on the hand with a ``q``: several queries of one configuration
    # share its forward kinematics.

    def ik(self, finger, target_palm, q0, link: str | None = None, p_link=None, normal_palm=None,
           restarts: int = 8, max_iter: int = 150, seed: int = 0) -> np.ndarray:
        """Place a point of a finger link on a target; only that finger's joints move.

        `ik_solve` without its report: see there. Returns q (nq,); raises `UnreachableError`
        (a KinematicsError) with the closest reachable point and the direction to move the target.
        """
        return self.ik_solve(finger, target_palm, q0, link=link, p_link=p_link, normal_palm=normal_palm,
                             restarts=restarts, max_iter=max_iter, seed=seed).q

    def ik_solve(self, finger, target_palm, q0, link: str | None = None, p_link=None, normal_palm=None,
                 restarts: int = 8, max_iter: int = 150, seed: int = 0) -> IKResult:
        """Place a point of a finger link on a target; only that finger's joints move.

        `planner.ik.ik_solve` on this hand (damped least squares, the pad normal a secondary
        task): see there. Returns an `IKResult`; raises `UnreachableError`.
        """
        return ik_solve(self, finger, target_palm, q0, link=link, p_link=p_link, normal_palm=normal_palm,
                        restarts=restarts, max_iter=max_iter, seed=seed)

    # ----------------------------------------------------------------- closing
    def close_finger(self, finger, q, obj, steps: int = 20, backoff: float = 1e-3) -> np.ndarray:
        """Close a finger onto the object, thesis eqs. (8)-(9): `planner.ik.close_finger` on
        this hand (see there). Returns q (nq,) with only the finger's closing joints changed.

        Remembered (the last `CLOSE_MEMO` closings, per hand): the same finger, the same ``q``
        to the bit and the object's geometry at the same pose give the same answer, a copy
        (synthesis closes a candidate's fingers, then `planner.realization.realize` closes
        them again from the file it wrote)."""
        name = self.finger(finger).name
        qa = np.asarray(q, dtype=float)
        T = np.asarray(obj.T_palm_obj, dtype=float)
        key = (name, qa.tobytes(), obj.shape, tuple(obj.size), obj.mesh_path, T.tobytes(), steps, backoff)
        memo = self.__dict__.setdefault("_close_memo", {})
        hit = memo.get(key)
        if hit is None:
            hit = np.asarray(close_finger(self, finger, q, obj, steps=steps, backoff=backoff), dtype=float)
            if len(memo) >= CLOSE_MEMO:
                for k in list(memo)[: CLOSE_MEMO // 2]:
                    del memo[k]
            memo[key] = hit
        return hit.copy()
