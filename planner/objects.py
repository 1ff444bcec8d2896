"""Grasped objects: box, cylinder, sphere and triangle mesh, with coal geometry.

The object frame is at the object's centre (box/cylinder/sphere: the geometric centre;
mesh: the origin of the mesh file, scaled). Surface normals returned here point OUTWARD;
contact code flips them to get contact normals into the object.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from planner.errors import InputError, UnknownNameError
from planner.fileio import Reader, resolve_path

if TYPE_CHECKING:  # coal is imported where geometry is built: the shape table needs no coal
    import coal

#: The object model, the one table every reader of ``object.shape``/``object.size`` uses
#: (grasp files, plan files, the replay): shape -> number(s) of ``size`` entries allowed.
SIZE_LENGTHS: Mapping[str, tuple[int, ...]] = MappingProxyType(
    {"box": (3,), "cylinder": (2,), "sphere": (1,), "mesh": (1, 3)})
#: shape -> what its ``size`` entries mean (error messages name it).
SIZE_MEANING: Mapping[str, str] = MappingProxyType({
    "box": "[x, y, z] full extents in metres",
    "cylinder": "[radius, length] in metres, axis = object z",
    "sphere": "[radius] in metres",
    "mesh": "[scale] or [sx, sy, sz]",
})
SHAPES: tuple[str, ...] = tuple(SIZE_LENGTHS)
#: The keys of an ``object:`` block (grasp files, plan files, synth object files, the API).
OBJECT_KEYS = ("shape", "size", "position", "quat_xyzw", "mesh", "mass_kg")
DEFAULT_DENSITY_KG_M3 = 500.0   # used when mass_kg is not given

# Ranges of an object, the same for every reader of an object block (`check_object_block`)
# and for `make_object`; messages state them.
#: Smallest and largest size entry of a box, cylinder or sphere, and extent of a scaled mesh
#: (m): a tenth of the touch tolerance (`planner.contacts.TOUCH_TOL_M`, 1 mm), below which an
#: object's opposite faces are one contact to the planner, up to the plan files' coordinate
#: range (`planner.plan.MAX_COORD_M`; no hand spans a metre).
MIN_SIZE_M, MAX_SIZE_M = 1e-4, 10.0
#: Largest |coordinate| of an object's position in the palm frame (m): the plan files' range.
MAX_POSITION_M = 10.0
#: A mesh's scale factors (its size entries); the scaled mesh must also fit `MAX_SIZE_M`.
MIN_MESH_SCALE, MAX_MESH_SCALE = 1e-6, 1e6
#: Lightest and heaviest object (kg), given or by default (volume x density). A milligram is
#: 1e4 times lighter than a finger link of ~10 g, about the mass ratio the simulator's contact
#: solver still resolves (and a mass of 0 makes its body fixed in space); a tonne is the plan
#: files' range, far beyond any hand's joint torques (the grip model then says the hand
#: cannot hold it: it needs finite forces, not an impossible object).
MIN_MASS_KG, MAX_MASS_KG = 1e-6, 1000.0
#: A quaternion whose norm is within this of 1 is normalised (a file's rounded digits:
#: 0.7071068); farther off it is refused (it is not meant as a rotation).
QUAT_NORM_TOL = 1e-3
#: A quaternion whose norm is 1 to rounding (within this: ten significant digits, as the
#: schema 2 plans wrote them) is kept exactly as written, so a normalised quaternion read
#: again (a plan file's, under its digest) stays bit for bit. The grasp files' rounded
#: quaternions (0.7071068: 4e-8 off; 9 digits: 1e-9 off) are normalised.
QUAT_ROUNDING = 1e-10

# Mesh limits (README "Hardening / plan integrity"), checked before the mesh is read.
#: Most triangles of an object mesh: a 15 cm object (more than the bundled hands span)
#: meshed with 1 mm edges, the touch tolerance: finer detail is below what any contact test
#: resolves. A mesh at the limit loads (parse, k-d tree, coal BVH, the convexity test of
#: `planner.signed_distance`) in a few seconds and ~0.5 GB; decimate a larger one (e.g.
#: Blender's Decimate modifier or ``meshlab``'s quadric edge collapse).
MAX_MESH_TRIANGLES = 200_000
#: Bytes per triangle of the most verbose format read (ASCII STL: seven lines per triangle).
MESH_BYTES_PER_TRIANGLE = 256
#: Largest mesh file read, bytes (a binary STL at the limit holds 50 bytes per triangle).
MAX_MESH_BYTES = MAX_MESH_TRIANGLES * MESH_BYTES_PER_TRIANGLE
#: Most lines of a text mesh (ASCII STL: 7 per triangle; OBJ: v, vn, vt and f lines).
MAX_MESH_LINES = 8 * MAX_MESH_TRIANGLES
#: Most hull-facet candidates the convexity test (`convex_hull_vertices`) examines per probe
#: point on average; past it the mesh counts as not convex (it keeps its triangles).
MAX_HULL_CANDIDATES = 200


class MeshFileError(InputError):
    """A mesh file is missing, too large or malformed (the message names the file, and for
    a malformed text mesh the line, never its content)."""


def _readonly(a) -> np.ndarray:
    a = np.array(a, dtype=float)
    a.flags.writeable = False
    return a


def check_mesh_file(path) -> None:
    """Refuse a mesh file before it is read: not a regular file, not .obj/.stl, more than
    `MAX_MESH_BYTES`, or a binary STL whose header announces more than `MAX_MESH_TRIANGLES`
    triangles or more than the file holds (`MeshFileError`, naming the file and the limit)."""
    path = Path(path)
    try:
        if not path.is_file():
            raise MeshFileError(f"mesh file not found (or not a regular file): {path}")
        ext = path.suffix.lower()
        if ext not in (".obj", ".stl"):
            raise MeshFileError(f"unsupported mesh format {ext!r} for {path}; use .obj or .stl")
        size = path.stat().st_size
        if size > MAX_MESH_BYTES:
            raise MeshFileError(f"mesh {path} is {size} bytes; at most {MAX_MESH_BYTES} bytes "
                                f"({MAX_MESH_TRIANGLES} triangles) are read: decimate it")
        if ext == ".stl":
            with open(path, "rb") as fh:
                head = fh.read(1000)
            if not _ascii_stl(head) and len(head) >= 84:
                (n,) = struct.unpack("<I", head[80:84])
                if size < 84 + 50 * n:  # first: a damaged file is not one to decimate
                    raise MeshFileError(f"mesh {path} is malformed: its binary STL header announces {n} triangles, "
                                        f"the file holds {(size - 84) // 50}")
                if n > MAX_MESH_TRIANGLES:
                    raise MeshFileError(f"mesh {path} has {n} triangles; at most {MAX_MESH_TRIANGLES} are read: "
                                        f"decimate it")
    except OSError as err:
        raise MeshFileError(f"cannot read mesh {path}: {err.strerror}") from None


def load_mesh(path, scale=(1.0, 1.0, 1.0)) -> tuple[np.ndarray, np.ndarray]:
    """Read an OBJ or STL (ASCII or binary) triangle mesh within the mesh limits
    (`check_mesh_file`, `MAX_MESH_LINES`); a malformed line is named by its number.

    Returns:
        vertices (n, 3) scaled, triangles (m, 3) int vertex indices.
    Raises:
        MeshFileError: naming the file (and the line or the limit), never quoting it.
    """
    path = Path(path)
    check_mesh_file(path)
    try:
        with open(path, "rb") as fh:
            raw = fh.read(MAX_MESH_BYTES + 1)
    except OSError as err:
        raise MeshFileError(f"cannot read mesh {path}: {err.strerror}") from None
    if len(raw) > MAX_MESH_BYTES:
        raise MeshFileError(f"mesh {path} is larger than {MAX_MESH_BYTES} bytes")
    obj = path.suffix.lower() == ".obj"
    if (obj or _ascii_stl(raw)) and raw.count(b"\n") > MAX_MESH_LINES:
        raise MeshFileError(f"mesh {path} has more than {MAX_MESH_LINES} lines ({MAX_MESH_TRIANGLES} triangles "
                            f"are read): decimate it")
    try:
        V, F = _parse_obj(raw) if obj else _parse_stl(raw)
    except ValueError as err:
        raise MeshFileError(f"mesh {path} is malformed: {err}") from None
    if len(F) == 0:
        raise MeshFileError(f"mesh {path} has no triangles")
    if len(F) > MAX_MESH_TRIANGLES:
        raise MeshFileError(f"mesh {path} has {len(F)} triangles; at most {MAX_MESH_TRIANGLES} are read: decimate it")
    if F.min() < 0 or F.max() >= len(V):
        raise MeshFileError(f"mesh {path}: a face refers to a vertex that does not exist ({len(V)} vertices)")
    if not np.isfinite(V).all() or np.abs(V).max() > 1e6:
        raise MeshFileError(f"mesh {path}: vertex coordinates must be finite and within 1e6")
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    F = F[np.linalg.norm(np.cross(b - a, c - a), axis=1) > 0]  # a zero-area triangle has no normal
    if not len(F):
        raise MeshFileError(f"mesh {path} has no triangle with a non-zero area")
    used = np.unique(F)
    extent = float(np.ptp(V[used], axis=0).max())
    if np.linalg.matrix_rank(V[used] - V[used].mean(axis=0), tol=1e-9 * max(extent, 1e-300)) < 3:
        raise MeshFileError(f"mesh {path} is flat (all its vertices lie in one plane): an object needs a volume")
    V = V * np.asarray(scale, dtype=float)
    reach, extent = float(np.abs(V[used]).max()), float(np.ptp(V[used], axis=0).max())
    if not (reach <= MAX_SIZE_M and extent >= MIN_SIZE_M):
        shown_scale = ", ".join(f"{float(x):g}" for x in np.ravel(scale))
        raise MeshFileError(f"mesh {path} scaled by [{shown_scale}] spans {extent:.3g} m and reaches "
                            f"{reach:.3g} m from its origin; an object spans at least {MIN_SIZE_M:g} m and lies "
                            f"within {MAX_SIZE_M:g} m of its origin (object.size scales it)")
    return V, F


def _ascii_stl(head: bytes) -> bool:
    return head[:5].lower() == b"solid" and b"facet" in head[:1000]


def _numbers(parts, line: int, what: str, kind=float) -> list:
    """``parts`` as numbers; ValueError naming the line and ``what`` it must be (the text is
    not quoted: a mesh path may point at any file)."""
    try:
        return [kind(x) for x in parts]
    except ValueError:
        raise ValueError(f"line {line}: {what}") from None


def _parse_obj(raw: bytes) -> tuple[np.ndarray, np.ndarray]:
    verts, tris = [], []
    for line, text in enumerate(raw.decode(errors="replace").splitlines(), start=1):
        parts = text.split()
        if not parts:
            continue
        if parts[0] == "v":
            if len(parts) < 4:
                raise ValueError(f"line {line}: a vertex line needs 3 coordinates")
            verts.append(_numbers(parts[1:4], line, "a vertex line needs 3 numbers"))
        elif parts[0] == "f":
            idx = _numbers([p.split("/")[0] for p in parts[1:]], line,
                           "a face needs at least 3 vertex indices (1-based integers)", int)
            if len(idx) < 3 or 0 in idx:
                raise ValueError(f"line {line}: a face needs at least 3 vertex indices (1-based integers)")
            idx = [i - 1 if i > 0 else len(verts) + i for i in idx]
            if not all(0 <= i < len(verts) for i in idx):
                raise ValueError(f"line {line}: a face refers to a vertex not defined before it")
            for k in range(1, len(idx) - 1):   # fan-triangulate polygons
                tris.append([idx[0], idx[k], idx[k + 1]])
            if len(tris) > MAX_MESH_TRIANGLES:
                raise ValueError(f"line {line}: more than {MAX_MESH_TRIANGLES} triangles (decimate it)")
    return np.array(verts, dtype=float).reshape(-1, 3), np.array(tris, dtype=int).reshape(-1, 3)


def _parse_stl(raw: bytes) -> tuple[np.ndarray, np.ndarray]:
    if _ascii_stl(raw):
        pts = []
        for line, text in enumerate(raw.decode(errors="replace").splitlines(), start=1):
            parts = text.split()
            if parts and parts[0] == "vertex":
                if len(parts) != 4:
                    raise ValueError(f"line {line}: a vertex line needs 3 coordinates")
                pts.append(_numbers(parts[1:], line, "a vertex line needs 3 numbers"))
        if len(pts) % 3:
            raise ValueError(f"the vertex count {len(pts)} is not a multiple of 3")
        tri_pts = np.array(pts, dtype=float).reshape(-1, 3, 3)
    else:
        if len(raw) < 84:
            raise ValueError(f"a binary STL has an 84-byte header, the file has {len(raw)} bytes")
        (n,) = struct.unpack("<I", raw[80:84])
        if n > MAX_MESH_TRIANGLES or len(raw) < 84 + 50 * n:
            raise ValueError(f"the header announces {n} triangles, the file holds {(len(raw) - 84) // 50}")
        rec = np.frombuffer(raw[84:84 + 50 * n], dtype=np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)),
                                                                  ("a", "<u2")]))
        tri_pts = rec["v"].astype(float)
    if not len(tri_pts):
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=int)
    V, inv = np.unique(tri_pts.reshape(-1, 3), axis=0, return_inverse=True)
    return V, inv.reshape(-1, 3)


@dataclass(frozen=True)
class GraspObject:
    """A rigid object in the palm frame.

    Attributes:
        shape: "box", "cylinder", "sphere" or "mesh".
        size: box (x, y, z) full extents; cylinder (radius, length), axis = object z;
            sphere (radius,); mesh scale (s,) or (sx, sy, sz). Metres.
        T_palm_obj: (4, 4) read-only pose of the object in the palm frame.
        mesh_path: mesh file for shape "mesh", else None.
        mass_kg: mass (default: volume x 500 kg/m^3).
        mass_given: False when ``mass_kg`` is the default (the file gave none).

    The one object type of the planner: grasp files, plans, synthesis, the replay and the
    pictures hold it. Its file form (the ``object:`` block of grasp and plan files) is
    `to_data` / `from_data`; the pose keeps the quaternion it was given with, so a file read
    and written again says the same. Two objects are equal when their file forms are.
    """

    shape: str
    size: tuple[float, ...]
    T_palm_obj: np.ndarray
    mesh_path: str | None = None
    mass_kg: float = 0.0
    _mesh: "MeshData | None" = field(default=None, repr=False, compare=False)
    _geometry: object = field(default=None, repr=False, compare=False)
    mass_given: bool = True
    _quat_xyzw: tuple | None = field(default=None, repr=False, compare=False)

    # ------------------------------------------------------------- file form
    @classmethod
    def from_data(cls, data: Mapping, base_dir=None) -> "GraspObject":
        """The object of an ``object:`` block (keys shape, size, position, quat_xyzw, and
        optionally mesh, mass_kg), checked by `check_object_block` (a `SpecError` names
        ``<object block>`` and the key: `read_object` names a file's), geometry built.

        Args:
            data: the block; ``quat_xyzw`` a unit quaternion [x, y, z, w] (palm frame),
                ``position`` metres (palm frame); ``mass_kg`` None or absent: the default.
            base_dir: folder a relative ``mesh`` path is relative to (default: as given).
        Raises:
            SpecError: a bad entry. InputError (`MeshFileError`: the mesh): the object
                cannot be built.
        """
        block = check_object_block(Reader("<object block>", data, "object"), base_dir)
        quat = block["quat_xyzw"]
        obj = make_object(block["shape"], block["size"], _pose(block["position"], quat), mesh_path=block["mesh"],
                          mass_kg=block["mass_kg"])
        object.__setattr__(obj, "_quat_xyzw", quat)
        return obj

    def to_data(self) -> dict:
        """Plain-data form, the ``object:`` block of grasp and plan files (``mass_kg`` None
        when the default; ``mesh`` the path as held)."""
        return {
            "shape": self.shape,
            "size": list(self.size),
            "position": list(self.position),
            "quat_xyzw": list(self.quat_xyzw),
            "mesh": self.mesh_path,
            "mass_kg": self.mass_kg if self.mass_given else None,
        }

    def replaced(self, **changes) -> "GraspObject":
        """The object with some of its file-form entries changed (size, position, quat_xyzw,
        mesh, mass_kg; None for the default mass), geometry rebuilt."""
        unknown = set(changes) - {"shape", "size", "position", "quat_xyzw", "mesh", "mass_kg"}
        if unknown:
            raise InputError(f"unknown object entries {sorted(unknown)}; entries are shape, size, position, "
                             "quat_xyzw, mesh, mass_kg")
        if set(changes) <= {"position", "quat_xyzw"}:  # a new pose: the same geometry and mass
            quat = tuple(float(v) for v in changes.get("quat_xyzw", self.quat_xyzw))
            T = _check_pose(_pose(changes.get("position", self.position), quat))
            return GraspObject(self.shape, self.size, T, self.mesh_path, self.mass_kg, self._mesh, self._geometry,
                               self.mass_given, quat)
        return GraspObject.from_data({**self.to_data(), **changes})

    @property
    def position(self) -> tuple[float, float, float]:
        """Object centre in the palm frame, metres."""
        return tuple(float(v) for v in self.T_palm_obj[:3, 3])

    @property
    def quat_xyzw(self) -> tuple[float, float, float, float]:
        """Object orientation in the palm frame, the unit quaternion it was given with."""
        if self._quat_xyzw is not None:
            return self._quat_xyzw
        return tuple(float(v) for v in Rotation.from_matrix(self.T_palm_obj[:3, :3]).as_quat())

    def __eq__(self, other) -> bool:
        return isinstance(other, GraspObject) and self.to_data() == other.to_data()

    def __hash__(self) -> int:
        return hash((self.shape, self.size, self.position, self.quat_xyzw, self.mesh_path))

    def convex_hull_points(self, tol: float) -> np.ndarray | None:
        """A mesh's convex hull vertices (k, 3) when the mesh is convex within ``tol``
        (`convex_hull_vertices`, computed once per mesh and tolerance), else None; None for
        the other shapes."""
        return None if self._mesh is None else self._mesh.convex_hull_points(tol)

    @property
    def geometry(self) -> coal.CollisionGeometry:
        """coal geometry in the object frame (built once)."""
        return self._geometry

    @property
    def volume_m3(self) -> float:
        s = self.size
        if self.shape == "box":
            return float(s[0] * s[1] * s[2])
        if self.shape == "cylinder":
            return float(np.pi * s[0] ** 2 * s[1])
        if self.shape == "sphere":
            return float(4.0 / 3.0 * np.pi * s[0] ** 3)
        return abs(self._mesh.signed_volume_m3)

    @property
    def extents(self) -> np.ndarray:
        """(3,) size of the object's bounding box in its own frame, metres (a mesh's real size)."""
        if self.shape == "box":
            return np.asarray(self.size, dtype=float)
        if self.shape == "cylinder":
            r, length = self.size
            return np.array([2 * r, 2 * r, length])
        if self.shape == "sphere":
            return np.full(3, 2.0 * self.size[0])
        return self._mesh.extents.copy()

    def with_pose(self, T_palm_obj) -> "GraspObject":
        """The same object at another pose (geometry shared)."""
        T = _check_pose(T_palm_obj)
        return GraspObject(self.shape, self.size, T, self.mesh_path, self.mass_kg, self._mesh, self._geometry,
                           self.mass_given)

    # ------------------------------------------------------------- sampling
    def sample_surface(self, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Points uniformly distributed by area on the surface.

        Args:
            n: number of points.
            rng: numpy Generator (seeded by the caller).
        Returns:
            p_obj (n, 3), n_out_obj (n, 3) unit outward normals, object frame.
        """
        if not isinstance(n, (int, np.integer)) or n < 0:
            raise InputError(f"n must be a non-negative integer, got {n!r}")
        if self.shape == "box":
            h = np.array(self.size) / 2.0
            areas = np.array([h[1] * h[2], h[0] * h[2], h[0] * h[1]] * 2)
            face = rng.choice(6, size=n, p=areas / areas.sum())
            axis, sign = face % 3, np.where(face < 3, 1.0, -1.0)
            p = rng.uniform(-h, h, size=(n, 3))
            p[np.arange(n), axis] = sign * h[axis]
            nrm = np.zeros((n, 3))
            nrm[np.arange(n), axis] = sign
            return p, nrm
        if self.shape == "sphere":
            v = rng.normal(size=(n, 3))
            v /= np.linalg.norm(v, axis=1, keepdims=True)
            return v * self.size[0], v
        if self.shape == "cylinder":
            r, L = self.size
            a_side, a_cap = 2 * np.pi * r * L, np.pi * r * r
            part = rng.choice(3, size=n, p=np.array([a_side, a_cap, a_cap]) / (a_side + 2 * a_cap))
            th = rng.uniform(0, 2 * np.pi, size=n)
            p = np.zeros((n, 3))
            nrm = np.zeros((n, 3))
            side = part == 0
            p[side] = np.column_stack([r * np.cos(th[side]), r * np.sin(th[side]),
                                       rng.uniform(-L / 2, L / 2, size=side.sum())])
            nrm[side] = np.column_stack([np.cos(th[side]), np.sin(th[side]), np.zeros(side.sum())])
            cap = ~side
            rad = r * np.sqrt(rng.uniform(0, 1, size=cap.sum()))   # uniform on the disc
            zs = np.where(part[cap] == 1, L / 2, -L / 2)
            p[cap] = np.column_stack([rad * np.cos(th[cap]), rad * np.sin(th[cap]), zs])
            nrm[cap] = np.column_stack([np.zeros(cap.sum()), np.zeros(cap.sum()), np.sign(zs)])
            return p, nrm
        m = self._mesh
        k = rng.choice(len(m.F), size=n, p=m.area_p)
        u, v = rng.uniform(size=(2, n))
        flip = u + v > 1
        u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
        a, b, c = m.a, m.b, m.c
        p = a[k] + u[:, None] * (b[k] - a[k]) + v[:, None] * (c[k] - a[k])
        return p, m.cross[k] / m.area[k][:, None]

    # ------------------------------------------------------------- queries
    def closest_surface(self, p_obj) -> tuple[np.ndarray, np.ndarray, float]:
        """Closest surface point, its outward normal and the signed distance of ``p_obj``.

        Args:
            p_obj: (3,) point in the object frame.
        Returns:
            p_surf_obj (3,), n_out_obj (3,) unit, signed_distance_m (negative inside).
        """
        p = np.asarray(p_obj, dtype=float)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise InputError(f"p_obj must be 3 finite numbers, got {p_obj!r}")
        if self.shape == "sphere":
            r = self.size[0]
            d = np.linalg.norm(p)
            n = p / d if d > 1e-12 else np.array([0.0, 0.0, 1.0])
            return n * r, n, float(d - r)
        if self.shape == "box":
            h = np.array(self.size) / 2.0
            q = np.abs(p) - h
            if np.all(q <= 0) or np.linalg.norm(p - np.clip(p, -h, h)) < 1e-12:   # inside or on: nearest face
                i = int(np.argmax(q))
                s = 1.0 if p[i] >= 0 else -1.0
                ps = p.copy()
                ps[i] = s * h[i]
                n = np.zeros(3)
                n[i] = s
                return ps, n, float(q[i])
            ps = np.clip(p, -h, h)
            d = p - ps
            return ps, d / np.linalg.norm(d), float(np.linalg.norm(d))
        if self.shape == "cylinder":
            r, L = self.size
            rho = np.hypot(p[0], p[1])
            radial = p[:2] / rho if rho > 1e-12 else np.array([1.0, 0.0])
            dr, dz = rho - r, abs(p[2]) - L / 2
            sz = 1.0 if p[2] >= 0 else -1.0
            on_surface = np.linalg.norm(p - np.r_[radial * min(rho, r), np.clip(p[2], -L / 2, L / 2)]) < 1e-12
            if (dr <= 0 and dz <= 0) or on_surface:   # inside or on the surface
                if dr >= dz:
                    return (np.r_[radial * r, p[2]], np.r_[radial, 0.0], float(dr))
                return np.r_[p[:2], sz * L / 2], np.array([0.0, 0.0, sz]), float(dz)
            ps = np.r_[radial * min(rho, r), np.clip(p[2], -L / 2, L / 2)]
            d = p - ps
            return ps, d / np.linalg.norm(d), float(np.linalg.norm(d))
        return self._closest_mesh(p)

    def _closest_mesh(self, p):
        m = self._mesh
        k, ps, d, interior = m.closest(p)
        fn = m.cross[k] / np.linalg.norm(m.cross[k])
        if d <= 1e-12:
            return ps, fn, d
        if interior and m.outward:   # the nearest point inside a face: that face's side decides
            inside = bool(np.dot(p - ps, fn) < 0)
        else:                        # an edge or a vertex is nearest: ray parity
            inside = _inside_mesh(p, m.a, m.b, m.c)
        n_out = (p - ps) / d * (-1.0 if inside else 1.0)
        return ps, n_out, -d if inside else d


