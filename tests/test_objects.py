"""Objects: surface samples lie on the surface with unit outward normals, area-uniform;
closest_surface is signed; bad sizes are rejected."""

from __future__ import annotations

import numpy as np
import pytest

from planner.errors import InputError, UnknownNameError
from planner.objects import make_object

CUBE_OBJ = """v -1 -1 -1\nv 1 -1 -1\nv 1 1 -1\nv -1 1 -1\nv -1 -1 1\nv 1 -1 1\nv 1 1 1\nv -1 1 1
f 1 3 2\nf 1 4 3\nf 5 6 7\nf 5 7 8\nf 1 2 6\nf 1 6 5\nf 2 3 7\nf 2 7 6\nf 3 4 8\nf 3 8 7\nf 4 1 5\nf 4 5 8
"""


def _write_stl(path, obj_text):
    V = np.array([[float(x) for x in l.split()[1:]] for l in obj_text.splitlines() if l.startswith("v ")])
    F = [[int(x) - 1 for x in l.split()[1:]] for l in obj_text.splitlines() if l.startswith("f ")]
    lines = ["solid cube"]
    for f in F:
        lines += ["facet normal 0 0 0", "outer loop"] + [f"vertex {V[i][0]} {V[i][1]} {V[i][2]}" for i in f]
        lines += ["endloop", "endfacet"]
    path.write_text("\n".join(lines + ["endsolid cube"]))


@pytest.fixture(params=["box", "cylinder", "sphere", "mesh_obj", "mesh_stl"])
def obj(request, tmp_path):
    kind = request.param
    if kind == "box":
        return make_object("box", (0.04, 0.06, 0.08))
    if kind == "cylinder":
        return make_object("cylinder", (0.02, 0.1))
    if kind == "sphere":
        return make_object("sphere", (0.03,))
    path = tmp_path / ("cube.obj" if kind == "mesh_obj" else "cube.stl")
    if kind == "mesh_obj":
        path.write_text(CUBE_OBJ)
    else:
        _write_stl(path, CUBE_OBJ)
    return make_object("mesh", (0.02,), mesh_path=path)


def test_samples_on_surface_with_outward_unit_normals(obj):
    """Samples are on the surface (distance 0), normals are unit, and stepping along them
    leaves the object while stepping against them enters it."""
    p, n = obj.sample_surface(400, np.random.default_rng(0))
    assert p.shape == n.shape == (400, 3)
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0)
    for x, m in zip(p[:100], n[:100]):
        assert abs(obj.closest_surface(x)[2]) < 1e-9
        assert obj.closest_surface(x + 1e-4 * m)[2] > 0
        assert obj.closest_surface(x - 1e-4 * m)[2] < 0


def test_closest_surface_is_signed_and_consistent(obj):
    """For random points, |signed distance| is the distance to the returned surface point, which is
    itself on the surface; the sign is negative inside."""
    rng = np.random.default_rng(1)
    for x in rng.uniform(-0.06, 0.06, size=(200, 3)):
        ps, n, d = obj.closest_surface(x)
        assert abs(abs(d) - np.linalg.norm(x - ps)) < 1e-9
        assert abs(obj.closest_surface(ps)[2]) < 1e-9
        assert np.isclose(np.linalg.norm(n), 1.0)
    assert obj.closest_surface(np.array([1e-3, 2e-3, -3e-3]))[2] < 0


def test_box_sampling_is_uniform_by_area():
    """On a flat box, the share of samples per face pair matches the share of area."""
    box = make_object("box", (0.01, 0.04, 0.1))
    p, n = box.sample_surface(20000, np.random.default_rng(3))
    share = np.abs(n).sum(axis=0) / len(n)
    area = np.array([0.04 * 0.1, 0.01 * 0.1, 0.01 * 0.04])
    assert np.allclose(share, area / area.sum(), atol=0.01)


def test_cylinder_sampling_is_uniform_by_area():
    """Cylinder caps get the cap share of samples and the side samples are uniform in height."""
    cyl = make_object("cylinder", (0.02, 0.1))
    p, n = cyl.sample_surface(20000, np.random.default_rng(4))
    caps = np.abs(n[:, 2]) > 0.5
    cap_share = 2 * np.pi * 0.02**2 / (2 * np.pi * 0.02**2 + 2 * np.pi * 0.02 * 0.1)
    assert abs(caps.mean() - cap_share) < 0.01
    assert abs(np.mean(np.abs(p[~caps, 2]) < 0.025) - 0.5) < 0.02


@pytest.mark.parametrize("shape, size", [("box", (0.1, 0.0, 0.1)), ("box", (0.1, 0.1)),
                                         ("cylinder", (-0.01, 0.1)), ("sphere", (np.inf,)),
                                         ("sphere", (0.0,)), ("box", ("a", 1, 1))])
def test_bad_sizes_rejected(shape, size):
    """Non-positive, non-finite or wrongly counted sizes raise InputError."""
    with pytest.raises(InputError):
        make_object(shape, size)


