"""Grasp-state graph and search on synthetic contact slots (no hand needed).

Contacts are single points on a sphere of radius R with inward normals. With soft
fingers, an antipodal pair is force closure; the cases below are built from that fact
and every claim is re-checked with `grasp_closure` independently of the graph.
"""

import itertools

import networkx as nx
import numpy as np
import pytest

from planner.model import Friction
from planner.closure import grasp_closure, min_grip_force
from planner.errors import InputError, NoSequenceError, UnknownNameError
from planner.explain import explain_failure
from planner.graph import LIFTED, GaitProblem, Slot, build_graph
from planner.gait_search import LazyGraph, greedy, search

R = 0.03
FRICTION = Friction(mu=0.5, gamma=0.004, edges=5)
DIRS = {
    "+x": (1, 0, 0), "-x": (-1, 0, 0), "+y": (0, 1, 0), "-y": (0, -1, 0), "+z": (0, 0, 1), "-z": (0, 0, -1),
}


def slot(finger, label, direction, tilt_deg=0.0):
    """A one-point slot on the sphere at a direction (optionally tilted toward +z)."""
    d = np.array(DIRS[direction] if isinstance(direction, str) else direction, dtype=float)
    if tilt_deg:
        d = d * np.cos(np.radians(tilt_deg)) + np.array([0, 0, 1.0]) * np.sin(np.radians(tilt_deg))
    d /= np.linalg.norm(d)
    return Slot(finger, label, [R * d], [-d])


def problem(slots, start, goal, **kw):
    fingers = tuple(slots)
    return GaitProblem(
        fingers=fingers,
        slots={f: tuple(s) for f, s in slots.items()},
        start=tuple(start[f] for f in fingers),
        goal=tuple(goal[f] for f in fingers),
        friction=FRICTION,
        **kw,
    )


def greedy_trap():
    """Moving A first (greedy's choice) strands B; moving B first works."""
    slots = {
        "A": [slot("A", "initial", "+x"), slot("A", "final", "+z")],
        "B": [slot("B", "initial", "+y"), slot("B", "final", "+x", tilt_deg=-8)],
        "C": [slot("C", "initial", "-x")],
        "D": [slot("D", "initial", "-y")],
    }
    return problem(slots, dict(A=0, B=0, C=0, D=0), dict(A=1, B=1, C=0, D=0))


def deadlock(with_intermediate):
    """Two fingers must form a new pair while each is part of the only other pair."""
    slots = {
        "A": [slot("A", "initial", "+x"), slot("A", "final", "+z")],
        "B": [slot("B", "initial", "-x")],
        "C": [slot("C", "initial", "+y"), slot("C", "final", "-z")],
        "D": [slot("D", "initial", "-y")],
    }
    if with_intermediate:
        slots["B"].append(slot("B", "int0", (0.15, 0.0, -1.0)))
    return problem(slots, dict(A=0, B=0, C=0, D=0), dict(A=1, B=LIFTED, C=1, D=LIFTED))


def recheck(prob, seq):
    """Independent re-check: single-finger steps, all states force closure, keys right."""
    assert seq.nodes[0] == prob.start and seq.nodes[-1] == prob.goal
    metrics = []
    for u, v in zip(seq.nodes, seq.nodes[1:]):
        assert sum(a != b for a, b in zip(u, v)) == 1
        changed = next(i for i in range(len(u)) if u[i] != v[i])
        assert LIFTED in (u[changed], v[changed])
    for v in seq.nodes:
        c = grasp_closure(prob.patches(v), FRICTION)
        assert c.is_force_closure
        metrics.append(c.metric)
    assert seq.bottleneck == pytest.approx(min(metrics), rel=1e-9, abs=1e-12)
    assert seq.mean_metric == pytest.approx(np.mean(metrics), rel=1e-9, abs=1e-12)


def test_greedy_is_stuck_where_graph_search_succeeds():
    """The thesis's greedy Algorithm 2 fails on an order-sensitive pair; graph search solves it."""
    prob = greedy_trap()
    G = build_graph(prob)
    with pytest.raises(NoSequenceError, match="greedy"):
        greedy(G)
    best = search(G, k=3)
    assert best, "graph search found no sequence"
    recheck(prob, best[0])
    assert best[0].order(prob)[:2] == ("B:lift", "B:land>final")


