"""The coal shapes of signed distances: poses as coal transforms and back, bounding
spheres, convex hulls, and an object's signed-distance geometry.

coal's GJK/EPA gives exact signed distances (penetration depth) between convex shapes; a
mesh (a ``BVHModel``) answers per triangle. `signed_distance_geometry` therefore stands an
object's convex mesh in by its hull, and `convex_hull` builds the hulls (also those of the
hand's link meshes, `planner.hand`). The collision layer (`planner.collision`) poses its
shapes with `transform` and culls with `bounding_sphere`. Signed distances are negative
for penetration.
"""

from __future__ import annotations

import coal
import numpy as np

MESH_CONVEX_TOL_M = 1e-4
"""A mesh whose vertices and face centroids all lie within this of its convex hull's
boundary counts as convex: its hull stands for it in signed distances, off by at most
this (a tenth of the touch tolerance). Meshes of smooth convex shapes are rarely convex
to the micrometre: the non-planar quads of grasps/meshes/rounded_box.obj fold inward by
up to 26 um."""

_SDF_GEOMETRY_CACHE: dict[int, tuple] = {}  # id(geometry) -> (geometry, its signed-distance geometry)


def transform(T: np.ndarray) -> coal.Transform3s:
    """A (4, 4) pose as a coal transform."""
    return coal.Transform3s(np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3]))


def transform_matrix(tf: coal.Transform3s) -> np.ndarray:
    """A coal transform as a (4, 4) pose."""
    T = np.eye(4)
    T[:3, :3] = tf.getRotation()
    T[:3, 3] = tf.getTranslation()
    return T


def object_transform(obj) -> coal.Transform3s:
    """The object's pose in the palm frame as a coal transform."""
    return transform(np.asarray(obj.T_palm_obj))


def bounding_sphere(geometry) -> tuple[np.ndarray, float]:
    """(centre (3,) in the geometry frame, radius) of a coal geometry's local AABB."""
    geometry.computeLocalAABB()
    return np.array(geometry.aabb_center, dtype=float), float(geometry.aabb_radius)


def signed_distance_geometry(obj):
    """The coal geometry whose signed distance to a finger link is the object's.

    coal's collision query refuses a negative security margin (a tolerated penetration)
    for a ``BVHModel`` ("Negative security margin are not handled yet for BVHModel"), and
    its distance query on a mesh is the smallest distance to any one triangle, a thin
    plate: when a link sinks into the solid it measures how far the link must move to
    clear one triangle, often sideways off it, so it reports a fraction of the depth (a
    capsule 2.6 mm deep into a 5 mm gridded box mesh reads 0.7 mm). Primitives
    (box, cylinder, sphere) are convex and coal's GJK/EPA gives their exact signed
    distance: they are returned as they are. A mesh is replaced by its convex hull (a
    ``coal.Convex``, where GJK/EPA is exact too) when the mesh is convex, i.e. the hull is
    the object (every vertex and face centroid on the hull's boundary within
    ``MESH_CONVEX_TOL_M``). A non-convex mesh keeps its triangles: its hull would report
    a finger resting in a concavity as deep inside, so the per-triangle distance (the
    measure the contacts and the closing procedure use for meshes) is kept: exact
    while the link is outside, it can under-report the depth once a link sinks in. A link
    wholly inside a mesh touches no triangle and reads as clear (as in coal's collision
    query with a positive margin); paths are checked every ``resolution_rad`` from outside,
    so they cannot get there without crossing the surface.
    """
    geometry = obj.geometry
    if not isinstance(geometry, coal.BVHModelBase):
        return geometry
    cached = _SDF_GEOMETRY_CACHE.get(id(geometry))
    if cached is None:  # the entry holds the geometry, so its id is not reused meanwhile
        if len(_SDF_GEOMETRY_CACHE) >= 8:
            _SDF_GEOMETRY_CACHE.pop(next(iter(_SDF_GEOMETRY_CACHE)))
        hull = obj.convex_hull_points(MESH_CONVEX_TOL_M)  # sub-quadratic: `planner.objects.convex_hull_vertices`
        try:
            sdf = geometry if hull is None else convex_hull(hull)
        except RuntimeError:  # coal holds at most 254 neighbours per hull vertex (a fine mesh's pole): the triangles
            sdf = geometry
        cached = _SDF_GEOMETRY_CACHE[id(geometry)] = (geometry, sdf)
    return cached[1]


def convex_hull(points) -> "coal.ConvexBase":
    """The convex hull of (n, 3) points as a coal convex shape (its local AABB computed)."""
    pts = coal.StdVec_Vec3s()
    for v in np.asarray(points, dtype=float):
        pts.append(np.ascontiguousarray(v))
    convex = coal.Convex.convexHull(pts, False, "Qt")
    convex.computeLocalAABB()
    return convex
