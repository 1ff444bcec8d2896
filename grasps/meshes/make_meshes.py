"""Write the small OBJ meshes of this folder (metres, object frame at the centre).

    python grasps/meshes/make_meshes.py        # rewrites the .obj files beside this script

- ``rounded_box.obj``: a 35 x 80 x 30 mm box (the size of the library's box grasps) with
  edges and corners rounded to 5 mm (30 deg arcs), 2120 triangles. Convex to within 26 um
  (the curved grid's quads are split along a fixed diagonal and fold in slightly); its
  chords (diagonals at the corners) lie at most 0.26 mm inside the ideal rounded box.
- ``box_35x80x30.obj``: the same box with sharp edges, every face split into a grid of
  about 5 mm (the mesh twin of the primitive box, for tests comparing the two).
- ``ellipsoid.obj``: a subdivided icosahedron scaled to semi-axes 20 x 30 x 15 mm. Convex.
- ``cross_prism.obj``: a plus-shaped prism (50 x 50 mm cross, 16 mm arms, 20 mm thick).
  Not convex: four inner corners.

Every mesh is closed, with triangles wound counter-clockwise seen from outside (outward
normals by the right-hand rule), as ``planner.objects`` expects. Deterministic: the files
are byte-identical on every run.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def _grid(lo: float, hi: float, step: float) -> np.ndarray:
    n = max(1, int(np.ceil((hi - lo) / step - 1e-9)))
    return np.linspace(lo, hi, n + 1)


def _axis_coords(h: float, r: float, step: float, arc_steps: int) -> np.ndarray:
    """Coordinates along one axis of a box of half-extent ``h``: a grid over the flat part
    and ``arc_steps`` points per rounded band (spaced by angle, so the arc is even)."""
    flat = _grid(-(h - r), h - r, step) if h - r > 0 else np.array([0.0])
    if r <= 0:
        return flat
    band = (h - r) + r * np.sin(np.linspace(0.0, np.pi / 2, arc_steps + 1)[1:])
    return np.concatenate([-band[::-1], flat, band])


def _merge(vertices: list, triangles: list) -> tuple[np.ndarray, np.ndarray]:
    """Weld equal vertices (rounded to 1e-9 m) and drop degenerate triangles."""
    V = np.array(vertices, dtype=float)
    key = np.round(V / 1e-9).astype(np.int64)
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first)  # keep the order of first appearance
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    F = rank[np.asarray(inverse).reshape(-1)][np.array(triangles, dtype=np.int64)]
    F = F[(F[:, 0] != F[:, 1]) & (F[:, 1] != F[:, 2]) & (F[:, 0] != F[:, 2])]
    return V[first[order]], F


def rounded_box(extents, radius: float, step: float = 0.005, arc_steps: int = 3):
    """Closed mesh of a box with full ``extents`` whose edges are rounded by ``radius``.

    A box of the given extents is gridded face by face (finer in the rounded bands), then
    every vertex within ``radius`` of an edge is moved onto the rounding: the point of the
    inner box (extents - 2 radius) nearest to it plus ``radius`` along the offset.
    """
    h = np.asarray(extents, dtype=float) / 2.0
    r = float(radius)
    coords = [_axis_coords(h[i], r, step, arc_steps) for i in range(3)]
    vertices: list = []
    triangles: list = []
    for axis in range(3):
        u, v = (axis + 1) % 3, (axis + 2) % 3  # (u, v, axis) is right-handed
        for sign in (1.0, -1.0):
            cu, cv = coords[u], coords[v]
            base = len(vertices)
            for a in cu:
                for b in cv:
                    p = np.zeros(3)
                    p[axis], p[u], p[v] = sign * h[axis], a, b
                    vertices.append(p)
            nv = len(cv)
            for i in range(len(cu) - 1):
                for j in range(nv - 1):
                    k00, k01 = base + i * nv + j, base + i * nv + j + 1
                    k10, k11 = base + (i + 1) * nv + j, base + (i + 1) * nv + j + 1
                    if sign > 0:  # u x v = +axis: counter-clockwise seen from outside
                        triangles += [[k00, k10, k11], [k00, k11, k01]]
                    else:
                        triangles += [[k00, k11, k10], [k00, k01, k11]]
    V, F = _merge(vertices, triangles)
    if r > 0:
        inner = np.clip(V, -(h - r), h - r)
        off = V - inner
        V = inner + r * off / np.linalg.norm(off, axis=1, keepdims=True)
    return V, F


def icosphere(subdivisions: int):
    """Unit sphere from an icosahedron whose triangles are split in four ``subdivisions`` times."""
    t = (1.0 + 5.0**0.5) / 2.0
    V = [[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t],
         [0, -1, -t], [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]]
    F = [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
         [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8],
         [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]]
    V = [np.array(v, dtype=float) / np.linalg.norm(v) for v in V]
    for _ in range(subdivisions):
        midpoint: dict = {}

        def mid(i, j):
            key = (min(i, j), max(i, j))
            if key not in midpoint:
                m = V[i] + V[j]
                V.append(m / np.linalg.norm(m))
                midpoint[key] = len(V) - 1
            return midpoint[key]

        new = []
        for a, b, c in F:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            new += [[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]
        F = new
    return np.array(V), np.array(F, dtype=np.int64)


def ellipsoid(semi_axes, subdivisions: int = 3):
    V, F = icosphere(subdivisions)
    return V * np.asarray(semi_axes, dtype=float), F


def cross_prism(width: float, arm: float, thickness: float):
    """Prism of a plus-shaped section (``width`` across, arms ``arm`` wide) along z.

    The section is star-shaped about its centre, so each cap is a fan from a centre vertex.
    """
    w, a = width / 2.0, arm / 2.0
    outline = [(w, -a), (w, a), (a, a), (a, w), (-a, w), (-a, a), (-w, a), (-w, -a),
               (-a, -a), (-a, -w), (a, -w), (a, -a)]  # counter-clockwise seen from +z
    n = len(outline)
    z = thickness / 2.0
    V = [[x, y, z] for x, y in outline] + [[x, y, -z] for x, y in outline] + [[0, 0, z], [0, 0, -z]]
    top, bottom = 2 * n, 2 * n + 1
    F = []
    for i in range(n):
        j = (i + 1) % n
        F += [[top, i, j], [bottom, n + j, n + i]]           # caps
        F += [[i, n + i, n + j], [i, n + j, j]]              # side quad, outward
    return np.array(V, dtype=float), np.array(F, dtype=np.int64)


def write_obj(path: Path, V: np.ndarray, F: np.ndarray, comment: str) -> None:
    lines = [f"# {comment}", "# written by grasps/meshes/make_meshes.py; metres, object frame at the centre"]
    lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in V]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in F]
    path.write_text("\n".join(lines) + "\n")


def check_closed_outward(V: np.ndarray, F: np.ndarray) -> None:
    """Every edge shared by exactly two triangles in opposite directions; positive volume."""
    edges = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    directed = {tuple(e) for e in edges.tolist()}
    if len(directed) != len(edges) or any((b, a) not in directed for a, b in directed):
        raise ValueError("mesh is not closed and consistently wound")
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    if np.einsum("ij,ij->i", a, np.cross(b, c)).sum() <= 0:
        raise ValueError("mesh normals point inward")


MESHES = {
    "rounded_box.obj": (lambda: rounded_box((0.035, 0.08, 0.03), 0.005),
                        "box 35 x 80 x 30 mm, edges rounded to 5 mm"),
    "box_35x80x30.obj": (lambda: rounded_box((0.035, 0.08, 0.03), 0.0),
                         "box 35 x 80 x 30 mm, faces gridded at about 5 mm"),
    "ellipsoid.obj": (lambda: ellipsoid((0.02, 0.03, 0.015)), "ellipsoid, semi-axes 20 x 30 x 15 mm"),
    "cross_prism.obj": (lambda: cross_prism(0.05, 0.016, 0.02),
                        "plus-shaped prism 50 x 50 mm, arms 16 mm, 20 mm thick (not convex)"),
}


def main() -> None:
    for name, (make, comment) in MESHES.items():
        V, F = make()
        check_closed_outward(V, F)
        write_obj(HERE / name, V, F, comment)
        print(f"{name}: {len(V)} vertices, {len(F)} triangles")


if __name__ == "__main__":
    main()
