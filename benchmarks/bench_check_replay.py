"""What holding a grasp in the simulator costs ``regrasp check --execution`` (session 56).

``check --execution`` runs execution mode's static test, then replays the grasp in a physics
engine as a plan's verification replays its initial grasp (`planner.regrasp.end_grasp_replay`);
``--no-verify`` keeps the static test alone, the baseline. For each bundled grasp (grasps/icub,
grasps/allegro, grasps/guide) both are run through `planner.cli.main` in this process,
alternated ``--repeats`` times (the machine's load varies), after one warm-up run of each that
fills the per-process caches. Prints per grasp the median wall time of each, their ratio and
difference, and the verdicts (which must agree with the static test wherever it refuses), then
the medians over the grasps the static test accepts (those that are replayed).

Usage: OPENBLAS_NUM_THREADS=1 python benchmarks/bench_check_replay.py [--repeats N] [--grasps GLOB]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import statistics
import time
from pathlib import Path

from planner.cli import main

ROOT = Path(__file__).resolve().parent.parent


def _run(path: Path, replay: bool) -> tuple[float, int, dict]:
    """(wall s, exit code, check --json's execution block) of one check --execution run."""
    argv = ["check", str(path), "--execution", "--json"] + ([] if replay else ["--no-verify"])
    buf = io.StringIO()
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(buf):
        code = main(argv)
    return time.perf_counter() - t0, code, json.loads(buf.getvalue())["execution"]


def main_(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--grasps", default="grasps/*/*.yaml", help="glob under the repository (default grasps/*/*.yaml)")
    args = ap.parse_args(argv)
    paths = sorted(ROOT.glob(args.grasps))
    for p in paths[:1]:  # warm-up: imports, the engine, caches
        _run(p, False)
        _run(p, True)
    rows = []
    print(f"{'grasp':<44} {'static s':>9} {'+replay s':>10} {'ratio':>6} {'+s':>6}  verdict")
    for p in paths:
        static, replay = [], []
        for _ in range(args.repeats):
            t, code_s, ex_s = _run(p, False)
            static.append(t)
            t, code_r, ex_r = _run(p, True)
            replay.append(t)
        sim = ex_r.get("simulator")
        if not ex_s["accepted"]:
            assert code_r == code_s == 1 and sim is None, p  # refused by the static test: nothing replayed
            verdict = "static test refuses"
        else:
            verdict = "held" if sim and sim["held"] else f"drops ({sim['failure']['direction']})" if sim else "not replayed"
        a, b = statistics.median(static), statistics.median(replay)
        rows.append((p, a, b, sim is not None))
        name = str(p.relative_to(ROOT / "grasps"))
        print(f"{name:<44} {a:9.2f} {b:10.2f} {b / a:6.2f} {b - a:6.2f}  {verdict}")
    replayed = [(a, b) for _, a, b, r in rows if r]
    if replayed:
        ratios = [b / a for a, b in replayed]
        extra = [b - a for a, b in replayed]
        print(f"replayed grasps: {len(replayed)} of {len(rows)}; median static {statistics.median(a for a, _ in replayed):.2f} s, "
              f"with the replay {statistics.median(b for _, b in replayed):.2f} s; ratio median {statistics.median(ratios):.2f} "
              f"(min {min(ratios):.2f}, max {max(ratios):.2f}); the replay adds {statistics.median(extra):.2f} s median")
    return 0


if __name__ == "__main__":
    raise SystemExit(main_())
