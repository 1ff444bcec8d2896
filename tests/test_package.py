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