class MeshData:
    """A loaded triangle mesh and what its queries need, computed once (read-only arrays).

    The closest-triangle query is exact and sub-linear: a k-d tree of the triangle
    centroids gives the nearest centroid; its triangle's distance d0 bounds the answer, and
    only triangles whose centroid lies within d0 + (largest centroid-to-vertex distance) can
    be closer. ``outward``: the faces are wound with outward normals (positive signed
    volume), so a point whose nearest surface point is inside a face is inside the mesh
    exactly when it lies behind that face; otherwise (or at edges and vertices) the
    ray-parity test decides.
    """

    def __init__(self, V, F):
        self.V = _readonly(V)
        self.F = np.array(F, dtype=np.int64)
        self.F.flags.writeable = False
        self.a, self.b, self.c = (_readonly(self.V[self.F[:, i]]) for i in range(3))
        self.cross = _readonly(np.cross(self.b - self.a, self.c - self.a))
        self.area = _readonly(np.linalg.norm(self.cross, axis=1))
        self.area_p = _readonly(self.area / self.area.sum())
        self.signed_volume_m3 = float(np.einsum("ij,ij->i", self.a, np.cross(self.b, self.c)).sum() / 6.0)
        self.outward = self.signed_volume_m3 > 0
        self.extents = _readonly(self.V.max(axis=0) - self.V.min(axis=0))
        centroid = (self.a + self.b + self.c) / 3.0
        self.reach = float(max(np.linalg.norm(t - centroid, axis=1).max() for t in (self.a, self.b, self.c)))
        self._tree = cKDTree(centroid)

    def convex_hull_points(self, tol: float) -> np.ndarray | None:
        """`convex_hull_vertices` of this mesh as points (k, 3), computed once per ``tol``."""
        cache = self.__dict__.setdefault("_hulls", {})
        if tol not in cache:
            idx = convex_hull_vertices(self.V, self.F, tol)
            cache[tol] = None if idx is None else self.V[idx]
        return cache[tol]

    def closest(self, p):
        """(triangle index, closest point (3,), distance, the point is inside the face) of p."""
        _, k0 = self._tree.query(p)
        c0 = _closest_on_triangles(p, self.a[k0:k0 + 1], self.b[k0:k0 + 1], self.c[k0:k0 + 1])[0]
        d0 = float(np.linalg.norm(c0 - p))
        cand = np.sort(np.asarray(self._tree.query_ball_point(p, d0 + self.reach + 1e-12), dtype=np.int64))
        a, b, c = self.a[cand], self.b[cand], self.c[cand]
        cp = _closest_on_triangles(p, a, b, c)
        d2 = np.einsum("ij,ij->i", cp - p, cp - p)
        j = int(np.argmin(d2))
        k = int(cand[j])
        w = _barycentric(cp[j], a[j], b[j], c[j])
        return k, cp[j], float(np.sqrt(d2[j])), bool(np.all(w > 1e-9))


