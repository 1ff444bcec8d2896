"""Exp. 3 - every valid gait ordering (thesis figs. 11-12).

For every parallel-extension -> IR2M pair of the library (box, cylinder, ...), all
minimal finger-gaiting orderings: the simple paths of the grasp-state graph with the
fewest edges (each finger that must change is lifted once and landed once, each finger
free at the end lifted once), with the bottleneck metric (worst state), the mean metric
and the worst *intermediate* metric (start and goal excluded; the bottleneck is often the
final grasp itself, shared by every ordering). The thesis's four sequences are marked:
the needed fingers repositioned one at a time (index-first or ring-first), then the
unneeded fingers lifted (little-first or thumb-first). Also counts the longer simple
paths (detours that lift and re-land a finger) and checks that `planner.gait_search.search`
returns a minimal ordering with the best bottleneck. Every pair is run under both contact
models: "patch" (every patch point, the thesis) and "mean" (one contact per finger, what
executable plans use).

    python experiments/exp3_sequences.py [--quick] [--workers N]
"""

from __future__ import annotations

import itertools
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from experiments.common import grasp_pairs, parser, print_summary, pyplot, realized, run_tasks, save, write_csv  # noqa: E402


def classify(problem, actions):
    """Thesis-style name of an ordering, or "" when it is not one of the thesis's kind."""
    from planner.graph import LIFTED

    fingers = problem.fingers
    needed = [f for f, s, g in zip(fingers, problem.start, problem.goal) if g != LIFTED and s != g]
    unneeded = [f for f, s, g in zip(fingers, problem.start, problem.goal) if g == LIFTED and s != LIFTED]
    i, order_n = 0, []
    while i + 1 < len(actions) and actions[i][1] == "lift" and actions[i + 1] == (actions[i][0], "land"):
        order_n.append(actions[i][0])
        i += 2
    rest = actions[i:]
    if sorted(order_n) != sorted(needed) or any(a != "lift" for _, a in rest) or sorted(f for f, _ in rest) != sorted(unneeded):
        return ""
    return f"{order_n[0] if order_n else '-'}-first, {rest[0][0] if rest else '-'}-first lifting"


def task(t: dict) -> dict:
    import networkx as nx

    from planner.graph import build_graph
    from planner.options import PlanOptions
    from planner.gait_search import search
    from planner.slots import build_problem

    from planner.errors import PlannerError

    t0 = time.perf_counter()
    a, b = realized(t["initial"]), realized(t["final"])
    out = {"pair": t["pair"], "contact_model": t["model"], "nodes": 0, "edges": 0, "graph_s": 0.0,
           "orderings": [], "longer_paths": {}}
    try:
        problem = build_problem(a, b, PlanOptions(motion=False, contact_model=t["model"]))
    except PlannerError as err:
        out["error"] = f"{type(err).__name__}: {err}"[:200]
        return out
    G = build_graph(problem)
    out.update(nodes=G.number_of_nodes(), edges=G.number_of_edges(), graph_s=time.perf_counter() - t0)
    start, goal = G.graph["start"], G.graph["goal"]
    if goal not in G or not nx.has_path(G, start, goal):
        out["error"] = "goal unreachable"
        return out
    L = nx.shortest_path_length(G, start, goal)
    metric = {v: G.nodes[v]["metric"] for v in G.nodes}
    for path in nx.all_simple_paths(G, start, goal, cutoff=L):
        actions = tuple((G.edges[u, v]["finger"], G.edges[u, v]["action"]) for u, v in zip(path, path[1:]))
        ms = [metric[v] for v in path]
        order = []
        for (f, act), v in zip(actions, path[1:]):
            order.append(f"{f}:{act}" + (f">{problem.labels(v)[f]}" if act == "land" else ""))
        out["orderings"].append({
            "pair": t["pair"], "contact_model": t["model"], "order": " ".join(order), "edges": len(actions),
            "bottleneck": min(ms), "mean_metric": float(np.mean(ms)),
            "worst_intermediate": min(ms[1:-1]) if len(ms) > 2 else float("nan"),
            "thesis": classify(problem, actions),
        })
    for extra in range(1, t["extra"] + 1):
        n = sum(1 for p in itertools.islice(nx.all_simple_paths(G, start, goal, cutoff=L + 2 * extra), t["count_limit"]))
        out["longer_paths"][L + 2 * extra] = n
    t1 = time.perf_counter()
    found = search(G, k=len(out["orderings"]) + 10)
    out["search_s"] = time.perf_counter() - t1
    best_b = max(o["bottleneck"] for o in out["orderings"])
    out["search_agrees"] = bool(found) and abs(found[0].bottleneck - best_b) <= 1e-12 and len(found[0].actions) == L
    out["at_best_bottleneck"] = sum(1 for o in out["orderings"] if o["bottleneck"] >= best_b - 1e-12)
    out["search_best"] = " ".join(found[0].order(problem)) if found else ""
    return out


