"""Package-level checks: public API and command line wiring."""

import subprocess
import sys

import planner


def test_all_names_exist_and_sorted():
    """Every name in planner.__all__ exists and the list is sorted."""
    assert list(planner.__all__) == sorted(planner.__all__)
    for name in planner.__all__:
        assert hasattr(planner, name), name


def test_python_dash_m_runs():
    """`python -m planner --help` exits 0 and names the subcommands."""
    out = subprocess.run([sys.executable, "-m", "planner", "--help"], capture_output=True, text=True)
    assert out.returncode == 0
    assert "demo" in out.stdout


def test_core_maths_imports_without_heavy_back_ends():
    """planner.closure and planner.graph import without pinocchio, coal, OMPL or pybullet."""
    code = (
        "import sys, planner.closure, planner.graph, planner.plan\n"
        "heavy = [m for m in ('pinocchio', 'coal', 'ompl', 'pybullet') if m in sys.modules]\n"
        "print(','.join(heavy))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""


def test_only_motion_imports_ompl_and_only_sim_imports_pybullet():
    """OMPL is imported only by planner/motion.py, pybullet only under planner/sim/."""
    from pathlib import Path

    root = Path(planner.__file__).parent
    for path in root.rglob("*.py"):
        text = path.read_text()
        rel = path.relative_to(root).as_posix()
        if "import ompl" in text or "from ompl" in text:
            assert rel == "motion.py", rel
        if "import pybullet" in text:
            assert rel.startswith("sim/"), rel
