"""Exp. 5 - graph search versus the greedy baseline (thesis Algorithm 2) on random pairs.

Random grasp pairs are generated from the library (every hand under grasps/): grasp files
sharing hand, object, pose and friction form a group; a pair takes an initial and a final
file of one group (the same file twice is allowed) and perturbs each, seeded: contact
points move tangentially by N(0, --point-sigma-mm) and are projected onto the surface
(when such a point is out of the finger's reach, the grasp is instead resampled from its
nominal realized postures), posture joints by N(0, --posture-sigma-rad) within limits, and each finger of the final
grasp other than one anchor is freed with probability --free-prob. Pairs whose two grasps
are not both force closure, or whose initial state has colliding fingers, are counted as
invalid and left out of the comparison.

For each valid pair: the ranked graph search over the pair's own contacts (`LazyGraph`,
k=1: the same best sequence as `build_graph` + `search`), the anytime planner with its
defaults (`plan_regrasp` without finger paths: intermediate contacts added in rounds within
--time-limit; its time includes slots and rounds) and the greedy baseline (`greedy`, run on
a fresh lazily evaluated graph so that its time only counts the states it visits): solved
or not, gait steps, bottleneck metric, time (slot construction with pairwise collision
checks is shared and timed separately for the first two).

    python experiments/exp5_graph_vs_greedy.py [--quick] [--pairs N] [--workers N] [--time-limit S]
"""

from __future__ import annotations

import sys
import time
from collections import defaultdict
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from experiments.common import library_grasps, load_spec, realized, parser, print_summary, pyplot, run_tasks, save, write_csv  # noqa: E402


def groups() -> list[list[str]]:
    """Library grasp files grouped by (hand, object, pose, friction)."""
    from planner.errors import PlannerError

    out = defaultdict(list)
    for path in library_grasps():
        try:
            s = load_spec(path)
        except PlannerError:  # a file being written or gone (SpecError: malformed, unreadable, invalid)
            continue
        o = s.object
        key = (s.hand_ref, o.shape, tuple(np.round(o.size, 6)), tuple(np.round(o.position, 6)),
               tuple(np.round(o.quat_xyzw, 6)), o.mesh_path, s.friction.mu, s.friction.gamma, s.friction.edges)
        out[key].append(path)
    return [v for _, v in sorted(out.items(), key=lambda kv: str(kv[0]))]


def as_postures(path: str):
    """The library grasp with every contact finger turned into a posture finger at its
    nominal realized joint values."""
    spec, g = load_spec(path), realized(path)
    return replace(spec, fingers=tuple(
        replace(f, kind="posture", point_obj=None, link=None, posture=tuple(float(v) for v in g.finger_q[f.name]))
        if f.kind == "contact" else f for f in spec.fingers))


def perturb(spec, hand, rng, point_sigma_m, posture_sigma_rad, free_prob):
    obj = spec.object
    fingers = []
    touching = [f.name for f in spec.fingers if f.kind != "free"]
    anchor = touching[int(rng.integers(len(touching)))] if touching else None
    for f in spec.fingers:
        if f.kind == "contact":
            p, n_out, _ = obj.closest_surface(np.asarray(f.point_obj, float))
            step = rng.normal(0.0, point_sigma_m, 3)
            step -= (step @ n_out) * n_out  # tangential
            p2, _, _ = obj.closest_surface(p + step)
            f = replace(f, point_obj=tuple(float(v) for v in p2))
        elif f.kind == "posture":
            idx = list(hand.fingers[f.name].q_index)
            lo, hi = np.asarray(hand.lower)[idx], np.asarray(hand.upper)[idx]
            # posture values are in hand.yaml joint order = the finger's joints order
            q = np.clip(np.asarray(f.posture, float) + rng.normal(0.0, posture_sigma_rad, len(f.posture)), lo, hi)
            f = replace(f, posture=tuple(float(v) for v in q))
        if f.kind != "free" and f.name != anchor and free_prob > 0 and rng.random() < free_prob:
            f = replace(f, kind="free", point_obj=None, link=None, posture=None)
        fingers.append(f)
    return replace(spec, fingers=tuple(fingers))


