"""Grasped objects: box, cylinder, sphere and triangle mesh, with coal geometry.

The object frame is at the object's centre (box/cylinder/sphere: the geometric centre;
mesh: the origin of the mesh file, scaled). Surface normals returned here point OUTWARD;
contact code flips them to get contact normals into the object.
"""

from __future__ import annotations

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
DEFAULT_DENSITY_KG_M3 = 500.0   # used when mass_kg is not given
#: Mesh limits (README "Hardening / plan integrity"): file size and triangle count.
MAX_MESH_BYTES = 50_000_000
MAX_MESH_TRIANGLES = 1_000_000


def _readonly(a) -> np.ndarray:
    a = np.array(a, dtype=float)
    a.flags.writeable = False
    return a


def load_mesh(path, scale=(1.0, 1.0, 1.0)) -> tuple[np.ndarray, np.ndarray]:
    """Read an OBJ or STL (ASCII or binary) triangle mesh.

    Returns:
        vertices (n, 3) scaled, triangles (m, 3) int vertex indices.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"mesh file not found: {path}")
    ext = path.suffix.lower()
    if ext not in (".obj", ".stl"):
        raise InputError(f"unsupported mesh format {ext!r} for {path}; use .obj or .stl")
    try:
        if path.stat().st_size > MAX_MESH_BYTES:
            raise InputError(f"mesh {path} is larger than {MAX_MESH_BYTES} bytes")
        raw = path.read_bytes()
    except OSError as err:
        raise InputError(f"cannot read mesh {path}: {err.strerror}") from err
    try:
        V, F = _parse_obj(raw) if ext == ".obj" else _parse_stl(raw)
    except (ValueError, IndexError, struct.error) as err:
        raise InputError(f"mesh {path} is malformed: {str(err).splitlines()[0][:80]}") from None
    if len(F) == 0:
        raise InputError(f"mesh {path} has no triangles")
    if len(F) > MAX_MESH_TRIANGLES:
        raise InputError(f"mesh {path} has {len(F)} triangles; at most {MAX_MESH_TRIANGLES}")
    if F.min() < 0 or F.max() >= len(V):
        raise InputError(f"mesh {path}: a face refers to a vertex that does not exist ({len(V)} vertices)")
    if not np.isfinite(V).all() or np.abs(V).max() > 1e6:
        raise InputError(f"mesh {path}: vertex coordinates must be finite and within 1e6")
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    if not (np.linalg.norm(np.cross(b - a, c - a), axis=1) > 0).any():
        raise InputError(f"mesh {path} has no triangle with a non-zero area")
    used = V[np.unique(F)]
    extent = float(np.ptp(used, axis=0).max())
    if np.linalg.matrix_rank(used - used.mean(axis=0), tol=1e-9 * max(extent, 1e-300)) < 3:
        raise InputError(f"mesh {path} is flat (all its vertices lie in one plane): an object needs a volume")
    return V * np.asarray(scale, dtype=float), F


def _parse_obj(raw: bytes) -> tuple[np.ndarray, np.ndarray]:
    verts, tris = [], []
    for line in raw.decode(errors="replace").splitlines():
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "v":
            if len(parts) < 4:
                raise ValueError("a vertex line needs 3 coordinates")
            verts.append([float(x) for x in parts[1:4]])
        elif parts[0] == "f":
            idx = [int(p.split("/")[0]) for p in parts[1:]]
            if len(idx) < 3 or 0 in idx:
                raise ValueError("a face needs at least 3 vertex indices (1-based)")
            idx = [i - 1 if i > 0 else len(verts) + i for i in idx]
            for k in range(1, len(idx) - 1):   # fan-triangulate polygons
                tris.append([idx[0], idx[k], idx[k + 1]])
            if len(tris) > MAX_MESH_TRIANGLES:
                raise ValueError(f"more than {MAX_MESH_TRIANGLES} triangles")
    return np.array(verts, dtype=float).reshape(-1, 3), np.array(tris, dtype=int).reshape(-1, 3)


def _parse_stl(raw: bytes) -> tuple[np.ndarray, np.ndarray]:
    if raw[:5].lower() == b"solid" and b"facet" in raw[:1000]:
        pts = [[float(x) for x in line.split()[1:4]] for line in raw.decode(errors="replace").splitlines()
               if line.strip().startswith("vertex")]
        if len(pts) % 3:
            raise ValueError("the vertex count is not a multiple of 3")
        tri_pts = np.array(pts, dtype=float).reshape(-1, 3, 3)
    else:
        if len(raw) < 84:
            raise ValueError(f"a binary STL has an 84-byte header, the file has {len(raw)} bytes")
        (n,) = struct.unpack("<I", raw[80:84])
        if len(raw) < 84 + 50 * n:
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
        optionally mesh, mass_kg), already validated (`planner.grasp.parse_object` checks a
        grasp file's, with the file and key in its errors).

        Args:
            data: the block; ``quat_xyzw`` a unit quaternion [x, y, z, w] (palm frame),
                ``position`` metres (palm frame); ``mass_kg`` None or absent: the default.
            base_dir: folder a relative ``mesh`` path is relative to (default: as given).
        """
        quat = tuple(float(v) for v in data["quat_xyzw"])
        T = _pose(data["position"], quat)
        mesh = data.get("mesh")
        if mesh is not None and base_dir is not None and not Path(mesh).is_absolute():
            mesh = str(Path(base_dir) / mesh)
        mass = data.get("mass_kg")
        obj = make_object(data["shape"], tuple(data["size"]), T, mesh_path=mesh, mass_kg=mass)
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


def make_object(shape: str, size, T_palm_obj=None, mesh_path=None, mass_kg=None) -> GraspObject:
    """Build a GraspObject and its coal geometry.

    Args:
        shape: "box", "cylinder", "sphere" or "mesh".
        size: see GraspObject.size (metres); every entry finite and > 0.
        T_palm_obj: (4, 4) pose in the palm frame (default identity).
        mesh_path: OBJ/STL file for shape "mesh".
        mass_kg: > 0, default volume x 500 kg/m^3.
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
    if not all(np.isfinite(x) and x > 0 for x in s):
        raise InputError(f"{shape} size entries must be finite and > 0 (metres), got {size!r}")
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
    if mass_kg is None:
        mass = DEFAULT_DENSITY_KG_M3 * obj.volume_m3
    else:
        mass = float(mass_kg)
        if not (np.isfinite(mass) and mass > 0):
            raise InputError(f"mass_kg must be > 0, got {mass_kg!r}")
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
