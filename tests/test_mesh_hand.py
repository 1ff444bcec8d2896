"""A hand whose links collide through meshes (STL/OBJ): loaded as convex hulls, planned with
OMPL finger paths and replayed, with no traceback (coal refuses negative margins on a BVH)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

def cylinder_obj(r, l, n=24):
    a = 2 * np.pi * np.arange(n) / n
    top = np.c_[r * np.cos(a), r * np.sin(a), np.full(n, l / 2)]
    bot = np.c_[r * np.cos(a), r * np.sin(a), np.full(n, -l / 2)]
    V = np.vstack([top, bot, [[0, 0, l / 2], [0, 0, -l / 2]]])
    F = []
    for i in range(n):
        j = (i + 1) % n
        F += [(i, j, n + i), (j, n + j, n + i), (2 * n, j, i), (2 * n + 1, n + i, n + j)]
    return V, F

def sphere_obj(r, n=12):
    V, F = [], []
    for i in range(n + 1):
        th = np.pi * i / n
        for k in range(2 * n):
            ph = np.pi * k / n
            V.append((r * np.sin(th) * np.cos(ph), r * np.sin(th) * np.sin(ph), r * np.cos(th)))
    m = 2 * n
    for i in range(n):
        for k in range(m):
            a, b, c, d = i * m + k, i * m + (k + 1) % m, (i + 1) * m + k, (i + 1) * m + (k + 1) % m
            F += [(a, c, b), (b, c, d)]
    return np.array(V), F

def write_obj(path, V, F):
    path.write_text("".join(f"v {x:.6f} {y:.6f} {z:.6f}\n" for x, y, z in V) + "".join(f"f {a+1} {b+1} {c+1}\n" for a, b, c in F))

def mesh_hand(out):
    """Copy the iCub hand with every cylinder and sphere collision shape an OBJ mesh; returns its hand.yaml."""
    src = ROOT / "robots" / "icub_right"
    out = Path(out); (out / "meshes").mkdir(parents=True, exist_ok=True)
    urdf = (src / "icub_right.urdf").read_text()
    def cyl(m):
        r, l = float(m.group(1)), float(m.group(2))
        name = f"meshes/cyl_{r:.5f}_{l:.5f}.obj"
        write_obj(out / name, *cylinder_obj(r, l))
        return f'<geometry><mesh filename="{name}"/></geometry>'
    def sph(m):
        r = float(m.group(1))
        name = f"meshes/sph_{r:.5f}.obj"
        write_obj(out / name, *sphere_obj(r))
        return f'<geometry><mesh filename="{name}"/></geometry>'
    urdf = re.sub(r'<geometry><cylinder radius="([0-9.e-]+)" length="([0-9.e-]+)"/></geometry>', cyl, urdf)
    urdf = re.sub(r'<geometry><sphere radius="([0-9.e-]+)"/></geometry>', sph, urdf)
    (out / "icub_mesh.urdf").write_text(urdf)
    spec = (src / "hand.yaml").read_text().replace("urdf: icub_right.urdf", "urdf: icub_mesh.urdf").replace("name: icub_right", "name: icub_mesh")
    (out / "hand.yaml").write_text(spec)
    assert urdf.count("<mesh") > 40
    return out / "hand.yaml"



def test_mesh_collision_hand_loads_as_convex_hulls_plans_and_verifies(tmp_path, capsys):
    """Every finger link a mesh: the hand loads (hulls, relative mesh paths found next to the
    URDF), a bundled sphere grasp checks as with the primitive hand, and execution mode plans
    the pair with OMPL paths and verifies it palm down in pybullet."""
    import coal

    from planner.cli import main
    from planner.hand import Hand

    spec = mesh_hand(tmp_path / "hand")
    hand = Hand.load(spec)
    kinds = {type(g.shape).__name__ for g in hand.collision.geometries if g.finger is not None}
    assert kinds == {"ConvexBase"} and not any(isinstance(g.shape, coal.BVHModelBase) for g in hand.collision.geometries)
    files = []
    for name in ("sphere_four_finger", "sphere_ir2m"):
        text = (ROOT / "grasps" / "icub" / f"{name}.yaml").read_text()
        path = tmp_path / f"{name}.yaml"
        path.write_text(re.sub(r"(?m)^hand: .*$", f"hand: {spec}", text))
        files.append(path)
    assert main(["check", str(files[1])]) == 0
    out = tmp_path / "p.json"
    assert main(["plan", str(files[0]), str(files[1]), "-o", str(out), "--execution", "--gravity-set", "1"]) == 0
    text = capsys.readouterr().out
    from planner.sim.engine import default_engine  # pybullet, or MuJoCo where it has no wheel

    assert f"verified in {default_engine()}: held in 1 gravity directions (palm_down)" in text
    assert main(["replay", str(out)]) == 0