def convex_hull_vertices(V, F, tol: float) -> np.ndarray | None:
    """Indices of the convex hull's vertices when every vertex and face centroid of the mesh
    (V, F) lies within ``tol`` of the hull's boundary (the mesh is convex to ``tol``), else
    None.

    Exact and sub-quadratic: a probe point p inside the hull is at distance
    ``min_f -(n_f . p + d_f)`` from its boundary, attained on the facet f* holding the nearest
    boundary point q; when that distance is at most ``tol``, f*'s centroid lies within
    ``tol + reach(f*)`` of p (reach: the facet's largest centroid-to-vertex distance). So
    only facets whose centroids are that close are examined: facets grouped by reach
    (doubling), one k-d tree per group. A mesh needing more than `MAX_HULL_CANDIDATES`
    candidates per probe on average (long sliver facets) counts as not convex (it keeps its
    triangles: `planner.signed_distance`).
    """
    from scipy.spatial import ConvexHull

    V = np.asarray(V, dtype=float)
    F = np.asarray(F, dtype=np.int64)
    hull = ConvexHull(V)
    on_hull = np.zeros(len(V), dtype=bool)
    on_hull[hull.vertices] = True
    probes = np.concatenate([V[~on_hull], V[F].mean(axis=1)])  # a hull vertex is on the boundary
    eq = hull.equations
    tri = V[hull.simplices]
    centre = tri.mean(axis=1)
    reach = np.linalg.norm(tri - centre[:, None], axis=2).max(axis=1)
    order = np.argsort(reach, kind="stable")
    groups, lo = [], 0
    while lo < len(order):
        hi = max(int(np.searchsorted(reach[order], max(2.0 * reach[order[lo]], tol), side="right")), lo + 1)
        idx = order[lo:hi]
        groups.append((cKDTree(centre[idx]), idx, tol + float(reach[order[hi - 1]])))
        lo = hi
    budget = MAX_HULL_CANDIDATES * len(probes)
    chunk = 32768
    for s in range(0, len(probes), chunk):
        P = probes[s:s + chunk]
        tree = cKDTree(P)
        budget -= sum(int(tree.count_neighbors(t, r)) for t, _, r in groups)
        if budget < 0:
            return None
        best = np.full(len(P), np.inf)
        for t, idx, r in groups:
            pairs = tree.sparse_distance_matrix(t, r, output_type="ndarray")
            if len(pairs):
                i, f = pairs["i"], idx[pairs["j"]]
                np.minimum.at(best, i, -(np.einsum("ij,ij->i", P[i], eq[f, :3]) + eq[f, 3]))
        if best.max() > tol:
            return None
    return hull.vertices