def test_intermediate_contact_unlocks_a_deadlock():
    """Without intermediate slots no sequence exists; one intermediate contact solves it."""
    G = build_graph(deadlock(with_intermediate=False))
    assert search(G, k=1) == []
    err = explain_failure(G, intermediate_tried=False)
    assert "intermediate" in str(err) and err.report["closest"]
    prob = deadlock(with_intermediate=True)
    best = search(build_graph(prob), k=1)
    assert best
    recheck(prob, best[0])
    assert any(a == "B:land>int0" for a in best[0].order(prob))


def test_search_matches_brute_force_ranking():
    """The best sequence's (bottleneck, length) equals the best over all simple paths."""
    prob = greedy_trap()
    G = build_graph(prob)
    best = search(G, k=5)
    brute = []
    for path in nx.all_simple_paths(G, prob.start, prob.goal, cutoff=10):
        m = [G.nodes[v]["metric"] for v in path]
        acts = [(G.edges[u, v]["finger"], G.edges[u, v]["action"]) for u, v in zip(path, path[1:])]
        # A landing right after the same finger's lift completes that gait.
        gaits = sum(not (a[1] == "land" and p == (a[0], "lift")) for p, a in zip([None] + acts, acts))
        brute.append((-min(m), gaits, len(path) - 1))
    assert best[0].rank_key[:3] == pytest.approx(min(brute))
    keys = [s.rank_key for s in best]
    assert keys == sorted(keys)
    assert len({s.nodes for s in best}) == len(best)
    for s in best:
        recheck(prob, s)


def test_graph_nodes_are_valid_and_blocked_are_not():
    """Every graph node is force closure; every blocked node is not (re-checked)."""
    prob = deadlock(with_intermediate=True)
    G = build_graph(prob)
    for v in G.nodes:
        assert grasp_closure(prob.patches(v), FRICTION).is_force_closure
    for v, reason in G.graph["blocked"].items():
        assert reason == "not force closure"
        assert not grasp_closure(prob.patches(v), FRICTION).is_force_closure
    for u, v, data in G.edges(data=True):
        assert data["action"] in ("lift", "land")


def test_removable_matches_algorithm_one():
    """Node 'removable' equals dropping each finger and re-testing closure."""
    prob = greedy_trap()
    G = build_graph(prob)
    for v in G.nodes:
        patches = prob.patches(v)
        expected = {f for f in prob.fingers if f not in patches}
        expected |= {f for f in patches if grasp_closure({g: p for g, p in patches.items() if g != f}, FRICTION).is_force_closure}
        assert G.nodes[v]["removable"] == frozenset(expected)


def test_collision_predicate_removes_states():
    """A pairwise collision predicate keeps colliding states out of the graph."""
    base = greedy_trap()
    # B at its final slot collides with A at its initial slot (both near +x).
    clash = lambda fa, sa, fb, sb: not ({(fa, sa), (fb, sb)} == {("A", 0), ("B", 1)})
    prob = GaitProblem(base.fingers, base.slots, base.start, base.goal, base.friction, compatible=clash)
    G = build_graph(prob)
    for v in G.nodes:
        assert not (v[0] == 0 and v[1] == 1)
    assert search(G, k=1) == []


def test_max_lifted_bound():
    """With at most one finger lifted, no graph node has two lifted fingers."""
    base = deadlock(with_intermediate=True)
    prob = GaitProblem(base.fingers, base.slots, base.start, base.goal, base.friction, max_lifted=1)
    G = build_graph(prob)
    assert all(sum(s == LIFTED for s in v) <= 1 for v in G.nodes)


def test_initial_grasp_not_force_closure_is_an_error():
    """An initial grasp that is not force closure is refused with a clear reason."""
    slots = {"A": [slot("A", "initial", "+x")], "B": [slot("B", "initial", "+y")]}
    with pytest.raises(NoSequenceError, match="initial grasp"):
        build_graph(problem(slots, dict(A=0, B=0), dict(A=0, B=LIFTED)))


def test_permuting_fingers_keeps_best_bottleneck():
    """Renaming/reordering fingers does not change the best bottleneck or step count."""
    prob = greedy_trap()
    best = search(build_graph(prob), k=1)[0]
    for perm in itertools.islice(itertools.permutations(range(4)), 1, 6):
        fingers = tuple(prob.fingers[i] for i in perm)
        p2 = GaitProblem(fingers, prob.slots, tuple(prob.start[i] for i in perm), tuple(prob.goal[i] for i in perm), FRICTION)
        b2 = search(build_graph(p2), k=1)[0]
        assert b2.bottleneck == pytest.approx(best.bottleneck, rel=1e-9)
        assert len(b2.actions) == len(best.actions)