def task(t: dict) -> dict:
    import networkx as nx

    from planner.errors import NoSequenceError, PlannerError
    from planner.graph import Evaluator, add_node
    from planner.grasp import load_hand
    from planner.options import PlanOptions
    from planner.realization import realize
    from planner.regrasp import plan_regrasp
    from planner.gait_search import LazyGraph, greedy
    from planner.slots import build_problem

    rng = np.random.default_rng(t["seed"])
    group = t["groups"][int(rng.integers(len(t["groups"])))]
    fi, ff = group[int(rng.integers(len(group)))], group[int(rng.integers(len(group)))]
    row = {"seed": t["seed"], "initial": Path(fi).stem, "final": Path(ff).stem, "hand": load_spec(fi).hand}
    hand = load_hand(load_spec(fi).hand_ref)
    grasps = []
    for path, free_prob in ((fi, 0.0), (ff, t["free_prob"])):
        # contact points perturbed on the surface; when a perturbed point is out of reach,
        # the grasp is resampled from its nominal realized postures instead
        state = rng.bit_generator.state
        try:
            grasps.append((realize(perturb(load_spec(path), hand, rng, t["point_sigma_m"], t["posture_sigma_rad"], free_prob), hand), "points"))
        except PlannerError:
            rng.bit_generator.state = state
            try:
                grasps.append((realize(perturb(as_postures(path), hand, rng, 0.0, t["posture_sigma_rad"], free_prob), hand), "postures"))
            except PlannerError as err:
                row.update(valid=False, reason=f"realize: {type(err).__name__}")
                return row
    (gi, mi), (gf, mf) = grasps
    row["perturbed"] = f"{mi}/{mf}"
    if not (gi.is_force_closure and gf.is_force_closure):
        row.update(valid=False, reason="initial or final grasp not force closure")
        return row
    row["valid"] = True
    t0 = time.perf_counter()
    problem = build_problem(gi, gf, PlanOptions(motion=False, intermediate=t["intermediate"], seed=t["seed"]))
    row["slots_s"] = time.perf_counter() - t0
    row["fingers_to_change"] = sum(s != g for s, g in zip(problem.start, problem.goal))
    t0 = time.perf_counter()
    try:
        lazy = LazyGraph(problem)
    except NoSequenceError as err:  # the initial state itself is invalid (fingers collide)
        row.update(valid=False, reason=str(err)[:120])
        return row
    found = lazy.best(1)
    row["graph_s"] = time.perf_counter() - t0
    # a final grasp whose fingers collide (or that cannot hold) is no state at all: no
    # planner can reach it
    row["final_state_valid"] = lazy.ev.blocked_reason(problem.goal) is None
    row["graph_nodes"] = lazy.G.number_of_nodes()
    row["graph_solved"] = bool(found)
    if found:
        row.update(graph_steps=found[0].gait_steps, graph_edges=len(found[0].actions), graph_bottleneck=found[0].bottleneck)
    # the anytime planner with its defaults (intermediate contacts in rounds, time limit),
    # no finger paths; its time includes slots and rounds (grasp realization excluded)
    t0 = time.perf_counter()
    try:
        res = plan_regrasp(gi, gf, PlanOptions(motion=False, intermediate=t["intermediate"], seed=t["seed"],
                                               alternatives=1, time_limit_s=t["time_limit_s"]))
        info = res.plan.summary["search"]
        row.update(anytime_solved=True, anytime_steps=res.sequence.gait_steps, anytime_bottleneck=res.sequence.bottleneck,
                   anytime_rounds=info["rounds"], anytime_added=sum(info["intermediate_added"].values()))
    except NoSequenceError as err:
        row.update(anytime_solved=False, anytime_reason=str(err)[-600:])
    row["anytime_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    ev = Evaluator(problem)
    G0 = nx.DiGraph(problem=problem, start=problem.start, goal=problem.goal, blocked={}, evaluator=ev)
    ev.evaluate([problem.start])
    add_node(G0, ev, problem.start)
    try:
        g = greedy(G0)
        row.update(greedy_solved=True, greedy_steps=g.gait_steps, greedy_edges=len(g.actions), greedy_bottleneck=g.bottleneck)
    except NoSequenceError as err:
        row.update(greedy_solved=False, greedy_reason=str(err).split(";")[0][:120])
    row["greedy_s"] = time.perf_counter() - t0
    return row


def _by_group(rows) -> str:
    """'hand object: anytime solved / graph solved / valid' per hand and object."""
    out = defaultdict(lambda: [0, 0, 0])
    for r in rows:
        k = f"{r['hand'].split('_')[0]} {r['initial'].split('_')[0]}"
        out[k][0] += bool(r["anytime_solved"])
        out[k][1] += bool(r["graph_solved"])
        out[k][2] += 1
    return ", ".join(f"{k} {a}/{g}/{n}" for k, (a, g, n) in sorted(out.items()))


def main(argv=None) -> dict:
    ap = parser(__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, default=None, help="random pairs (default 12 quick, 120 full)")
    ap.add_argument("--point-sigma-mm", type=float, default=3.0)
    ap.add_argument("--posture-sigma-rad", type=float, default=0.1)
    ap.add_argument("--free-prob", type=float, default=0.15)
    ap.add_argument("--intermediate", type=int, default=0, help="intermediate contacts per finger")
    ap.add_argument("--time-limit", type=float, default=10.0, help="the anytime planner's budget per pair, s")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    gs = groups()
    n = args.pairs or (12 if args.quick else 120)
    tasks = [{"seed": args.seed * 1_000_003 + i, "groups": gs, "point_sigma_m": args.point_sigma_mm * 1e-3,
              "posture_sigma_rad": args.posture_sigma_rad, "free_prob": args.free_prob,
              "intermediate": args.intermediate, "time_limit_s": args.time_limit} for i in range(n)]
    rows = run_tasks(task, tasks, args, desc="exp5 graph vs greedy")
    write_csv(args.out / "exp5_graph_vs_greedy.csv", rows)
    valid = [r for r in rows if r["valid"]]
    both = [r for r in valid if r["graph_solved"] and r["greedy_solved"]]

    plt = pyplot()
    fig, ax = plt.subplots(1, 3, figsize=(13, 4))
    ax[0].bar(["anytime\n(defaults)", "graph\n(fixed contacts)", "greedy"],
              [np.mean([r[k] for r in valid]) if valid else 0 for k in ("anytime_solved", "graph_solved", "greedy_solved")],
              color=["tab:blue", "tab:green", "tab:gray"])
    ax[0].set_ylim(0, 1)
    ax[0].set_ylabel("solved fraction")
    ax[0].set_title(f"{len(valid)} valid random pairs")
    if both:
        gb, yb = np.array([r["graph_bottleneck"] for r in both]), np.array([r["greedy_bottleneck"] for r in both])
        ax[1].scatter(yb, gb, s=14)
        lim = [min(gb.min(), yb.min()), max(gb.max(), yb.max())]
        ax[1].plot(lim, lim, "k--", lw=0.8)
    ax[1].set_xlabel("greedy bottleneck metric")
    ax[1].set_ylabel("graph bottleneck metric")
    ax[1].set_title("pairs both solve")
    ax[2].hist([[r["graph_s"] * 1e3 for r in valid], [r["greedy_s"] * 1e3 for r in valid]], bins=15, label=["graph", "greedy"])
    ax[2].set_xlabel("time (ms; slots excluded)")
    ax[2].set_ylabel("pairs")
    ax[2].legend()
    save(fig, args.out / "exp5_graph_vs_greedy.png")

    def mean(key, rs):
        v = [r[key] for r in rs if key in r]
        return float(np.mean(v)) if v else float("nan")

    summary = {
        "groups": [" + ".join(Path(p).stem for p in g) for g in gs],
        "pairs": n, "valid_pairs": len(valid),
        "graph_solved": f"{sum(r['graph_solved'] for r in valid)}/{len(valid)}",
        "anytime_solved": f"{sum(r['anytime_solved'] for r in valid)}/{len(valid)}",
        "final_state_invalid": sum(not r["final_state_valid"] for r in valid),
        "solved_with_a_valid_final_state_graph_vs_anytime": (
            f"{sum(r['graph_solved'] for r in valid if r['final_state_valid'])}/{sum(r['final_state_valid'] for r in valid)}",
            f"{sum(r['anytime_solved'] for r in valid if r['final_state_valid'])}/{sum(r['final_state_valid'] for r in valid)}"),
        "graph_median_s_solved": float(np.median([r["graph_s"] + r["slots_s"] for r in valid if r["graph_solved"]]))
        if any(r["graph_solved"] for r in valid) else float("nan"),
        "anytime_median_s_solved": float(np.median([r["anytime_s"] for r in valid if r["anytime_solved"]]))
        if any(r["anytime_solved"] for r in valid) else float("nan"),
        "anytime_solved_with_intermediate": sum(r["anytime_solved"] and r.get("anytime_rounds", 0) > 0 for r in valid),
        "anytime_solved_by_group": _by_group(valid),
        # what the anytime planner says on the pairs it does not solve although their final
        # grasp is a valid state (the end of its message: what was tried)
        "anytime_unsolved_with_a_valid_final_state": [
            f"seed {r['seed']} {r['initial']} -> {r['final']}: {r['anytime_reason'].rsplit('; ', 1)[-1]}"
            for r in valid if r["final_state_valid"] and not r["anytime_solved"]],
        "greedy_solved": f"{sum(r['greedy_solved'] for r in valid)}/{len(valid)}",
        "greedy_only": sum(r["greedy_solved"] and not r["graph_solved"] for r in valid),
        "both_solved": len(both),
        "graph_better_bottleneck": sum(r["graph_bottleneck"] > r["greedy_bottleneck"] + 1e-12 for r in both),
        "mean_bottleneck_graph_vs_greedy_on_both": (mean("graph_bottleneck", both), mean("greedy_bottleneck", both)),
        "mean_steps_graph_vs_greedy_on_both": (mean("graph_steps", both), mean("greedy_steps", both)),
        "mean_ms_graph_vs_greedy": (1e3 * mean("graph_s", valid), 1e3 * mean("greedy_s", valid)),
        "mean_slots_s": mean("slots_s", valid),
        "wall_s": time.perf_counter() - t0,
    }
    print_summary("exp5 graph vs greedy", summary)
    return summary


if __name__ == "__main__":
    main()
