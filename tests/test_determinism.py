"""Plans are byte-deterministic across processes: nothing depends on Python's string hashing
(set or dict-of-set iteration order), which changes with PYTHONHASHSEED from one process to the next."""

import os
import subprocess
import sys
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
PAIR = ("grasps/icub/cylinder_parallel_extension.yaml", "grasps/icub/cylinder_ir2m.yaml")


def test_cylinder_pair_plans_byte_identical_under_two_hash_seeds(tmp_path):
    """`regrasp plan` of the bundled cylinder pair (--no-motion) in two processes with
    different PYTHONHASHSEED writes the same bytes, and the plan has gait steps to compare."""
    runs = []
    for seed in ("1", "4242"):
        out = tmp_path / f"plan_{seed}.yaml"
        env = {**os.environ, "PYTHONHASHSEED": seed}
        cmd = [sys.executable, "-m", "planner", "plan", *(ROOT / p for p in PAIR), "--no-motion", "-o", out]
        runs.append((out, subprocess.Popen(cmd, env=env, cwd=tmp_path, stdout=subprocess.PIPE,
                                           stderr=subprocess.PIPE, text=True)))
    for out, proc in runs:
        stdout, stderr = proc.communicate(timeout=300)
        assert proc.returncode == 0, stdout + stderr
    (a, _), (b, _) = runs
    data = yaml.safe_load(a.read_text())
    assert len(data["states"]) >= 3 and data["steps"], "a plan with gait steps"
    assert a.read_bytes() == b.read_bytes()