# --------------------------------------------------------------------------- grip ranking

#: Weight of 0.3 N pulling down and sideways: the loads every state must hold.
LOADS = np.array([[0.0, 0.0, -0.3, 0.0, 0.0, 0.0], [0.3, 0.0, 0.0, 0.0, 0.0, 0.0]])


def loaded_deadlock(extra, budget=10.0):
    """The deadlock with two intermediate contacts for B (directions ``extra``) and loads."""
    slots = {
        "A": [slot("A", "initial", "+x"), slot("A", "final", "+z")],
        "B": [slot("B", "initial", "-x")] + [slot("B", f"int{i}", d) for i, d in enumerate(extra)],
        "C": [slot("C", "initial", "+y"), slot("C", "final", "-z")],
        "D": [slot("D", "initial", "-y")],
    }
    return problem(slots, dict(A=0, B=0, C=0, D=0), dict(A=1, B=LIFTED, C=1, D=LIFTED),
                   loads=LOADS, load_names=("down", "side"), max_grip_force_n=budget)


def brute_force_keys(G, prob, rank):
    """Rank keys of every simple start-goal path, by enumeration (networkx), sorted."""
    keys = []
    for path in nx.all_simple_paths(G, prob.start, prob.goal):
        m = [G.nodes[v]["metric"] for v in path]
        g = [G.nodes[v]["grip_force"] for v in path]
        acts = [(G.edges[u, v]["finger"], G.edges[u, v]["action"]) for u, v in zip(path, path[1:])]
        gaits = sum(not (a[1] == "land" and p == (a[0], "lift")) for p, a in zip([None] + acts, acts))
        if rank == "grip":
            keys.append((round(max(g), 6), gaits, -min(m), len(acts), -float(np.mean(m))))  # to 1 uN
        else:
            keys.append((-min(m), gaits, len(acts), -float(np.mean(m))))
    return sorted(keys)


def test_grip_ranking_picks_the_smaller_grip_bottleneck_where_metric_ranking_does_not():
    """On a hand-built problem the metric ranking's best sequence needs 0.76 N at its worst
    state, while another sequence needs only 0.68 N (with a smaller metric bottleneck): the
    grip ranking picks that one. Both rankings' top 6 equal the brute-force ranking of all
    simple paths (exactness), and every node's grip force re-checks as the largest
    min_grip_force over the loads."""
    prob = loaded_deadlock([(-0.811, 0.752, 0.253), (0.896, -0.345, -1.482)])
    G = build_graph(prob)
    for v, data in G.nodes(data=True):
        expected = max(min_grip_force(prob.patches(v), FRICTION, w) for w in LOADS)
        assert data["grip_force"] == pytest.approx(expected, rel=1e-9)
        assert set(data["grip_forces"]) == {"down", "side"}
    by_metric, by_grip = search(G, k=6), search(G, k=6, rank="grip")
    assert by_metric[0].nodes != by_grip[0].nodes
    assert by_grip[0].bottleneck_grip < by_metric[0].bottleneck_grip - 0.05
    assert by_grip[0].bottleneck < by_metric[0].bottleneck
    for found, rank in ((by_metric, "metric"), (by_grip, "grip")):
        assert [s.rank_key for s in found] == brute_force_keys(G, prob, rank)[:6]
        assert G.graph["search_exact"]
        for s in found:
            recheck(prob, s)
            assert s.bottleneck_grip == max(G.nodes[v]["grip_force"] for v in s.nodes)


@pytest.mark.parametrize("seed", range(4))
def test_search_is_exact_for_both_rankings_on_random_problems(seed):
    """Random intermediate contacts: the k best of `search` are the k best of all simple
    paths (brute force), for the metric and the grip ranking."""
    rng = np.random.default_rng(seed)
    prob = loaded_deadlock([tuple(rng.normal(size=3)) for _ in range(2)])
    G = build_graph(prob)
    for rank in ("metric", "grip"):
        brute = brute_force_keys(G, prob, rank)
        found = search(G, k=8, rank=rank)
        assert [s.rank_key for s in found] == brute[:8]
        assert len({s.nodes for s in found}) == len(found)


