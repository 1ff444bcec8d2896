"""What resuming verification replays from snapshots saves (`planner.sim.snapshots`).

Pairs of exp9 v2 (experiments/results/exp9_pairs_v2) whose verification replays several
sequences: the iCub box 30 g (refused after 6 sequences, every one failing at the thumb's
lift palm down), the Allegro cylinder 100 g (refused after several), the iCub mesh 100 g
(planned). Each is planned with ``--execution`` (`PlanOptions.for_execution`, OMPL paths,
six directions on two worker processes), grasp realization excluded, with snapshots (the
planner as it runs) and without (the scope replaced by none: every replay from the start),
the two alternated, after one warm-up plan that fills the per-process caches (reachable
contact pools). Prints per pair the median wall time of each and their ratio, and checks
that both give the same outcome: the same plan (states and steps) or the same refusal text
(its seconds of replays aside).

Usage: python benchmarks/bench_verify_resume.py [--repeats N] [--pairs NAME,...]
"""

from __future__ import annotations

import argparse
import contextlib
import re
import statistics
import time
from pathlib import Path

import planner.regrasp as regrasp
from planner.errors import NoSequenceError
from planner.grasp import load_grasp
from planner.options import PlanOptions
from planner.realization import realize

ROOT = Path(__file__).resolve().parent.parent
PAIRS_DIR = ROOT / "experiments" / "results" / "exp9_pairs_v2"
PAIRS = ("icub_right_box_m0.03", "allegro_right_cylinder_m0.1", "icub_right_mesh_m0.1")


@contextlib.contextmanager
def _no_scope():
    yield None


def outcome(initial, final, resume: bool) -> tuple[float, str]:
    """(wall time s, what came out: the plan's states and steps, or the refusal without its
    timings)."""
    saved = regrasp.snapshots
    if not resume:
        regrasp.snapshots = type("NoSnapshots", (), {"scope": staticmethod(_no_scope)})
    t0 = time.perf_counter()
    try:
        plan = regrasp.plan_regrasp(initial, final, PlanOptions.for_execution()).plan.to_dict()
        what = "planned: " + repr((plan["states"], plan["steps"]))
    except NoSequenceError as err:
        what = "refused: " + re.sub(r"[0-9.]+ s of replays", "s of replays", str(err))
    finally:
        regrasp.snapshots = saved
    return time.perf_counter() - t0, what


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--pairs", default=",".join(PAIRS))
    args = parser.parse_args()
    print(f"{'pair':<30} {'outcome':<8} {'from the start s':>16} {'resumed s':>10} {'ratio':>6}  same outcome")
    for name in args.pairs.split(","):
        initial = realize(load_grasp(PAIRS_DIR / f"{name}_initial.yaml"))
        final = realize(load_grasp(PAIRS_DIR / f"{name}_final.yaml"))
        outcome(initial, final, resume=True)  # warm-up: the reachable contact pools
        times: dict[bool, list[float]] = {False: [], True: []}
        seen: dict[bool, set] = {False: set(), True: set()}
        for _ in range(args.repeats):
            for resume in (False, True):
                t, what = outcome(initial, final, resume)
                times[resume].append(t)
                seen[resume].add(what)
        a, b = statistics.median(times[False]), statistics.median(times[True])
        same = len(seen[False]) == len(seen[True]) == 1 and seen[False] == seen[True]
        kind = next(iter(seen[True])).split(":")[0]
        print(f"{name:<30} {kind:<8} {a:>16.2f} {b:>10.2f} {b / a:>5.2f}x  {'yes' if same else 'NO'}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
