"""Planning time and graph size: graph search vs the greedy baseline (thesis Algorithm 2).

For the box and cylinder pairs (parallel extension -> IR2M), times the planner without
finger paths (grasp realization excluded, measured separately), repeated, and prints
medians. The greedy baseline runs on the same realized grasps in the same process.
Target from the issue: the box pair planned (without paths) in under 1 s on 2 cores.

Then the box pair in execution mode (`PlanOptions.for_execution`: mean contacts, six
gravity directions, grip ranking: six grip LPs per state) against the default planner and
the mean-contact planner without gravity, without and with OMPL finger paths, as a ratio
to the default measured in the same run.

Usage: python benchmarks/bench_plan.py [--repeats N]
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

from planner.errors import NoSequenceError
from planner.grasp import load_grasp, realize
from planner.regrasp import PlanOptions, plan_regrasp

ROOT = Path(__file__).resolve().parent.parent
PAIRS = {
    "box": ("grasps/icub/box_parallel_extension.yaml", "grasps/icub/box_ir2m.yaml"),
    "cylinder": ("grasps/icub/cylinder_parallel_extension.yaml", "grasps/icub/cylinder_ir2m.yaml"),
}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    print(f"{'pair':<9} {'strategy':<8} {'realize s':>9} {'plan s (median)':>16} {'nodes':>6} {'edges':>6} {'steps':>5} {'bottleneck':>11}")
    for name, (a, b) in PAIRS.items():
        t0 = time.perf_counter()
        initial, final = realize(load_grasp(ROOT / a)), realize(load_grasp(ROOT / b))
        t_realize = time.perf_counter() - t0
        baseline = None
        for strategy in ("greedy", "graph"):
            times, result = [], None
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                try:
                    result = plan_regrasp(initial, final, PlanOptions(strategy=strategy, motion=False))
                except NoSequenceError:
                    result = None
                times.append(time.perf_counter() - t0)
            med = statistics.median(times)
            if strategy == "greedy":
                baseline = med
            ratio = f" ({med / baseline:.2f}x greedy)" if strategy == "graph" and baseline else ""
            if result is None:
                print(f"{name:<9} {strategy:<8} {t_realize:>9.3f} {med:>16.4f} {'-':>6} {'-':>6} {'fail':>5} {'-':>11}{ratio}")
                continue
            s = result.plan.summary
            print(
                f"{name:<9} {strategy:<8} {t_realize:>9.3f} {med:>16.4f} {s['graph_nodes']:>6} {s['graph_edges']:>6} "
                f"{s['gait_steps']:>5} {s['bottleneck_metric']:>11.4g}{ratio}"
            )
    print()
    print(f"{'box pair mode':<28} {'paths':<5} {'plan s (median)':>16} {'nodes':>6} {'blocked':>7} {'grip N':>7} {'ratio':>6}")
    initial, final = realize(load_grasp(ROOT / PAIRS["box"][0])), realize(load_grasp(ROOT / PAIRS["box"][1]))
    modes = {
        "default (patch, metric)": lambda **kw: PlanOptions(**kw),
        "mean contacts": lambda **kw: PlanOptions(contact_model="mean", **kw),
        "mean + gravity palm down": lambda **kw: PlanOptions(contact_model="mean", gravity=(0.0, 0.0, 9.81), **kw),
        "execution (set 6, grip)": lambda **kw: PlanOptions.for_execution(**kw),
    }
    for motion in (False, True):
        baseline = None
        for name, make in modes.items():
            times = []
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                result = plan_regrasp(initial, final, make(motion=motion))
                times.append(time.perf_counter() - t0)
            med = statistics.median(times)
            baseline = baseline or med
            s = result.plan.summary
            grip = s["bottleneck_grip_force_n"]
            print(f"{name:<28} {'yes' if motion else 'no':<5} {med:>16.4f} {s['graph_nodes']:>6} {s['blocked_states']:>7} "
                  f"{'-' if grip is None else f'{grip:.3f}':>7} {med / baseline:>5.2f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
