"""Run every experiment (exp1..exp7) in turn; the same options are passed to each.

    python experiments/run_all.py --quick            # a few minutes on 2 cores
    python experiments/run_all.py --workers 2        # the full sweeps
    python experiments/run_all.py --only exp1 exp3   # a subset
"""

from __future__ import annotations

import argparse
import importlib
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

EXPERIMENTS = ["exp1_cone_edges", "exp2_mean_vs_all", "exp3_sequences", "exp4_shape_robustness",
               "exp5_graph_vs_greedy", "exp6_scale", "exp7_execution"]


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="*", default=None, help="experiment name prefixes (exp1 ...)")
    args, rest = ap.parse_known_args(argv)
    chosen = [e for e in EXPERIMENTS if not args.only or any(e.startswith(p) for p in args.only)]
    out, times = {}, {}
    for name in chosen:
        t0 = time.perf_counter()
        module = importlib.import_module(f"experiments.{name}")
        out[name] = module.main(list(rest))
        times[name] = time.perf_counter() - t0
    print("== run_all: wall time per experiment")
    for name, s in times.items():
        print(f"  {name}: {s:.1f} s")
    print(f"  total: {sum(times.values()):.1f} s")
    return out


if __name__ == "__main__":
    main()