def _barycentric(x, a, b, c) -> np.ndarray:
    v0, v1, v2 = b - a, c - a, x - a
    d00, d01, d11 = v0 @ v0, v0 @ v1, v1 @ v1
    d20, d21 = v2 @ v0, v2 @ v1
    den = d00 * d11 - d01 * d01
    if den <= 0:
        return np.zeros(3)
    v = (d11 * d20 - d01 * d21) / den
    w = (d00 * d21 - d01 * d20) / den
    return np.array([1.0 - v - w, v, w])


#: Built meshes (MeshData and coal BVH) by file identity and scale: a synthesis builds the
#: same object at every sampled pose; a file changed on disk gets a new entry.
_MESH_CACHE: "dict[tuple, tuple[MeshData, object]]" = {}
_MESH_CACHE_SIZE = 4


def _mesh_and_bvh(mesh_path, scale):
    import coal  # coal: only where geometry is built (the shape table and `GraspObject` need none)

    try:
        path = Path(mesh_path).resolve()
        st = path.stat()
        key = (str(path), st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, tuple(scale))
    except OSError:
        key = None
    if key is not None and key in _MESH_CACHE:
        return _MESH_CACHE[key]
    V, F = load_mesh(mesh_path, scale)
    mesh = MeshData(V, F)
    geom = coal.BVHModelOBBRSS()
    geom.beginModel(len(mesh.F), len(mesh.V))
    geom.addVertices(np.ascontiguousarray(mesh.V, dtype=float))
    geom.addTriangles(np.ascontiguousarray(mesh.F, dtype=np.int64))
    geom.endModel()
    geom.computeLocalAABB()
    if key is not None:
        while len(_MESH_CACHE) >= _MESH_CACHE_SIZE:
            _MESH_CACHE.pop(next(iter(_MESH_CACHE)))
        _MESH_CACHE[key] = (mesh, geom)
    return mesh, geom