def main(argv=None) -> dict:
    from planner.closure import CONTACT_MODELS

    ap = parser(__doc__.splitlines()[0])
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    pairs = grasp_pairs()
    tasks = [{"pair": n, "model": model, "initial": i, "final": f, "extra": 1 if args.quick else 2, "count_limit": 200_000}
             for n, i, f in pairs for model in CONTACT_MODELS]
    results = run_tasks(task, tasks, args, desc="exp3 sequences")
    rows = [o for r in results for o in r["orderings"]]
    write_csv(args.out / "exp3_sequences.csv", rows)
    summary_rows = []
    for r in results:
        o = r["orderings"]
        thesis = [x for x in o if x["thesis"]]
        summary_rows.append({
            "pair": r["pair"], "contact_model": r["contact_model"], "graph_nodes": r["nodes"], "graph_edges": r["edges"], "graph_s": r["graph_s"],
            "minimal_orderings": len(o), "thesis_style": len(thesis),
            "longer_simple_paths": " ".join(f"<={k}:{v}" for k, v in r["longer_paths"].items()),
            "bottleneck_best": max((x["bottleneck"] for x in o), default=float("nan")),
            "bottleneck_worst": min((x["bottleneck"] for x in o), default=float("nan")),
            "worst_intermediate_best": max((x["worst_intermediate"] for x in o), default=float("nan")),
            "worst_intermediate_worst": min((x["worst_intermediate"] for x in o), default=float("nan")),
            "orderings_at_best_bottleneck": r.get("at_best_bottleneck", 0),
            "search_best_is_best_minimal": r.get("search_agrees", False),
            "search_best": r.get("search_best", ""), "error": r.get("error", ""),
        })
    write_csv(args.out / "exp3_sequences_summary.csv", summary_rows)

    plt = pyplot()
    fig, axes = plt.subplots(len(results), 1, figsize=(12, 3.6 * max(len(results), 1)), squeeze=False)
    for ax, r in zip(axes[:, 0], results):
        o = sorted(r["orderings"], key=lambda x: -x["worst_intermediate"])
        x = np.arange(len(o))
        ax.bar(x, [v["worst_intermediate"] for v in o], color=["tab:red" if v["thesis"] else "tab:gray" for v in o],
               label="worst intermediate metric (red: thesis's sequences)")
        ax.plot(x, [v["bottleneck"] for v in o], "k_", ms=8, label="bottleneck (incl. start/goal)")
        names = []
        for xi, v in zip(x, o):
            if v["thesis"]:
                names.append(f"T{len(names) + 1}: {v['thesis']}")
                ax.annotate(f"T{len(names)}", (xi, v["worst_intermediate"]), fontsize=7, ha="center", va="bottom")
        ax.text(0.99, 0.97, "\n".join(names), transform=ax.transAxes, ha="right", va="top", fontsize=7,
                bbox={"fc": "white", "alpha": 0.8})
        top = max([v["worst_intermediate"] for v in o] + [v["bottleneck"] for v in o] + [1e-9])
        ax.set_ylim(0, 1.3 * top)
        ax.set_title(f"{r['pair']}, {r['contact_model']} contacts: {len(o)} minimal orderings ({r['nodes']} valid states)")
        ax.set_xlabel("ordering (sorted by worst intermediate metric)")
        ax.set_ylabel("metric")
        ax.legend(fontsize=7, loc="upper center")
    save(fig, args.out / "exp3_sequences.png")

    summary = {"pairs": [p[0] for p in pairs]}
    for s in summary_rows:
        summary[f"{s['pair']} ({s['contact_model']})"] = (f"{s['minimal_orderings']} minimal orderings ({s['thesis_style']} thesis-style), "
                              f"bottleneck {s['bottleneck_worst']:.4g}..{s['bottleneck_best']:.4g}, worst intermediate "
                              f"{s['worst_intermediate_worst']:.4g}..{s['worst_intermediate_best']:.4g}; longer {s['longer_simple_paths']}; "
                              f"{s['orderings_at_best_bottleneck']} at the best bottleneck; search(k=1) returns one of them: {s['search_best_is_best_minimal']}")
    for r in rows:
        if r["thesis"]:
            summary[f"{r['pair']} ({r['contact_model']}) {r['thesis']}"] = f"bottleneck {r['bottleneck']:.4g}, worst intermediate {r['worst_intermediate']:.4g}"
    summary["wall_s"] = time.perf_counter() - t0
    print_summary("exp3 sequences", summary)
    return summary


if __name__ == "__main__":
    main()