def test_bad_shape_pose_and_mass_rejected():
    """Unknown shapes list the valid ones; non-rigid poses and non-positive masses are refused."""
    with pytest.raises(UnknownNameError, match="box, cylinder, mesh, sphere"):
        make_object("cone", (1.0,))
    with pytest.raises(InputError):
        make_object("box", (0.1, 0.1, 0.1), T_palm_obj=2 * np.eye(4))
    with pytest.raises(InputError):
        make_object("box", (0.1, 0.1, 0.1), mass_kg=0.0)
    with pytest.raises(InputError):
        make_object("mesh", (1.0,), mesh_path="/nonexistent.obj")


def test_pose_is_read_only_and_mass_defaults_from_volume():
    """The stored pose cannot be modified and the default mass is volume x 500 kg/m^3."""
    box = make_object("box", (0.1, 0.1, 0.1))
    with pytest.raises(ValueError):
        box.T_palm_obj[0, 3] = 1.0
    assert np.isclose(box.mass_kg, 0.5)


def test_closest_surface_on_edges_gives_unit_normals():
    """Points exactly on a box edge/corner or a cylinder rim get a finite unit normal, distance 0."""
    from planner.objects import make_object

    box = make_object("box", (0.06, 0.05, 0.03), np.eye(4))
    cyl = make_object("cylinder", (0.01, 0.1), np.eye(4))
    for obj, pts in ((box, [(0.03, 0.025, 0.0), (0.03, 0.025, 0.015), (0.03 + 1e-17, 0.0, 0.015)]),
                     (cyl, [(0.01, 0.0, 0.05), (0.0, 0.01 + 1e-18, -0.05)])):
        for pt in pts:
            ps, n, d = obj.closest_surface(np.array(pt))
            assert np.all(np.isfinite(n)) and abs(np.linalg.norm(n) - 1) < 1e-12
            assert abs(d) < 1e-9


def _uv_sphere(nu: int, nv: int, r: float):
    th = np.linspace(0, np.pi, nv + 1)[1:-1]
    ph = np.linspace(0, 2 * np.pi, nu, endpoint=False)
    V = [[0, 0, r]] + [[r * np.sin(t) * np.cos(p), r * np.sin(t) * np.sin(p), r * np.cos(t)] for t in th for p in ph]
    V.append([0, 0, -r])
    F = [[0, 1 + j, 1 + (j + 1) % nu] for j in range(nu)]
    for i in range(nv - 2):
        for j in range(nu):
            a, b = 1 + i * nu + j, 1 + i * nu + (j + 1) % nu
            F += [[a, a + nu, b + nu], [a, b + nu, b]]
    base, last = 1 + (nv - 2) * nu, len(V) - 1
    F += [[last, base + (j + 1) % nu, base + j] for j in range(nu)]
    return np.array(V), np.array(F)


@pytest.mark.parametrize("flip", [False, True], ids=["outward", "inward-wound"])
def test_mesh_closest_query_equals_brute_force(tmp_path, flip):
    """The k-d tree query returns exactly the brute-force nearest triangle point (distance and
    point), and the inside/outside sign equals the ray-parity test, for a finely tessellated
    sphere (thousands of triangles) wound either way; the sphere's own distance agrees to the
    tessellation error."""
    from planner.objects import _closest_on_triangles, _inside_mesh

    V, F = _uv_sphere(48, 32, 1.0)
    if flip:
        F = F[:, ::-1]
    path = tmp_path / "ball.obj"
    path.write_text("".join(f"v {x} {y} {z}\n" for x, y, z in V) + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in F))
    obj = make_object("mesh", (0.03,), mesh_path=path)
    a, b, c = (0.03 * V[F[:, i]] for i in range(3))
    rng = np.random.default_rng(3)
    pts = np.vstack([rng.normal(size=(120, 3)) * 0.02, rng.normal(size=(60, 3)) * 0.002 + 0.03 * np.eye(3)[0]])
    for x in pts:
        ps, n, d = obj.closest_surface(x)
        cp = _closest_on_triangles(x, a, b, c)
        d2 = np.einsum("ij,ij->i", cp - x, cp - x)
        assert abs(abs(d) - np.sqrt(d2.min())) < 1e-12
        assert np.allclose(ps, cp[np.argmin(d2)], atol=1e-12)
        assert (d < 0) == _inside_mesh(x, a, b, c)
        assert abs(d - (np.linalg.norm(x) - 0.03)) < 0.03 * (1 - np.cos(np.pi / 32)) + 1e-9


def test_mesh_is_built_once_per_file_and_rebuilt_when_it_changes(tmp_path):
    """Objects made from one mesh file share the built geometry (a synthesis makes one per
    sampled pose); a file changed on disk is read again."""
    path = tmp_path / "cube.obj"
    path.write_text(CUBE_OBJ)
    o1, o2 = make_object("mesh", (0.02,), mesh_path=path), make_object("mesh", (0.02,), mesh_path=path)
    assert o1.geometry is o2.geometry
    assert make_object("mesh", (0.03,), mesh_path=path).geometry is not o1.geometry
    path.write_text(CUBE_OBJ.replace("v 1 1 1", "v 2 2 2"))
    import os
    os.utime(path, ns=(1, 1))
    o3 = make_object("mesh", (0.02,), mesh_path=path)
    assert o3.geometry is not o1.geometry
    assert np.allclose(o3.extents, [0.06, 0.06, 0.06])
