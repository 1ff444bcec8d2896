"""Exp. 1 - friction-cone discretization (thesis figs. 5-6).

The closure metric and its computation time versus the number of cone edges (3..30) for
one realized grasp: the iCub box parallel extension. Also the removable fingers per edge
count, and where the metric stabilises: the smallest edge count from which the metric
stays within 1 % (and 5 %) of a fine reference (edges = 120). Both contact models are
swept: "patch" (every patch point, the thesis) and "mean" (one contact per finger at the
patch mean, what executable plans use; `planner.closure.apply_contact_model`).

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
    from planner.model import Friction
    from planner.closure import apply_contact_model, grasp_closure, removable_fingers

    g = realized(t["grasp"])
    patches = apply_contact_model(g.patches, t["model"])
    fr = Friction(g.friction.mu, g.friction.gamma, t["edges"])
    times, rtimes = [], []
    for _ in range(t["repeats"]):
        t0 = time.perf_counter()
        c = grasp_closure(patches, fr)
        times.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        rem = removable_fingers(patches, fr)
        rtimes.append(time.perf_counter() - t0)
    n_points = sum(len(p) for p, _ in patches.values())
    return {
        "grasp": Path(t["grasp"]).stem,
        "contact_model": t["model"],
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
    from planner.closure import CONTACT_MODELS

    ap = parser(__doc__.splitlines()[0])
    ap.add_argument("--grasp", default=GRASP)
    args = ap.parse_args(argv)
    edges = [3, 4, 5, 6, 7, 8, 10, 15, 20, 25, 30] if args.quick else list(range(3, 31))
    repeats = 3 if args.quick else 9
    tasks = [{"grasp": args.grasp, "model": model, "edges": e, "repeats": repeats}
             for model in CONTACT_MODELS for e in edges + [REFERENCE_EDGES]]
    t0 = time.perf_counter()
    results = run_tasks(task, tasks, args, desc="exp1 cone edges")
    by_model = {model: [r for r in results if r["contact_model"] == model] for model in CONTACT_MODELS}
    csv_rows, summary = [], {"grasp": Path(args.grasp).stem, "edges": f"{edges[0]}..{edges[-1]}"}
    plt = pyplot()
    fig, ax = plt.subplots(1, 2, figsize=(10, 3.8))
    for model, style in zip(CONTACT_MODELS, ("o-", "s-")):
        rows, ref = by_model[model][:-1], by_model[model][-1]
        m = np.array([r["metric"] for r in rows])
        for r in rows:
            r["rel_to_ref"] = r["metric"] / ref["metric"] - 1.0
        csv_rows += rows + [dict(ref, rel_to_ref=0.0)]
        n = int(rows[0]["wrenches"] // (2 * rows[0]["edges"]))
        ax[0].plot(edges, m, style, label=f"{model} ({n} contact points)")
        ax[0].axhline(ref["metric"], color="gray", ls="--", lw=0.8)
        ax[1].plot(edges, [r["closure_ms"] for r in rows], style, label=f"grasp_closure, {model}")
        ax[1].plot(edges, [r["removable_ms"] for r in rows], style, mfc="none", label=f"removable_fingers (Alg. 1), {model}")
        summary.update({
            f"{model}: contact points": n,
            f"{model}: metric at 3 / 5 / {edges[-1]} edges / reference": (
                f"{m[0]:.5f} / {rows[edges.index(5)]['metric'] if 5 in edges else float('nan'):.5f} / {m[-1]:.5f} / {ref['metric']:.5f}"),
            f"{model}: stable within 5 % / 1 % from edges": (
                stable_from(edges, m, ref["metric"], 0.05), stable_from(edges, m, ref["metric"], 0.01)),
            f"{model}: removable sets": sorted({r["removable"] for r in rows}),
            f"{model}: closure ms at 3 / {edges[-1]} edges": (round(rows[0]["closure_ms"], 2), round(rows[-1]["closure_ms"], 2)),
            f"{model}: removable ms at 3 / {edges[-1]} edges": (round(rows[0]["removable_ms"], 2), round(rows[-1]["removable_ms"], 2)),
        })
    summary["metric_reference"] = float(by_model["patch"][-1]["metric"])
    write_csv(args.out / "exp1_cone_edges.csv", csv_rows)
    ax[0].axvline(5, color="tab:red", ls=":", label="thesis choice (5)")
    ax[0].set_xlabel("friction-cone edges")
    ax[0].set_ylabel("Ferrari-Canny metric")
    ax[0].set_title(f"box parallel extension: metric vs edges (dashed: {REFERENCE_EDGES} edges)")
    ax[0].legend(fontsize=8)
    ax[1].set_xlabel("friction-cone edges")
    ax[1].set_ylabel(f"time (ms, best of {repeats})")
    ax[1].set_title("computation time")
    ax[1].legend(fontsize=7)
    save(fig, args.out / "exp1_cone_edges.png")
    summary["wall_s"] = time.perf_counter() - t0
    print_summary("exp1 cone edges", summary)
    return summary


if __name__ == "__main__":
    main()
