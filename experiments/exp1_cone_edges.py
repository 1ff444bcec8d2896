"""Exp. 1 - friction-cone discretization (thesis figs. 5-6).

The closure metric and its computation time versus the number of cone edges (3..30) for
one realized grasp: the iCub box parallel extension. Also the removable fingers per edge
count, and where the metric stabilises: the smallest edge count from which the metric
stays within 1 % (and 5 %) of a fine reference (edges = 120).

    python experiments/exp1_cone_edges.py [--quick] [--workers N]
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from experiments.common import parser, print_summary, pyplot, realized, run_tasks, save, write_csv  # noqa: E402

GRASP = "grasps/icub/box_parallel_extension.yaml"
REFERENCE_EDGES = 120


def task(t: dict) -> dict:
    from planner.closure import Friction, grasp_closure, removable_fingers

    g = realized(t["grasp"])
    fr = Friction(g.friction.mu, g.friction.gamma, t["edges"])
    times, rtimes = [], []
    for _ in range(t["repeats"]):
        t0 = time.perf_counter()
        c = grasp_closure(g.patches, fr)
        times.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        rem = removable_fingers(g.patches, fr)
        rtimes.append(time.perf_counter() - t0)
    n_points = sum(len(p) for p, _ in g.patches.values())
    return {
        "grasp": Path(t["grasp"]).stem,
        "edges": t["edges"],
        "wrenches": 2 * t["edges"] * n_points,
        "force_closure": c.is_force_closure,
        "metric": c.metric,
        "closure_ms": 1e3 * float(np.min(times)),
        "removable_ms": 1e3 * float(np.min(rtimes)),
        "removable": " ".join(sorted(rem)),
    }


def stable_from(edges, metric, ref, tol) -> int | None:
    """Smallest e such that every edge count >= e is within tol (relative) of ref."""
    ok = np.abs(np.asarray(metric) - ref) <= tol * abs(ref)
    for i in range(len(edges)):
        if ok[i:].all():
            return int(edges[i])
    return None


def main(argv=None) -> dict:
    ap = parser(__doc__.splitlines()[0])
    ap.add_argument("--grasp", default=GRASP)
    args = ap.parse_args(argv)
    edges = [3, 4, 5, 6, 7, 8, 10, 15, 20, 25, 30] if args.quick else list(range(3, 31))
    repeats = 3 if args.quick else 9
    tasks = [{"grasp": args.grasp, "edges": e, "repeats": repeats} for e in edges + [REFERENCE_EDGES]]
    t0 = time.perf_counter()
    rows = run_tasks(task, tasks, args, desc="exp1 cone edges")
    ref = rows[-1]
    rows = rows[:-1]
    m = np.array([r["metric"] for r in rows])
    for r in rows:
        r["rel_to_ref"] = r["metric"] / ref["metric"] - 1.0
    write_csv(args.out / "exp1_cone_edges.csv", rows + [dict(ref, rel_to_ref=0.0)])

    plt = pyplot()
    fig, ax = plt.subplots(1, 2, figsize=(10, 3.8))
    ax[0].plot(edges, m, "o-", label="metric")
    ax[0].axhline(ref["metric"], color="gray", ls="--", label=f"reference ({REFERENCE_EDGES} edges)")
    ax[0].axvline(5, color="tab:red", ls=":", label="thesis choice (5)")
    ax[0].set_xlabel("friction-cone edges")
    ax[0].set_ylabel("Ferrari-Canny metric")
    ax[0].set_title("box parallel extension: metric vs edges")
    ax[0].legend(fontsize=8)
    ax[1].plot(edges, [r["closure_ms"] for r in rows], "o-", label="grasp_closure")
    ax[1].plot(edges, [r["removable_ms"] for r in rows], "s-", label="removable_fingers (Alg. 1)")
    ax[1].set_xlabel("friction-cone edges")
    ax[1].set_ylabel(f"time (ms, best of {repeats})")
    ax[1].set_title("computation time")
    ax[1].legend(fontsize=8)
    save(fig, args.out / "exp1_cone_edges.png")

    summary = {
        "grasp": Path(args.grasp).stem,
        "edges": f"{edges[0]}..{edges[-1]}",
        "metric_at_3": float(m[0]),
        "metric_at_5": float(rows[edges.index(5)]["metric"]) if 5 in edges else float("nan"),
        "metric_at_30_or_last": float(m[-1]),
        "metric_reference": float(ref["metric"]),
        "stable_within_5pct_from_edges": stable_from(edges, m, ref["metric"], 0.05),
        "stable_within_1pct_from_edges": stable_from(edges, m, ref["metric"], 0.01),
        "removable_sets": sorted({r["removable"] for r in rows}),
        "closure_ms_first_last": (round(rows[0]["closure_ms"], 2), round(rows[-1]["closure_ms"], 2)),
        "removable_ms_first_last": (round(rows[0]["removable_ms"], 2), round(rows[-1]["removable_ms"], 2)),
        "wall_s": time.perf_counter() - t0,
    }
    print_summary("exp1 cone edges", summary)
    return summary


if __name__ == "__main__":
    main()
