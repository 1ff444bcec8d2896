"""`replay --gui` without a display is one line and exit 2: pybullet's window ended the
process from C (exit 1, nothing said: the C library's complaint went where the libraries'
console output goes)."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from planner.cli import main
from planner.resources import bundled_grasp

pytest.importorskip("pybullet")
ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="DISPLAY is how Linux says there is a display")
def test_gui_without_a_display(tmp_path):
    plan = tmp_path / "plan.yaml"
    assert main(["plan", str(bundled_grasp("icub/box_parallel_extension.yaml")), str(bundled_grasp("icub/box_ir2m.yaml")),
                 "--no-motion", "-q", "-o", str(plan)]) == 0
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    run = subprocess.run([sys.executable, "-m", "planner", "replay", str(plan), "--gui", "--engine", "pybullet"],
                         env=env, capture_output=True, text=True, timeout=120)
    err = run.stderr.strip().splitlines()
    assert run.returncode == 2 and len(err) == 1 and "--gui needs a display" in err[0], (run.returncode, err)