def test_grip_budget_blocks_states_and_grip_ranking_needs_a_load():
    """States over the per-finger budget are blocked with the reason; grip ranking on a
    problem without loads and an unknown rank are errors."""
    extra = [(-0.811, 0.752, 0.253), (0.896, -0.345, -1.482)]
    G = build_graph(loaded_deadlock(extra, budget=0.7))
    assert all(d["grip_force"] <= 0.7 for _, d in G.nodes(data=True))
    assert any("N per finger to hold the load" in r for r in G.graph["blocked"].values())
    best = search(G, k=1, rank="grip")[0]
    assert best.bottleneck_grip == pytest.approx(0.6839, abs=1e-3)
    plain = build_graph(deadlock(with_intermediate=True))
    with pytest.raises(InputError, match="grip ranking needs"):
        search(plain, k=1, rank="grip")
    with pytest.raises(UnknownNameError):
        search(plain, k=1, rank="fastest")


# --------------------------------------------------------------------------- lazy search, explanations


@pytest.mark.parametrize("seed", range(3))
def test_lazy_graph_ranks_exactly_like_the_full_graph(seed):
    """`LazyGraph.best` returns the same k best rank keys as `build_graph` + `search` (both
    rankings, brute-force-checked above), evaluates no more states than the full graph,
    and every returned state re-checks force closure."""
    rng = np.random.default_rng(seed)
    prob = loaded_deadlock([tuple(rng.normal(size=3)) for _ in range(3)])
    full = build_graph(prob)
    for rank in ("metric", "grip"):
        lazy = LazyGraph(prob, rank)
        got = lazy.best(6)
        # equal up to the last digits (a state's metric depends on the batch it was evaluated in)
        assert [s.rank_key for s in got] == [pytest.approx(s.rank_key, rel=1e-9, abs=1e-15) for s in search(full, k=6, rank=rank)]
        assert lazy.G.graph["search_exact"]
        assert len(lazy.ev.closure) <= len(full.graph["evaluator"].closure)
        for s in got:
            recheck(prob, s)


def test_lazy_graph_evaluates_only_the_states_the_search_reaches():
    """Five fingers around a sphere with four slots each (5^5 combinations): the best
    sequence equals the full graph's, found with fewer closure evaluations."""
    dirs = [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1)]
    rng = np.random.default_rng(7)
    slots = {}
    for k, d in enumerate(dirs):
        name = "ABCDE"[k]
        near = [tuple(np.array(d) + 0.35 * rng.normal(size=3)) for _ in range(3)]
        slots[name] = [slot(name, "initial", d)] + [slot(name, lab, v) for lab, v in zip(("final", "int0", "int1"), near)]
    prob = problem(slots, {f: 0 for f in slots}, {f: 1 for f in slots})
    full = build_graph(prob)
    want = search(full, k=1)
    lazy = LazyGraph(prob)
    got = lazy.best(1)
    assert want and [s.rank_key for s in got] == [pytest.approx(s.rank_key, rel=1e-9, abs=1e-15) for s in want]
    assert len(lazy.ev.closure) < len(full.graph["evaluator"].closure)
    recheck(prob, got[0])


def test_extended_problem_reuses_caches_and_matches_a_fresh_search():
    """A round of intermediate contacts (slots appended) on the evaluator of the previous
    round gives the same ranking as a fresh search; a problem that renumbers slots is refused."""
    first = LazyGraph(deadlock(with_intermediate=False))
    assert first.best(1) == [] and first.complete
    cached = len(first.ev.closure)
    bigger = deadlock(with_intermediate=True)
    grown = GaitProblem(bigger.fingers, {f: first.problem.slots[f] + tuple(bigger.slots[f][len(first.problem.slots[f]):])
                                         for f in bigger.fingers}, bigger.start, bigger.goal, FRICTION)
    again = LazyGraph(grown, evaluator=first.ev)
    fresh = LazyGraph(bigger)
    assert [s.rank_key for s in again.best(3)] == [pytest.approx(s.rank_key, rel=1e-9, abs=1e-15) for s in fresh.best(3)]
    assert len(again.ev.closure) > cached
    with pytest.raises(InputError, match="appending slots"):
        LazyGraph(bigger, evaluator=first.ev)


