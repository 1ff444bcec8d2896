"""The package without pybullet (Python >= 3.12 has no pybullet wheel): it imports, its engine
is MuJoCo, `hand check` loads the URDF in MuJoCo and a picture is refused in one line.

Each check runs in a fresh interpreter with pybullet hidden (``sys.modules['pybullet'] =
None``: its import fails and `importlib.util.find_spec` says it is absent), so the suite checks
this on the Python that has pybullet too.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
HIDE = "import sys; sys.modules['pybullet'] = None\n"


def _run(code: str, tmp_path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", HIDE + code], capture_output=True, text=True, cwd=tmp_path,
                          timeout=600)


def _cli(args: list[str], tmp_path) -> subprocess.CompletedProcess:
    return _run(f"from planner.cli import main\nsys.exit(main({args!r}))", tmp_path)


def test_every_module_but_the_pybullet_ones_imports_and_the_engine_is_mujoco(tmp_path):
    """Only pybullet's own modules (its engine, scene builder, renderer and films) need it."""
    pybullet_modules = {"planner.sim.engine_pybullet", "planner.sim.scene", "planner.sim.render", "planner.sim.film"}
    modules = sorted(".".join(p.relative_to(REPO).with_suffix("").parts)
                     for p in (REPO / "planner").rglob("*.py") if p.name not in ("__init__.py", "__main__.py"))
    assert pybullet_modules <= set(modules)
    code = ("import importlib\n"
            f"for m in {sorted(set(modules) - pybullet_modules)!r}:\n"
            "    importlib.import_module(m)\n"
            "from planner.sim.engine import default_engine\n"
            "print(default_engine())\n")
    out = _run(code, tmp_path)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split()[-1] == "mujoco"


def test_hand_check_loads_the_urdf_in_mujoco(tmp_path):
    out = _cli(["hand", "check", "icub_right"], tmp_path)
    assert out.returncode == 0, out.stderr
    assert "ok: mujoco: loads the URDF with every joint" in out.stdout, out.stdout
    assert "pybullet" not in out.stdout


def test_pictures_are_refused_in_one_line_naming_pybullet(tmp_path):
    """check --png and view --gif: exit 2, one line on stderr (no traceback), no file written."""
    grasp = str(REPO / "grasps" / "icub" / "box_ir2m.yaml")
    for args, made in ((["check", grasp, "--png", "g.png"], "g.png"), (["view", grasp, "-o", "g.html", "--gif", "g.gif"], "g.gif")):
        out = _cli(args, tmp_path)
        lines = out.stderr.strip().splitlines()
        assert out.returncode == 2 and len(lines) == 1, out.stderr
        assert "pictures" in lines[0] and "pip install pybullet" in lines[0] and "Traceback" not in out.stderr
        assert not (tmp_path / made).exists()
