"""Object inputs (issue 35): meshes past the limits are refused before they are read, a
malformed mesh is named by file and line without its content, every object-block reader
(grasp files, plan files, synth object files, the API) uses one validator with the same
ranges and quaternion rule, and no per-mesh structure grows with the square of the
triangle count. Each class of bad input: exit 2, one line naming the file, the key path
and the valid range, no traceback, no content of the file echoed."""

import json
import math
import struct
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from planner.cli import main
from planner.errors import SpecError
from planner.objects import (MAX_MESH_BYTES, MAX_MESH_LINES, MAX_MESH_TRIANGLES, QUAT_NORM_TOL, GraspObject,
                             convex_hull_vertices, load_mesh)

ROOT = Path(__file__).resolve().parents[1]
GRASP = ROOT / "grasps/icub/box_ir2m.yaml"
SECRET = "hunter2-secret"
FINGERS = ["--fingers", "thumb,index", "-n", "1"]


def _run(capsys, *argv) -> tuple[int, list[str]]:
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    assert "Traceback" not in out.err + out.out
    return code, out.err.strip().splitlines()


def _sphere(n_tri: int, r: float = 0.02) -> np.ndarray:
    """(m, 3, 3) triangles of a UV sphere, m close to n_tri (poles: slivers and zero-area triangles)."""
    k = int(np.sqrt(n_tri / 2))
    m = n_tri // (2 * k)
    th, ph = np.meshgrid(np.linspace(0, np.pi, k + 1), np.linspace(0, 2 * np.pi, m + 1), indexing="ij")
    V = np.stack([r * np.sin(th) * np.cos(ph), r * np.sin(th) * np.sin(ph), r * np.cos(th)], -1)
    a, b, c, d = V[:-1, :-1], V[1:, :-1], V[1:, 1:], V[:-1, 1:]
    return np.concatenate([np.stack([a, b, c], -2).reshape(-1, 3, 3), np.stack([a, c, d], -2).reshape(-1, 3, 3)])