def test_failure_is_explained_in_words():
    """No Python dicts in the message; the finger that cannot be lifted is named with the
    grasp left without it and its metric, a refused landing names the finger it would
    collide with, and a finger free in both grasps is never mentioned."""
    slots = {**{f: list(s) for f, s in deadlock(False).slots.items()}, "E": []}
    prob = GaitProblem(tuple(slots), {f: tuple(s) for f, s in slots.items()}, (0, 0, 0, 0, LIFTED),
                       (1, LIFTED, 1, LIFTED, LIFTED), FRICTION)
    lazy = LazyGraph(prob)
    assert lazy.best(1) == []
    err = explain_failure(lazy.G, intermediate_tried=False)
    text = str(err)
    assert "{" not in text and "E " not in text and "E," not in text
    assert "there A cannot be lifted: without it the grasp (B, C) is not force closure, metric -" in text
    assert "ends 2 finger(s) from the final grasp in: A initial, B initial, C final, D lifted" in text
    assert err.report["closest"]["C"] == "final"
    base = greedy_trap()
    clash = lambda fa, sa, fb, sb: not ({(fa, sa), (fb, sb)} == {("A", 0), ("B", 1)})
    lazy = LazyGraph(GaitProblem(base.fingers, base.slots, base.start, base.goal, FRICTION, compatible=clash))
    assert lazy.best(1) == []
    err = explain_failure(lazy.G, intermediate_tried=True)
    assert "B cannot land on its final contact: it would collide with A" in str(err)
    assert err.report["blockers"][0] in ("A", "B")


def test_lazy_graph_honours_removed_edges_and_the_lift_bound():
    """A move removed for good (a finger path that cannot be planned) is never used again,
    and the ranking then equals the full graph's without that edge; with ``max_lifted`` no
    explored state has more fingers lifted."""
    prob = greedy_trap()
    lazy = LazyGraph(prob)
    first = lazy.best(3)[0]
    u, v = first.nodes[0], first.nodes[1]
    lazy.remove_edge(u, v)
    again = lazy.best(3)
    full = build_graph(prob)
    full.remove_edge(u, v)
    assert again and all((u, v) not in zip(s.nodes, s.nodes[1:]) for s in again)
    assert [s.rank_key for s in again] == [pytest.approx(s.rank_key, rel=1e-9, abs=1e-15) for s in search(full, k=3)]
    bound = GaitProblem(prob.fingers, prob.slots, prob.start, prob.goal, FRICTION, max_lifted=1)
    bounded = LazyGraph(bound)
    found = bounded.best(2)
    assert found and all(sum(s == LIFTED for s in v) <= 1 for v in bounded.G.nodes)
    assert [s.rank_key for s in found] == [pytest.approx(s.rank_key, rel=1e-9, abs=1e-15)
                                           for s in search(build_graph(bound), k=2)]
    for s in found:
        recheck(prob, s)


def test_fewest_gaits_to_goal_is_exact():
    """gaits_to_goal (the search's gait bound): from the start, the fewest gaits over every
    simple start-goal path (brute force), on random problems, over the whole graph and over
    the states no worse than the best bottleneck."""
    from planner.gait_search import gaits_to_goal

    checked = 0
    for seed in range(8):
        rng = np.random.default_rng(seed)
        prob = loaded_deadlock([tuple(rng.normal(size=3)) for _ in range(2)])
        G = build_graph(prob)
        paths = list(nx.all_simple_paths(G, prob.start, prob.goal)) if prob.goal in G else []
        if not paths:
            assert (prob.start, None) not in gaits_to_goal(G, prob.goal)
            continue
        checked += 1
        best = max(min(G.nodes[v]["metric"] for v in path) for path in paths)

        def gaits(path):
            acts = [(G.edges[u, v]["finger"], G.edges[u, v]["action"]) for u, v in zip(path, path[1:])]
            return sum(not (a[1] == "land" and p == (a[0], "lift")) for p, a in zip([None] + acts, acts))

        assert gaits_to_goal(G, prob.goal)[(prob.start, None)] == min(map(gaits, paths))
        allowed = {v for v in G if G.nodes[v]["metric"] >= best}
        assert gaits_to_goal(G, prob.goal, allowed)[(prob.start, None)] == min(
            gaits(p) for p in paths if all(v in allowed for v in p))
    assert checked >= 3