def _inside_mesh(p, a, b, c) -> bool:
    """Ray-parity test (Moller-Trumbore, vectorised) for a closed mesh; a fixed odd direction
    avoids grazing edges of axis-aligned meshes."""
    d = np.array([0.5773, 0.5774, 0.5775])
    d = d / np.linalg.norm(d) + np.array([1e-3, -2e-3, 0.0])
    e1, e2 = b - a, c - a
    h = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, h)
    ok = np.abs(det) > 1e-15
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = p - a
    u = np.einsum("ij,ij->i", s, h) * inv
    qv = np.cross(s, e1)
    v = (qv @ d) * inv
    t = np.einsum("ij,ij->i", e2, qv) * inv
    hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
    return bool(hit.sum() % 2)


def _closest_on_triangles(p, a, b, c):
    """Closest point of p on each triangle (a, b, c): (m, 3). Ericson, RTCD 5.1.5, vectorised."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = np.einsum("ij,ij->i", ab, ap), np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3, d4 = np.einsum("ij,ij->i", ab, bp), np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5, d6 = np.einsum("ij,ij->i", ab, cp), np.einsum("ij,ij->i", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = 1.0 / (va + vb + vc)
        v = vb * denom
        w = vc * denom
        out = a + ab * v[:, None] + ac * w[:, None]
        # edge regions
        m = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
        t = d1 / (d1 - d3)
        out[m] = (a + ab * t[:, None])[m]
        m = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
        t = d2 / (d2 - d6)
        out[m] = (a + ac * t[:, None])[m]
        m = (va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0)
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        out[m] = (b + (c - b) * t[:, None])[m]
    # vertex regions
    m = (d1 <= 0) & (d2 <= 0)
    out[m] = a[m]
    m = (d3 >= 0) & (d4 <= d3)
    out[m] = b[m]
    m = (d6 >= 0) & (d5 <= d6)
    out[m] = c[m]
    bad = ~np.isfinite(out).all(axis=1)
    if bad.any():  # a sliver so thin that its weights are 0/0 (float32 STL vertices): its nearest vertex
        corners = np.stack([a[bad], b[bad], c[bad]], axis=1)
        near = np.argmin(np.einsum("ijk,ijk->ij", corners - p, corners - p), axis=1)
        out[bad] = corners[np.arange(len(corners)), near]
    return out


def _pose(position, quat_xyzw) -> np.ndarray:
    """(4, 4) pose of a position (3,) and a unit quaternion [x, y, z, w] (the file form's)."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(quat_xyzw).as_matrix()
    T[:3, 3] = position
    return T


def _check_pose(T) -> np.ndarray:
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise InputError(f"T_palm_obj must be a finite 4x4 matrix, got shape {T.shape}")
    R = T[:3, :3]
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0 or \
            not np.allclose(T[3], [0, 0, 0, 1]):
        raise InputError("T_palm_obj must be a homogeneous rigid transform (orthonormal rotation)")
    return _readonly(T)


def check_object_block(r: Reader, base_dir=None) -> dict:
    """The one validator of an ``object:`` block, for every reader of one (grasp files, plan
    files, synth object files, the API through `GraspObject.from_data`): keys `OBJECT_KEYS`;
    ``shape`` one of `SHAPES`; ``size`` as `SIZE_LENGTHS` says, each entry in
    [`MIN_SIZE_M`, `MAX_SIZE_M`] m (a mesh's scale: [`MIN_MESH_SCALE`, `MAX_MESH_SCALE`]);
    ``position`` within `MAX_POSITION_M`; ``quat_xyzw`` finite, its norm within
    `QUAT_NORM_TOL` of 1 (normalised, unless 1 to `QUAT_ROUNDING`: kept as written);
    ``mesh`` for shape mesh only; ``mass_kg`` absent, null or in [`MIN_MASS_KG`, `MAX_MASS_KG`].

    Args:
        r: the block in its file (`planner.fileio.Reader`: errors name the file and the key
            path, e.g. ``ball.yaml: object.mass_kg: ...``, and the valid range).
        base_dir: folder a relative ``mesh`` is relative to: the mesh file must then exist
            and pass `check_mesh_file` (size and triangle limits, before it is read). None:
            the path is kept as written (a plan's, relative to the plan; checked when built).
    Returns:
        The block: shape, size, position and quat_xyzw as tuples of floats, mesh (a path or
        None), mass_kg (a float or None).
    Raises:
        SpecError: naming r's file and the key path.
    """
    o = r.mapping(string_keys=True)
    o.keys(OBJECT_KEYS, required=("shape", "size", "position", "quat_xyzw"))
    shape = o.child("shape").choice(SHAPES, "shape")
    low, high, unit = (MIN_MESH_SCALE, MAX_MESH_SCALE, "") if shape == "mesh" else (MIN_SIZE_M, MAX_SIZE_M, "m")
    size = o.child("size").vector(SIZE_LENGTHS[shape], SIZE_MEANING[shape], quantity=(low, high, unit))
    position = o.child("position").vector((3,), "[x, y, z] in metres, palm frame",
                                           quantity=(-MAX_POSITION_M, MAX_POSITION_M, "m"))
    quat = o.child("quat_xyzw").vector((4,), "[x, y, z, w]")
    norm = math.sqrt(sum(v * v for v in quat))
    if not abs(norm - 1.0) <= QUAT_NORM_TOL:
        raise o.fail(f"expected a unit quaternion [x, y, z, w] (norm within {QUAT_NORM_TOL:g} of 1: it is "
                     f"normalised), got norm {norm:.4g}", "quat_xyzw")
    if abs(norm - 1.0) > QUAT_ROUNDING:
        quat = tuple(float(v) for v in np.asarray(quat) / norm)
    mesh = None
    if shape == "mesh":
        if o.get("mesh") is None:
            raise o.fail("shape mesh needs a mesh file path (.obj or .stl, relative to this file)", "mesh")
        mesh = o.child("mesh").name(4096)
        if base_dir is not None:
            try:
                mp = Path(mesh) if Path(mesh).is_absolute() else resolve_path(Path(base_dir) / mesh)
            except OSError as err:  # a symlink loop
                raise o.fail(f"cannot resolve the mesh path {mesh!r}: {err}", "mesh") from None
            try:
                check_mesh_file(mp)
            except MeshFileError as err:
                raise o.fail(str(err), "mesh") from None
            mesh = str(mp)
    elif o.get("mesh") is not None:
        raise o.fail(f"only shape mesh takes a mesh file (shape is {shape})", "mesh")
    mass = None
    if o.get("mass_kg") is not None:
        mass = o.child("mass_kg").quantity(MIN_MASS_KG, MAX_MASS_KG, "kg")
    return {"shape": shape, "size": size, "position": position, "quat_xyzw": tuple(quat), "mesh": mesh,
            "mass_kg": mass}


def read_object(r: Reader, base_dir=None) -> GraspObject:
    """The object of the ``object:`` block ``r`` reads (`check_object_block`), its geometry
    built; every error a `SpecError` naming r's file and the key (a mesh's: ``.mesh``)."""
    block = check_object_block(r, base_dir)
    try:
        return GraspObject.from_data(block)
    except MeshFileError as err:
        raise r.fail(str(err), "mesh") from None
    except InputError as err:
        raise r.fail(str(err)) from None


def make_object(shape: str, size, T_palm_obj=None, mesh_path=None, mass_kg=None) -> GraspObject:
    """Build a GraspObject and its coal geometry.

    Args:
        shape: "box", "cylinder", "sphere" or "mesh".
        size: see GraspObject.size (metres); every entry in [`MIN_SIZE_M`, `MAX_SIZE_M`]
            (a mesh's scale in [`MIN_MESH_SCALE`, `MAX_MESH_SCALE`]).
        T_palm_obj: (4, 4) pose in the palm frame (default identity).
        mesh_path: OBJ/STL file for shape "mesh" (`load_mesh`: within the mesh limits).
        mass_kg: in [`MIN_MASS_KG`, `MAX_MASS_KG`], default volume x 500 kg/m^3 (which must
            be in that range too).
    Raises:
        UnknownNameError: unknown shape. InputError: bad size, pose, mass or mesh.
    """
    import coal  # coal: only where geometry is built (the shape table and `GraspObject` need none)

    if shape not in SHAPES:
        raise UnknownNameError("shape", str(shape), SHAPES)
    try:
        s = tuple(float(x) for x in np.atleast_1d(np.asarray(size, dtype=float)))
    except (TypeError, ValueError) as err:
        raise InputError(f"{shape} size must be numbers, got {size!r}") from err
    if len(s) not in SIZE_LENGTHS[shape]:
        raise InputError(f"{shape} size must be {SIZE_MEANING[shape]}, got {size!r}")
    low, high, unit = (MIN_MESH_SCALE, MAX_MESH_SCALE, "") if shape == "mesh" else (MIN_SIZE_M, MAX_SIZE_M, " m")
    if not all(np.isfinite(x) and low <= x <= high for x in s):
        raise InputError(f"{shape} size entries must be finite and in [{low:g}, {high:g}]{unit}, got {size!r}")
    T = _check_pose(np.eye(4) if T_palm_obj is None else T_palm_obj)
    mesh = None
    if shape == "box":
        geom = coal.Box(*s)
    elif shape == "cylinder":
        geom = coal.Cylinder(s[0], s[1])
    elif shape == "sphere":
        geom = coal.Sphere(s[0])
    else:
        if mesh_path is None:
            raise InputError("shape 'mesh' needs mesh_path")
        mesh, geom = _mesh_and_bvh(mesh_path, s * 3 if len(s) == 1 else s)
    if shape != "mesh":
        geom.computeLocalAABB()
    obj = GraspObject(shape, s, T, None if mesh_path is None else str(mesh_path), 0.0, mesh, geom)
    mass = DEFAULT_DENSITY_KG_M3 * obj.volume_m3 if mass_kg is None else float(mass_kg)
    if not (np.isfinite(mass) and MIN_MASS_KG <= mass <= MAX_MASS_KG):
        what = f"the default mass (volume x {DEFAULT_DENSITY_KG_M3:g} kg/m^3) is {mass:.3g} kg: give mass_kg; " \
            if mass_kg is None else ""
        raise InputError(f"{what}mass_kg must be in [{MIN_MASS_KG:g}, {MAX_MASS_KG:g}] kg, got {mass!r}")
    object.__setattr__(obj, "mass_kg", float(mass))
    object.__setattr__(obj, "mass_given", mass_kg is not None)
    return obj


def default_mass_kg(shape: str, size, mesh_path=None, relative_to=None) -> float:
    """The mass `make_object` gives an object without ``mass_kg``: volume x
    `DEFAULT_DENSITY_KG_M3` (the planner's mass, recorded in plans so the replay uses it).

    Args:
        shape, size, mesh_path: as for `make_object`.
        relative_to: a file whose folder a relative ``mesh_path`` is relative to.
    """
    if shape == "mesh" and mesh_path is not None and relative_to is not None and not Path(mesh_path).is_absolute():
        mesh_path = Path(relative_to).parent / mesh_path
    return make_object(shape, size, mesh_path=mesh_path).mass_kg
