"""Exp. 6 - planning time versus problem size (synthetic patches, planner.graph and planner.gait_search only).

Synthetic gait problems on a sphere (radius 30 mm, mu 0.9, gamma 4 mm, 5 cone edges):
every finger has an initial slot, a final slot and N intermediate slots, each a patch of P
points (a disc of radius 3 mm around a random surface point, normals into the sphere);
the start (all initial) and goal (all final) are resampled until force closure. No
collision predicate. Timed: `build_graph` (all reachable valid states, batch closure) and
`search` (k=1), and `LazyGraph.best` (k=1: the same best sequence, asserted, from only the
states the best-first search reaches). One factor varies at a time around the base (4
fingers, N=1, P=8).

    python experiments/exp6_scale.py [--quick] [--workers N]
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from experiments.common import parser, print_summary, pyplot, run_tasks, save, write_csv  # noqa: E402

RADIUS_M = 0.03
PATCH_RADIUS_M = 0.003
BASE = {"fingers": 4, "intermediate": 1, "points": 8}


def patch(rng, p_points):
    c = rng.normal(size=3)
    c /= np.linalg.norm(c)
    t1 = np.cross(c, [1.0, 0, 0] if abs(c[0]) < 0.9 else [0, 1.0, 0])
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(c, t1)
    if p_points == 1:
        offs = np.zeros((1, 2))
    else:
        ang = 2 * np.pi * np.arange(p_points - 1) / (p_points - 1)
        offs = np.vstack([[0, 0], PATCH_RADIUS_M * np.column_stack([np.cos(ang), np.sin(ang)])])
    d = c[None, :] * RADIUS_M + offs[:, :1] * t1 + offs[:, 1:] * t2
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return d * RADIUS_M, -d


def make_problem(rng, n_fingers, n_inter, n_points):
    from planner.model import Friction
    from planner.closure import grasp_closure
    from planner.graph import GaitProblem, Slot

    fr = Friction(0.9, 0.004, 5)
    fingers = tuple(f"f{i}" for i in range(n_fingers))
    for attempt in range(200):
        slots = {f: tuple(Slot(f, lab, *patch(rng, n_points)) for lab in ["initial", "final"] + [f"int{k}" for k in range(n_inter)])
                 for f in fingers}
        start, goal = (0,) * n_fingers, (1,) * n_fingers
        prob = GaitProblem(fingers, slots, start, goal, fr)
        if grasp_closure(prob.patches(start), fr).is_force_closure and grasp_closure(prob.patches(goal), fr).is_force_closure:
            return prob, attempt
    raise RuntimeError("no force-closure start/goal after 200 draws")


def task(t: dict) -> dict:
    from planner.graph import build_graph
    from planner.gait_search import LazyGraph, search

    rng = np.random.default_rng(t["seed"])
    prob, attempts = make_problem(rng, t["fingers"], t["intermediate"], t["points"])
    t0 = time.perf_counter()
    G = build_graph(prob)
    t1 = time.perf_counter()
    found = search(G, k=1)
    t2 = time.perf_counter()
    lazy = LazyGraph(prob)  # the same best sequence, growing only the states the search reaches
    best = lazy.best(1)
    t3 = time.perf_counter()
    # same keys up to rounding: a state's metric depends (last digits) on the batch it was evaluated in
    assert np.allclose([s.rank_key for s in best], [s.rank_key for s in found], rtol=1e-9, atol=1e-15), \
        "lazy and full search disagree"
    return {
        "lazy_s": t3 - t2, "lazy_nodes": lazy.G.number_of_nodes(), "lazy_expanded": lazy.G.graph["expanded"],
        "lazy_closure_evaluations": len(lazy.ev.closure),
        "sweep": t["sweep"], "fingers": t["fingers"], "intermediate": t["intermediate"], "points": t["points"],
        "seed": t["seed"], "slots_per_finger": 2 + t["intermediate"],
        "state_bound": (3 + t["intermediate"]) ** t["fingers"],
        "graph_nodes": G.number_of_nodes(), "blocked": len(G.graph["blocked"]), "graph_edges": G.number_of_edges(),
        "closure_evaluations": len(G.graph["evaluator"].closure),
        "build_s": t1 - t0, "search_s": t2 - t1, "total_s": t2 - t0,
        "solved": bool(found), "gait_steps": found[0].gait_steps if found else -1,
    }


def main(argv=None) -> dict:
    ap = parser(__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=None, help="seeds per setting (default 2 quick, 4 full)")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    sweeps = {
        "fingers": [3, 4, 5] if args.quick else [3, 4, 5, 6],
        "intermediate": [0, 1, 2] if args.quick else [0, 1, 2, 3, 4],
        "points": [1, 8, 32] if args.quick else [1, 4, 8, 16, 32, 64],
    }
    reps = args.repeats or (2 if args.quick else 4)
    tasks = []
    for name, values in sweeps.items():
        for v in values:
            for r in range(reps):
                tasks.append(dict(BASE, **{name: v}, sweep=name, seed=args.seed * 10_007 + 1000 * r + v))
    rows = run_tasks(task, tasks, args, desc="exp6 scale")
    write_csv(args.out / "exp6_scale.csv", rows)

    plt = pyplot()
    fig, ax = plt.subplots(1, 3, figsize=(13, 3.8))
    summary = {}
    for a, (name, values) in zip(ax, sweeps.items()):
        med_b = [np.median([r["build_s"] for r in rows if r["sweep"] == name and r[name] == v]) for v in values]
        med_s = [np.median([r["search_s"] for r in rows if r["sweep"] == name and r[name] == v]) for v in values]
        nodes = [np.median([r["graph_nodes"] for r in rows if r["sweep"] == name and r[name] == v]) for v in values]
        a.plot(values, med_b, "o-", label="build_graph")
        a.plot(values, med_s, "s-", label="search (k=1)")
        med_l = [np.median([r["lazy_s"] for r in rows if r["sweep"] == name and r[name] == v]) for v in values]
        a.plot(values, med_l, "^-", label="lazy build + search (k=1)")
        a.set_yscale("log")
        a.set_xlabel({"fingers": "fingers", "intermediate": "intermediate slots per finger (N)", "points": "points per patch (P)"}[name])
        a.set_ylabel("time (s, median)")
        a.set_title(f"vary {name} (base F=4, N=1, P=8)")
        for x, y, n in zip(values, med_b, nodes):
            a.annotate(f"{int(n)}", (x, y), fontsize=7, textcoords="offset points", xytext=(0, 5), ha="center")
        a.legend(fontsize=8)
        lazy_n = [np.median([r["lazy_closure_evaluations"] for r in rows if r["sweep"] == name and r[name] == v]) for v in values]
        summary[f"vary {name}"] = ", ".join(f"{v}: {b:.3g}s build / {s * 1e3:.3g}ms search / {int(n)} states; "
                                            f"lazy {lz:.3g}s / {int(ln)} states evaluated"
                                            for v, b, s, n, lz, ln in zip(values, med_b, med_s, nodes, med_l, lazy_n))
    save(fig, args.out / "exp6_scale.png")
    summary["solved"] = f"{sum(r['solved'] for r in rows)}/{len(rows)}"
    summary["wall_s"] = time.perf_counter() - t0
    print_summary("exp6 scale", summary)
    return summary


if __name__ == "__main__":
    main()