def test_search_ranks_many_near_tied_orders_exactly():
    """Five fingers around the ball, each moving to a contact a few degrees away: the 120
    orders of five lift-land gaits, and many more with interleaved lifts, nearly tie. With
    the mean metric in its key and the exact gait bound the search stays exact within
    1 500 expansions: its best sequence beats or equals every one of the 120 orders, and the
    three it returns come in rank order."""
    dirs = {"+x": (1, 0, 0.05), "-x": (-1, 0, 0.05), "+y": (0, 1, 0.05), "-y": (0, -1, 0.05), "+z": (0.05, 0, 1)}
    slots = {f"F{i}": [slot(f"F{i}", "initial", d), slot(f"F{i}", "final", v)] for i, (d, v) in enumerate(dirs.items())}
    prob = problem(slots, {f: 0 for f in slots}, {f: 1 for f in slots})
    G = build_graph(prob)
    found = search(G, k=3, max_expansions=1500)
    assert len(found) == 3 and G.graph["search_exact"]
    for s in found:
        recheck(prob, s)
    orders = []
    for order in itertools.permutations(range(5)):
        node, path = list(prob.start), [prob.start]
        for i in order:
            node[i] = LIFTED
            path.append(tuple(node))
            node[i] = 1
            path.append(tuple(node))
        if all(G.has_edge(u, v) for u, v in zip(path, path[1:])):
            m = [G.nodes[v]["metric"] for v in path]
            orders.append((-min(m), 5, 10, -float(np.mean(m))))
    assert len(orders) > 50 and found[0].rank_key <= min(orders)
    assert [s.rank_key for s in found] == sorted(s.rank_key for s in found)


def test_moves_taken_out_later_are_named_not_called_unexplored():
    """A finger whose lifts were taken out after they failed later (a finger path, the
    simulator: `LazyGraph.remove_edge`) in the initial grasp and with A lifted, and refused by
    the closure test in the other states (C or D lifted), is said to be both (each where it
    happened), not the search to have stopped before it."""
    slots = {"A": [slot("A", "initial", "+x")], "B": [slot("B", "initial", "-x"), slot("B", "final", "-x", tilt_deg=20)],
             "C": [slot("C", "initial", "+y")], "D": [slot("D", "initial", "-y")]}
    prob = problem(slots, dict(A=0, B=0, C=0, D=0), dict(A=0, B=1, C=0, D=0))
    lazy = LazyGraph(prob)
    assert grasp_closure(prob.patches((0, LIFTED, 0, 0)), FRICTION).is_force_closure  # B may lift in the model
    taken = []
    for _ in range(10):
        found = lazy.best(1)
        if not found:
            break
        s = found[0]
        i = [f for f, _ in s.actions].index("B")
        lazy.remove_edge(s.nodes[i], s.nodes[i + 1])
        taken.append((s.nodes[i], s.nodes[i + 1]))
    assert taken and lazy.best(1) == []
    assert lazy.G.graph["removed_moves"] == taken
    text = str(explain_failure(lazy.G, intermediate_tried=True))
    assert "B's lift in the initial grasp and 1 other state (e.g. A lifted, B initial, C initial, D initial) was " \
           "taken out after failing later" in text
    assert "B cannot be lifted in any other reached state (e.g. A initial, B initial, C lifted, D initial): without " \
           "it the grasp (A, D) is not force closure" in text
    assert not grasp_closure(prob.patches((0, LIFTED, LIFTED, 0)), FRICTION).is_force_closure
    assert "--time-limit" not in text and "stopped" not in text


def test_a_finger_whose_moves_were_not_taken_out_is_not_said_to_have_lost_them():
    """Moves taken out later (`LazyGraph.remove_edge`) are attributed to the finger they move
    only: with A's lift in the initial grasp taken out and the search stopped after the first
    states (B's lift found, never taken out), A's moves are said to be taken out and B is
    said to be unexplored (the search stopped), not the other way round."""
    slots = {"A": [slot("A", "initial", "+x"), slot("A", "final", "+x", tilt_deg=20)],
             "B": [slot("B", "initial", "-x"), slot("B", "final", "-x", tilt_deg=20)],
             "C": [slot("C", "initial", "+y")], "D": [slot("D", "initial", "-y")]}
    prob = problem(slots, dict(A=0, B=0, C=0, D=0), dict(A=1, B=1, C=0, D=0))
    lazy = LazyGraph(prob)
    assert lazy.best(1, max_expansions=2) == []  # stopped: the start expanded, its successors evaluated
    lifts = {prob.fingers[[a != b for a, b in zip(prob.start, w)].index(True)]: w for w in lazy.G.successors(prob.start)}
    assert {"A", "B"} <= set(lifts)
    lazy.remove_edge(prob.start, lifts["A"])
    text = str(explain_failure(lazy.G, intermediate_tried=True))
    assert "taken out after failing later: lift A in the initial grasp" in text
    assert "A still has to move: the moves the search found for it were taken out" in text
    assert "B still has to move and no such move was refused: the search stopped" in text
    assert "A, B still have to move" not in text