def _binary_stl(path: Path, tris: np.ndarray, announce: int | None = None) -> Path:
    rec = np.zeros(len(tris), dtype=np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")]))
    rec["v"] = tris
    path.write_bytes(b"\0" * 80 + struct.pack("<I", len(tris) if announce is None else announce) + rec.tobytes())
    return path


def _synth(capsys, tmp_path, object_text: str, name: str = "ball.yaml"):
    (tmp_path / name).write_text(object_text)
    code, err = _run(capsys, "synth", "icub_right", tmp_path / name, *FINGERS, "-o", tmp_path / "out")
    assert not (tmp_path / "out").exists()
    return code, err


def _one_line(code, err, *words):
    assert code == 2 and len(err) == 1, err
    assert all(w in err[0] for w in words), (words, err)
    assert SECRET not in err[0]


# ------------------------------------------------------------------ meshes past the limits


def test_a_mesh_past_the_limits_is_refused_before_it_is_read(tmp_path, capsys):
    """A 999k-triangle binary STL (the reproducer), a file past the byte limit (sparse) and
    a text mesh past the line limit: exit 2, one line naming the object file, its mesh key
    and the limit. The grasp file's reader says the same at object.mesh."""
    _binary_stl(tmp_path / "big.stl", _sphere(999_000))
    with open(tmp_path / "huge.obj", "wb") as fh:
        fh.truncate(MAX_MESH_BYTES + 1)
    (tmp_path / "lines.obj").write_text("v 0 0 0\n" * (MAX_MESH_LINES + 1))
    limits = {"big.stl": str(MAX_MESH_TRIANGLES), "huge.obj": str(MAX_MESH_BYTES), "lines.obj": str(MAX_MESH_LINES)}
    for mesh, limit in limits.items():
        code, err = _synth(capsys, tmp_path, f"shape: mesh\nsize: [1]\nmesh: {mesh}\n")
        _one_line(code, err, "ball.yaml: mesh:", mesh, limit)
    grasp = yaml.safe_load(GRASP.read_text())
    grasp["object"] = {"shape": "mesh", "size": [1], "mesh": "big.stl", "position": [0.03, 0, 0.03],
                       "quat_xyzw": [0, 0, 0, 1]}
    (tmp_path / "g.yaml").write_text(yaml.safe_dump(grasp))
    code, err = _run(capsys, "check", tmp_path / "g.yaml")
    _one_line(code, err, "g.yaml: object.mesh:", "big.stl", str(MAX_MESH_TRIANGLES))


def test_a_malformed_mesh_is_named_by_file_and_line_without_its_content(tmp_path, capsys):
    """OBJ and ASCII STL lines that are not numbers, a binary STL shorter than its header
    says: exit 2, one line naming the object file, the mesh and the line, not the text."""
    (tmp_path / "v.obj").write_text(f"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 {SECRET}\nf 1 2 3\n")
    (tmp_path / "f.obj").write_text(f"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 {SECRET}\n")
    (tmp_path / "a.stl").write_text(f"solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 {SECRET} 0\n"
                                    "vertex 0 1 0\nendloop\nendfacet\nendsolid x\n")
    _binary_stl(tmp_path / "short.stl", _sphere(200), announce=5000)
    lines = {"v.obj": "line 4", "f.obj": "line 5", "a.stl": "line 5", "short.stl": "announces 5000 triangles"}
    for mesh, where in lines.items():
        code, err = _synth(capsys, tmp_path, f"shape: mesh\nsize: [1]\nmesh: {mesh}\n")
        _one_line(code, err, "ball.yaml: mesh:", mesh, "malformed", where)


# ------------------------------------------------------------------ ranges of an object block


@pytest.mark.parametrize("text, key, valid", [
    ("shape: sphere\nsize: [0.02]\nmass_kg: 1.0e+308\n", "mass_kg", "[1e-06, 1000] kg"),
    ("shape: sphere\nsize: [0.02]\nmass_kg: 0\n", "mass_kg", "[1e-06, 1000] kg"),
    ("shape: sphere\nsize: [1.0e-9]\n", "size[0]", "[0.0001, 10] m"),
    ("shape: box\nsize: [0.02, 0.03, .inf]\n", "size[2]", "[0.0001, 10] m"),
    ("shape: cylinder\nsize: [0.02, 100]\n", "size[1]", "[0.0001, 10] m"),
    ("shape: sphere\nsize: [0.02]\nposition: [0, 1.0e+6, 0]\n", "position[1]", "[-10, 10] m"),
    ("shape: sphere\nsize: [0.02]\nposition: [0, 0, 0]\nquat_xyzw: [0, 0, 0, 0]\n", "quat_xyzw", "norm within 0.001"),
    ("shape: sphere\nsize: [0.02]\nposition: [0, 0, 0]\nquat_xyzw: [0, 0, 0, .nan]\n", "quat_xyzw[3]", "finite"),
    ("object: {shape: sphere, size: [0.02]}\nfriction: {mu: -1, gamma: 0.004}\n", "friction.mu", "(0, 100]"),
    ("object: {shape: sphere, size: [0.02]}\nfriction: {mu: 0.9, gamma: 5}\n", "friction.gamma", "[0, 1] m"),
    ("object: {shape: sphere, size: [0.02]}\nfriction: {mu: 0.9, gamma: 0.004, edges: 1000000000}\n",
     "friction.edges", "[3, 256]"),
    ("object: {shape: sphere, size: [0.02], mass_kg: -3}\n", "object.mass_kg", "[1e-06, 1000] kg"),
])
def test_synth_object_file_values_out_of_range_name_file_key_and_range(tmp_path, capsys, text, key, valid):
    code, err = _synth(capsys, tmp_path, text)
    _one_line(code, err, f"ball.yaml: {key}: ", valid)


def test_grasp_and_plan_files_and_the_api_share_the_ranges(tmp_path, capsys):
    """The same bad mass in a grasp file, a plan's data and the API's object block: each
    refused at object.mass_kg with the same range."""
    sys.path.insert(0, str(Path(__file__).parent))
    from test_plan import tiny_plan

    from planner.api import synth
    from planner.plan import plan_from_data

    grasp = yaml.safe_load(GRASP.read_text())
    grasp["object"]["mass_kg"] = 1e308
    (tmp_path / "g.yaml").write_text(yaml.safe_dump(grasp))
    code, err = _run(capsys, "check", tmp_path / "g.yaml")
    _one_line(code, err, "g.yaml: object.mass_kg: ", "[1e-06, 1000] kg")
    plan = tiny_plan().to_dict()
    plan["object"]["mass_kg"] = 1e308
    with pytest.raises(SpecError, match=r"\[1e-06, 1000\] kg") as info:
        plan_from_data(plan, "p.yaml")
    assert info.value.key == "object.mass_kg"
    with pytest.raises(SpecError, match=r"\[1e-06, 1000\] kg") as info:
        synth("icub_right", {"shape": "sphere", "size": [0.02], "mass_kg": 1e308}, "thumb,index")
    assert info.value.key == "object.mass_kg" and "<object block>" in str(info.value)


# ------------------------------------------------------------------ one quaternion rule


def _quat_readers(tmp_path, quat):
    """The object's quaternion as each reader of an object block returns it (or its SpecError)."""
    sys.path.insert(0, str(Path(__file__).parent))
    from test_plan import tiny_plan

    from planner.grasp import load_grasp
    from planner.plan import plan_from_data
    from planner.synthesis import load_object_file

    grasp = yaml.safe_load(GRASP.read_text())
    grasp["object"]["quat_xyzw"] = list(quat)
    (tmp_path / "g.yaml").write_text(yaml.safe_dump(grasp))
    (tmp_path / "o.yaml").write_text(yaml.safe_dump({k: grasp["object"][k] for k in ("shape", "size", "position",
                                                                                      "quat_xyzw")}))
    plan = tiny_plan().to_dict()
    plan["object"]["quat_xyzw"] = list(quat)
    readers = {
        "grasp": lambda: load_grasp(tmp_path / "g.yaml").object,
        "synth": lambda: load_object_file(tmp_path / "o.yaml")[0],
        "plan": lambda: plan_from_data(plan, "p.yaml").object,
        "api": lambda: GraspObject.from_data({**grasp["object"], "mesh": None}),
    }
    out = {}
    for name, read in readers.items():
        try:
            out[name] = read().quat_xyzw
        except SpecError as err:
            out[name] = err
    return out


def test_every_reader_normalises_within_the_tolerance_and_refuses_beyond(tmp_path):
    """A quaternion 5e-4 off unit is normalised by all four readers, 2e-3 off refused by all
    at quat_xyzw; a unit one (to rounding) is kept bit for bit."""
    half = 0.5 * QUAT_NORM_TOL
    near = _quat_readers(tmp_path, [0.0, 0.0, 0.0, 1.0 + half])
    assert all(q == (0.0, 0.0, 0.0, 1.0) for q in near.values()), near
    far = _quat_readers(tmp_path, [0.0, 0.0, 0.0, 1.0 + 2 * QUAT_NORM_TOL])
    assert all(isinstance(e, SpecError) and e.key.endswith("quat_xyzw") and "norm within 0.001" in e.message
               for e in far.values()), far
    unit = [0.0, math.sqrt(0.5), 0.0, math.sqrt(0.5)]
    kept = _quat_readers(tmp_path, unit)
    assert all(q == tuple(unit) for q in kept.values()), kept


def test_a_written_plans_object_reads_back_bit_for_bit():
    """The recorded object of the committed schema 2 plan, and of a plan made from a grasp
    whose quaternion the grasp reader normalised, read back unchanged."""
    from planner.grasp import load_grasp
    from planner.plan import plan_from_data

    path = ROOT / "tests/data/plans/schema2_cylinder_execution.json"
    data = json.loads(path.read_text())
    assert list(plan_from_data(data, path).object.quat_xyzw) == data["object"]["quat_xyzw"]
    obj = load_grasp(ROOT / "grasps/icub/pen_palmar_pinch.yaml").object
    again = GraspObject.from_data(obj.to_data())
    assert again.quat_xyzw == obj.quat_xyzw and again.to_data() == obj.to_data()


# ------------------------------------------------------------------ no quadratic structure


@pytest.mark.parametrize("kind", ["convex", "cross", "dented"])
def test_convexity_test_equals_the_all_pairs_one(kind):
    """`convex_hull_vertices` (k-d trees of hull facets) decides exactly as comparing every
    vertex and face centroid with every hull plane (the former O(n^2) array)."""
    from scipy.spatial import ConvexHull

    tris = _sphere(2000)
    V, inv = np.unique(tris.reshape(-1, 3), axis=0, return_inverse=True)
    F = inv.reshape(-1, 3)
    if kind == "cross":
        V, F = load_mesh(ROOT / "grasps/meshes/cross_prism.obj")
    elif kind == "dented":
        V = V.copy()
        V[np.argmin(np.abs(V[:, 2]))] *= 0.99  # one vertex 0.2 mm in
    hull = ConvexHull(V)
    probes = np.concatenate([V, V[F].mean(axis=1)])
    gap = -(probes @ hull.equations[:, :3].T + hull.equations[:, 3]).max(axis=1)
    want = None if gap.max() > 1e-4 else hull.vertices
    got = convex_hull_vertices(V, F, 1e-4)
    assert (got is None) == (want is None) and (got is None or np.array_equal(got, want)), kind


def test_a_mesh_at_the_limit_builds_and_answers_without_nan(tmp_path):
    """A float32 sphere of MAX_MESH_TRIANGLES / 4 triangles with slivers and zero-area
    triangles at its poles: its signed-distance geometry is built (the all-pairs convexity
    array would hold ~10^10 numbers) and surface queries near the poles are finite."""
    from planner.objects import make_object
    from planner.signed_distance import signed_distance_geometry

    path = _binary_stl(tmp_path / "s.stl", _sphere(MAX_MESH_TRIANGLES // 4))
    obj = make_object("mesh", (1.0,), mesh_path=path, mass_kg=0.05)
    assert signed_distance_geometry(obj) is not None
    rng = np.random.default_rng(0)
    for p in rng.normal(scale=2e-4, size=(200, 3)) + [0.0, 0.0, 0.02]:
        ps, n, d = obj.closest_surface(p)
        assert np.isfinite(ps).all() and np.isfinite(n).all() and math.isfinite(d)
