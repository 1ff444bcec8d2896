"""Ranked search for finger-gaiting sequences over the grasp-state graph (`planner.graph`).

`search` ranks paths in one of two ways (`RANKS`):

* ``metric`` (the thesis): (1) the bottleneck, the worst closure metric along the path,
  larger is better; (2) fewer gait steps (then fewer edges); (3) a larger mean metric.
* ``grip`` (for execution): (1) the grip bottleneck, the largest grip force any state of the
  path needs, smaller is better (to 1 uN: `GRIP_RANK_DECIMALS`); (2) fewer gait steps; (3)
  the metric ranking (larger metric bottleneck, fewer edges, larger mean metric).

The search is exact for both: it returns the k best simple paths under the key.
`LazyGraph` gives the same k best without building the whole graph: a best-first search
over the implicit graph that evaluates a state only when it is popped (see its docstring
for why the ranking stays exact). `greedy` is the thesis's Algorithm 2, kept as the
baseline. A path found is a `GaitSequence`.

Pure numpy/networkx, like `planner.graph`.
"""

from __future__ import annotations

import heapq
import itertools
import time
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import networkx as nx
import numpy as np

from planner.errors import InputError, NoSequenceError, UnknownNameError
from planner.graph import LIFTED, Evaluator, GaitProblem, Node, add_node, seed_graph, within_lift_bound
from planner.plan_data import order_entry

RANKS = ("metric", "grip")
"""Sequence rankings of `search` (module docstring)."""

#: Grip forces (N per finger) are ranked rounded to this many decimals (1 uN): states whose
#: programs have the same optimum tie (but for the rare pair straddling a rounding boundary)
#: and the ranking's next keys (gait steps, the closure metric) decide, not HiGHS's last
#: digits (1e-10 N apart, and from where its simplex started: `planner.lp.solve_highs_rhs`).
#: Those digits also made the lazy search expand every state a hair below the best sequence's
#: grip, whatever its gait steps. A sequence ranked first may so need up to 0.5 uN more than
#: another.
GRIP_RANK_DECIMALS = 6


def ranked_grip(g: float | None) -> float | None:
    """A grip force as the ranking compares it (`GRIP_RANK_DECIMALS`)."""
    return None if g is None else round(g, GRIP_RANK_DECIMALS)


@dataclass(frozen=True)
class GaitSequence:
    """A path through the graph with its ranking keys.

    Attributes:
        nodes: the states, start to goal.
        actions: (finger, action) per edge.
        bottleneck: worst closure metric over the states.
        mean_metric: mean closure metric over the states.
        gait_steps: finger gaits: a lift and the landing of the same finger right after it
            are one gait; a lift or a landing on its own is one gait too.
        bottleneck_grip: the largest grip force (N per finger) any state needs to hold the
            problem's loads; None when the problem has no load.
        rank: the ranking ``rank_key`` follows (`RANKS`).
    """

    nodes: tuple[Node, ...]
    actions: tuple[tuple[str, str], ...]
    bottleneck: float
    mean_metric: float
    gait_steps: int = field(default=0)
    bottleneck_grip: float | None = None
    rank: str = "metric"

    @property
    def rank_key(self) -> tuple:
        """Sort key, smaller is better. ``metric``: larger bottleneck, then fewer gait steps
        (then edges), then larger mean. ``grip``: smaller grip bottleneck, then fewer gait
        steps, then the metric ranking (larger bottleneck, fewer edges, larger mean)."""
        if self.rank == "grip":
            return (ranked_grip(self.bottleneck_grip), self.gait_steps, -self.bottleneck, len(self.actions),
                    -self.mean_metric)
        return (-self.bottleneck, self.gait_steps, len(self.actions), -self.mean_metric)

    def order(self, problem: GaitProblem) -> tuple[str, ...]:
        """Compact ordering: "finger:lift" / "finger:land>label" per edge."""
        return tuple(order_entry(finger, "land", problem.labels(node)[finger]) if action == "land"
                     else order_entry(finger, "lift") for (finger, action), node in zip(self.actions, self.nodes[1:]))


def _gait_increment(prev: tuple[str, str] | None, action: tuple[str, str]) -> int:
    """1 when ``action`` starts a new gait; 0 for a landing right after its own lift."""
    return 0 if action[1] == "land" and prev == (action[0], "lift") else 1


def _sequence(G: nx.DiGraph, nodes: Sequence[Node], rank: str = "metric") -> GaitSequence:
    metrics = [G.nodes[v]["metric"] for v in nodes]
    grips = [G.nodes[v].get("grip_force") for v in nodes]
    actions = tuple((G.edges[u, v]["finger"], G.edges[u, v]["action"]) for u, v in zip(nodes, nodes[1:]))
    return GaitSequence(
        nodes=tuple(nodes),
        actions=actions,
        bottleneck=float(min(metrics)),
        mean_metric=float(np.mean(metrics)),
        gait_steps=sum(_gait_increment(prev, act) for prev, act in zip((None,) + actions, actions)),
        bottleneck_grip=None if any(g is None for g in grips) else float(max(grips)),
        rank=rank,
    )


def _bottleneck_to_goal(G: nx.DiGraph, goal: Node, cost: Mapping[Node, float]) -> dict[Node, float]:
    """For every node v that reaches the goal: the smallest possible largest ``cost`` over
    the nodes of a walk from v to the goal (both ends included). Dijkstra on the reversed
    graph with max in place of +; a lower bound for any simple path too."""
    best = {goal: cost[goal]}
    heap = [(cost[goal], goal)]
    done = set()
    while heap:
        d, v = heapq.heappop(heap)
        if v in done:
            continue
        done.add(v)
        for u in G.predecessors(v):
            du = max(cost[u], d)
            if du < best.get(u, np.inf):
                best[u] = du
                heapq.heappush(heap, (du, u))
    return best


def gaits_to_goal(G: nx.DiGraph, goal: Node, allowed=None) -> dict[tuple[Node, str | None], int]:
    """Fewest gaits from each state to the goal (within ``allowed`` states when given),
    keyed (state, finger whose lift led to it or None): a landing right after the same
    finger's lift is free (`_gait_increment`). Look a state up under its lifted finger and
    under None, and take the smaller (a 0-1 Dijkstra on the reversed graph)."""
    if goal not in G or (allowed is not None and goal not in allowed):
        return {}
    dist = {(goal, None): 0}
    heap = [(0, 0, goal, None)]
    tie = itertools.count(1)
    done = set()
    while heap:
        d, _, w, lw = heapq.heappop(heap)
        if (w, lw) in done:
            continue
        done.add((w, lw))
        for u in G.predecessors(w):
            if allowed is not None and u not in allowed:
                continue
            e = G.edges[u, w]
            f, action = e["finger"], e["action"]
            if lw is not None and (action, f) != ("lift", lw):  # (w, None) bounds every (w, f) too
                continue
            steps = [((u, None), d + 1)] + ([((u, f), d)] if action == "land" else [])
            for state, du in steps:
                if du < dist.get(state, np.inf):
                    dist[state] = du
                    heapq.heappush(heap, (du, next(tie), *state))
    return dist


def search(G: nx.DiGraph, k: int = 1, *, rank: str = "metric", max_expansions: int = 200_000) -> list[GaitSequence]:
    """The best ``k`` distinct gait sequences from the graph's start to its goal.

    Ranking (``rank``, `RANKS`): ``metric`` sorts by ``(-bottleneck, gait steps, edges,
    -mean metric)``, ``grip`` by ``(grip bottleneck, gait steps, -bottleneck, edges, -mean
    metric)`` (`GaitSequence.rank_key`). ``grip`` needs the nodes' ``grip_force`` (a
    problem with a load).

    Exact best-first enumeration of simple paths (A*). A partial path is keyed by a lower
    bound of the key of every goal path extending it, component by component: each
    bottleneck part is the worse of the path's own and the best bottleneck any walk from
    its end to the goal can have (`_bottleneck_to_goal`); gait steps add one per finger
    not yet at its goal slot (less one when the last edge lifted a finger whose landing
    would complete that gait); edges add the shortest edge count to the goal. Every part
    is a lower bound and complete paths are keyed exactly, so goal paths come off the heap
    in key order (every prefix of a goal path is keyed no higher than the path itself).
    The mean metric is keyed too (for paths of the same edge count: the metrics so far plus
    the graph's best metric for each state still to come), so that the many orderings of
    the same moves that tie on everything else are cut once k paths are found; among equal
    keys the longer partial path goes first. The search stops once the next partial path
    is keyed above the k-th goal path found; results are sorted by the full key. No
    partial path is dropped for any other reason, so the result is exact unless
    ``max_expansions`` partial paths were expanded first (then it is the best found and
    ``G.graph["search_exact"]`` is False; it is True otherwise).

    Returns:
        Up to k sequences, best first; empty when the goal is unreachable.

    Raises:
        InputError: unknown ``rank``, or ``rank="grip"`` on a graph without grip forces.
    """
    if rank not in RANKS:
        raise UnknownNameError("rank", rank, RANKS)
    G.graph["search_exact"] = True
    start, goal = G.graph["start"], G.graph["goal"]
    if goal not in G or start not in G:
        return []
    neg_metric = {v: -G.nodes[v]["metric"] for v in G.nodes}
    hb_metric = _bottleneck_to_goal(G, goal, neg_metric)
    if start not in hb_metric:
        return []
    grip = hb_grip = None
    if rank == "grip":
        grip = {v: ranked_grip(G.nodes[v].get("grip_force")) for v in G.nodes}
        if any(g is None for g in grip.values()):
            raise InputError("grip ranking needs the grip force of every state: plan with a gravity (a load)")
        hb_grip = _bottleneck_to_goal(G, goal, grip)
    hops = nx.single_target_shortest_path_length(G, goal)
    hops = dict(hops) if not isinstance(hops, dict) else hops
    # fewest gaits to the goal, over the whole graph and over the states whose primary cost
    # (the first ranking component) is at most the best bottleneck's: a path that can still
    # reach the goal with that bottleneck is bounded by the second, tighter table
    primary, hb_primary = (neg_metric, hb_metric) if grip is None else (grip, hb_grip)
    best_primary = hb_primary[start]
    gaits_all = gaits_to_goal(G, goal)
    gaits_best = gaits_to_goal(G, goal, {v for v, c in primary.items() if c <= best_primary})

    def gaits_left(v: Node, last, p: float) -> int:
        table = gaits_best if max(p, hb_primary[v]) <= best_primary else gaits_all
        lifted = last[0] if last is not None and last[1] == "lift" else None
        return min(table.get((v, lifted), np.inf), table.get((v, None), np.inf))

    top_metric = max(-m for m in neg_metric.values())

    def key(neg_b, g_max, gaits, n_edges, total, v, last) -> tuple:
        b = max(neg_b, hb_metric[v])
        g = gaits + gaits_left(v, last, neg_b if grip is None else g_max)
        e = n_edges + hops[v]
        # the mean metric can be at most: the path's metrics so far, the best metric of the
        # graph for each state still to come (exact once the path is complete)
        mean = -(total + hops[v] * top_metric) / (e + 1)
        if rank == "grip":
            return (max(g_max, hb_grip[v]), g, b, e, mean)
        return (b, g, e, mean)

    tie = itertools.count()
    g0 = grip[start] if grip is not None else 0.0
    m0 = -neg_metric[start]
    # equal keys: the longer partial path first (depth-first along a plateau of equal keys)
    heap = [(key(neg_metric[start], g0, 0, 0, m0, start, None), 0, next(tie), neg_metric[start], g0, 0, 0, m0, (start,), None)]
    found: list[GaitSequence] = []
    bound = None  # key of the k-th goal path found (its mean a hair lower: float sums)
    expansions = 0
    while heap:
        f, _, _, neg_b, g_max, gaits, n_edges, total, path, last = heapq.heappop(heap)
        if bound is not None and f > bound:
            break
        v = path[-1]
        if v == goal:
            found.append(_sequence(G, path, rank))
            if len(found) >= k:
                found.sort(key=lambda s: s.rank_key)
                bound = found[k - 1].rank_key[:-1] + (found[k - 1].rank_key[-1] + 1e-9,)
            continue
        if expansions >= max_expansions:
            G.graph["search_exact"] = False
            break
        expansions += 1
        on_path = set(path)
        for w in sorted(G.successors(v)):
            if w in on_path or w not in hops:
                continue
            e = G.edges[v, w]
            act = (e["finger"], e["action"])
            nb = max(neg_b, neg_metric[w])
            gm = max(g_max, grip[w]) if grip is not None else 0.0
            gw = gaits + _gait_increment(last, act)
            tw = total - neg_metric[w]
            fw = key(nb, gm, gw, n_edges + 1, tw, w, act)
            if bound is not None and fw > bound:
                continue
            heapq.heappush(heap, (fw, -(n_edges + 1), next(tie), nb, gm, gw, n_edges + 1, tw, path + (w,), act))
    found.sort(key=lambda s: s.rank_key)
    return found[:k]


def _gaits_lower_bound(start: Node, goal: Node, v: Node) -> int:
    """Fewest gaits any start-goal path through ``v`` can have: every finger whose slot
    differs between start and v needs a gait before v, every finger differing between v and
    goal one after it; at most one gait (a lift right before v and that finger's landing
    right after it) is counted twice."""
    before = sum(a != b for a, b in zip(start, v))
    after = sum(a != b for a, b in zip(v, goal))
    straddle = any(s == LIFTED and a != LIFTED and g != LIFTED for a, s, g in zip(start, v, goal))
    return before + after - int(straddle)



#: The graph's lists of moves taken out after the search found them, by why (`LazyGraph`:
#: ``remove_edge``, ``remove_state``, ``forbid``); a resumed search carries them over.
REMOVED_RECORDS = ("removed_moves", "removed_with_state", "removed_stuck")


class LazyGraph:
    """The state graph grown lazily, best-first, as far as the ranked search needs it.

    States are expanded in order of (their best possible primary cost from the start, a
    lower bound of the gait steps of any path through them): the primary cost of a path is
    its ranking's bottleneck (``metric``: minus the worst closure metric; ``grip``: the
    largest grip force), and a state's is the smallest bottleneck over the paths reaching
    it (a widest-path Dijkstra). A generated state is queued unevaluated, keyed by its
    parent's value (a lower bound of its own); closure, collisions and grip force are
    evaluated only when it is popped (one batch closure call per half batch, with the caches of
    `Evaluator`), then it is queued again with its true key, and expanded when popped
    again. States keyed above what the ranking needs are never evaluated.

    Exactness: once every queued state keyed at most (c, g) is popped, every path whose
    (primary, gait steps) is at most (c, g) lies wholly in the explored graph (each of its
    states has a primary cost <= c and a gait bound <= g, and so had its lower-bound key
    when its predecessor on the path generated it). `best` goes on until that holds for the
    k-th sequence `search` finds on the explored graph, so its ranking equals the ranking
    over the whole graph (`planner.graph.build_graph`), up to ``max_expansions``.

    Attributes:
        G: the explored graph (same attributes as `planner.graph.build_graph`'s, without ``removable``
            until `planner.graph.annotate_removable`); ``G.graph["expanded"]`` counts expanded states.
        complete: True when every reachable valid state has been expanded.
        timed_out: True when the deadline stopped an expansion.
    """

    BATCH = 16
    """States popped per batch (evaluated together: `planner.graph.Evaluator.evaluate_states`)."""

    def __init__(self, problem: GaitProblem, rank: str = "metric", evaluator: Evaluator | None = None,
                 deadline: float | None = None, helpers: int = 0):
        if rank not in RANKS:
            raise UnknownNameError("rank", rank, RANKS)
        if rank == "grip" and not problem.all_loads():
            raise InputError("grip ranking needs the grip force of every state: plan with a gravity (a load)")
        self.problem, self.rank, self.deadline = problem, rank, deadline
        self.G = seed_graph(problem, evaluator)
        self.ev: Evaluator = self.G.graph["evaluator"]
        self.ev.helpers = helpers
        self.G.graph["expanded"] = 0
        self.G.graph["blocked_moves"] = []  # (from state, finger index, action, to state) of refused moves
        self.removed: set[tuple[Node, Node]] = set()
        self.removed_states: set[Node] = set()
        self.forbidden: set[tuple[int, int]] = set()  # (finger index, slot): never lifted off nor landed on
        self.value = {problem.start: self._cost(problem.start)}
        self._heap = [self._key(problem.start)]
        self.expanded: set[Node] = set()
        self._pending: dict[Node, list] = {}  # generated, not yet evaluated: its (parent, finger index, action)s
        self.timed_out = False

    def _cost(self, v: Node) -> float:
        data = self.G.nodes[v]
        return -data["metric"] if self.rank == "metric" else ranked_grip(data["grip_force"])

    def _key(self, v: Node) -> tuple:
        return (self.value[v], _gaits_lower_bound(self.problem.start, self.problem.goal, v), v)

    @property
    def complete(self) -> bool:
        return self._top() is None

    def _top(self) -> tuple | None:
        """(value, gait bound) of the next state to expand, dropping stale heap entries."""
        while self._heap:
            value, _, v = self._heap[0]
            if v not in self.expanded and v not in self.G.graph["blocked"] and value <= self.value[v]:
                return self._heap[0][:2]
            heapq.heappop(self._heap)
        return None

    def _expand(self, bound: tuple, budget: int | None) -> int:
        """Pop states keyed at most ``bound`` (value, gait bound): a state not yet evaluated
        is evaluated (collisions, then closure and grip: `planner.graph.Evaluator.evaluate_states`) and pushed
        again with its true key, an evaluated one is expanded: its successors are pushed
        unevaluated, keyed by the best value they can have (their parent's). Returns how many
        states were expanded."""
        p, G, ev, done = self.problem, self.G, self.ev, 0
        blocked, pending = G.graph["blocked"], self._pending
        while self._top() is not None and self._top() <= bound:
            if budget is not None and done >= budget:
                break
            if self.deadline is not None and time.perf_counter() > self.deadline:
                self.timed_out = True
                break
            grow, fresh = [], []
            while self._top() is not None and self._top() <= bound and len(grow) + len(fresh) < self.BATCH:
                v = heapq.heappop(self._heap)[2]
                if v in G:
                    self.expanded.add(v)
                    grow.append(v)
                elif v not in blocked and v not in fresh:
                    fresh.append(v)
            # collisions first (cached per slot pair): colliding states need no closure, and
            # only force-closure states need the load test (half of the batch in a helper process)
            ev.evaluate_states([w for w in fresh if within_lift_bound(p, w) and ev.collision_free(w)])
            for w in fresh:
                reason = ev.blocked_reason(w)
                parents = pending.pop(w)
                if reason is not None:
                    blocked[w] = reason
                    G.graph["blocked_moves"].extend((u, i, action, w) for u, i, action in parents)
                    continue
                add_node(G, ev, w)
                for u, i, action in parents:
                    G.add_edge(u, w, finger=p.fingers[i], action=action)
                self.value[w] = max(self.value[w], self._cost(w))
                heapq.heappush(self._heap, self._key(w))
            for u in grow:
                for i, action, w in p.neighbours(u):
                    if (u, w) in self.removed or w in self.removed_states:
                        continue
                    if self.forbidden and (i, u[i] if action == "lift" else w[i]) in self.forbidden:
                        continue
                    if w in blocked:
                        G.graph["blocked_moves"].append((u, i, action, w))
                        continue
                    if w in G:
                        G.add_edge(u, w, finger=p.fingers[i], action=action)
                        c = max(self.value[u], self._cost(w))
                    else:  # evaluated when popped: its value is at least its parent's
                        pending.setdefault(w, []).append((u, i, action))
                        c = self.value[u]
                    if c < self.value.get(w, np.inf):
                        self.value[w] = c
                        heapq.heappush(self._heap, self._key(w))
            done += len(grow)
        G.graph["expanded"] = len(self.expanded)
        return done

    def _primary(self, s: GaitSequence) -> float:
        return -s.bottleneck if self.rank == "metric" else ranked_grip(s.bottleneck_grip)

    def best(self, k: int = 1, *, max_expansions: int = 200_000, alternative_expansions: int = 5_000) -> list[GaitSequence]:
        """The k best sequences (`search`'s ranking), growing the graph as needed; the
        evaluator's helper process (``helpers``, `planner.graph.Evaluator.evaluate_states`) ends
        with the call.

        The best one is exact unless ``max_expansions`` states were expanded or the deadline
        passed first; alternatives 2..k are exact unless completing them needed more than
        ``alternative_expansions`` further states. ``G.graph["search_exact"]`` says whether
        all k are. Empty when the goal cannot be reached (then `complete` is True, unless a
        limit stopped the growth).
        """
        try:
            return self._best(k, max_expansions, alternative_expansions)
        finally:
            self.ev.close()

    def _best(self, k: int, max_expansions: int, alternative_expansions: int) -> list[GaitSequence]:
        G, goal, inf = self.G, self.problem.goal, (np.inf, np.inf)

        def more(bound, budget) -> bool:
            """Expand up to ``bound``; False when nothing was left to do or a limit stopped it."""
            left, top = max_expansions - len(self.expanded), self._top()
            if top is None or top > bound or self.timed_out or left <= 0 or budget <= 0:
                return False
            self._expand(bound, min(left, budget))
            return True

        def key(s: GaitSequence) -> tuple:
            return (-s.bottleneck if self.rank == "metric" else ranked_grip(s.bottleneck_grip), s.gait_steps)

        exact = True
        while goal not in G and more(inf, self.BATCH):
            pass
        found = []
        while goal in G:  # the best sequence: expand until nothing keyed below it is left
            found = search(G, k, rank=self.rank, max_expansions=max_expansions)
            exact = exact and G.graph["search_exact"]
            if not found or not more(key(found[0]), max_expansions):  # none: search's own limit
                break
        budget = alternative_expansions
        while found:  # alternatives 2..k, within their own budget
            target = key(found[k - 1]) if len(found) >= k else inf
            before = len(self.expanded)
            if not more(target, budget):
                break
            budget -= len(self.expanded) - before
            found = search(G, k, rank=self.rank, max_expansions=max_expansions)
            exact = exact and G.graph["search_exact"]
        if found:
            target = key(found[k - 1]) if len(found) >= k else inf
            top = self._top()
            exact = exact and not (top is not None and top <= target)
        exact = exact and not self.timed_out
        G.graph["search_exact"] = exact
        return found

    def _drop(self, u: Node, v: Node, record: str) -> None:
        """Drop a move for good, recorded (the first time) in the graph's list ``record`` (one
        of `REMOVED_RECORDS`: why it went, for the explanation of a failure)."""
        if (u, v) not in self.removed:
            self.G.graph.setdefault(record, []).append((u, v))
        self.removed.add((u, v))
        if self.G.has_edge(u, v):
            self.G.remove_edge(u, v)

    def remove_edge(self, u: Node, v: Node) -> None:
        """Drop a move (e.g. a finger path that cannot be planned) for good (recorded in the
        graph's ``removed_moves`` for the explanation of a failure)."""
        self._drop(u, v, "removed_moves")

    def forbid(self, finger_index: int, slot: int) -> None:
        """Drop, for good, every move lifting a finger off a contact or landing it there (a
        contact the finger cannot back off in any state: `planner.retreat.retreat_blocked`).
        The moves dropped from the graph are recorded in its ``removed_stuck``, not in
        ``removed_moves``: they were never tried (the caller takes the move that failed out
        first, with `remove_edge`)."""
        self.forbidden.add((finger_index, slot))
        for u, v in list(self.G.edges):
            if u[finger_index] == slot and v[finger_index] == LIFTED or \
                    u[finger_index] == LIFTED and v[finger_index] == slot:
                self._drop(u, v, "removed_stuck")

    def remove_state(self, v: Node) -> None:
        """Drop every move into a state (e.g. one that failed in the simulator), for good:
        the moves already in the graph and any found later. The moves dropped from the graph
        are recorded in its ``removed_with_state``, not in ``removed_moves``: they did not fail
        themselves (the caller takes the move that failed out first, with `remove_edge`)."""
        self.removed_states.add(v)
        for u in list(self.G.predecessors(v)) if v in self.G else ():
            self._drop(u, v, "removed_with_state")


def greedy(G: nx.DiGraph) -> GaitSequence:
    """The thesis's Algorithm 2 on the same states, as the baseline.

    Repeatedly repositions (lift, then land at its final slot) the first finger, in
    hand order, that still needs repositioning and is removable; when all needed fingers
    are in place, lifts the fingers free in the final grasp, each when removable. It
    never looks ahead, so it fails where the order matters.

    Raises:
        NoSequenceError: greedy got stuck; ``report`` holds the partial sequence.
    """
    p: GaitProblem = G.graph["problem"]
    ev: Evaluator = G.graph["evaluator"]
    current = p.start
    path = [current]
    needed = [i for i, s in enumerate(p.goal) if s != LIFTED and p.start[i] != s]
    unneeded = [i for i, s in enumerate(p.goal) if s == LIFTED and p.start[i] != LIFTED]

    def step(node: Node) -> bool:
        ev.evaluate([node])
        if ev.blocked_reason(node) is not None:
            return False
        if node not in G:
            add_node(G, ev, node)
        return True

    def stuck(why: str) -> NoSequenceError:
        labels = p.labels(current)
        return NoSequenceError(
            f"greedy (thesis Algorithm 2) is stuck: {why}; reached {labels}",
            report={"partial": [p.labels(v) for v in path], "strategy": "greedy"},
        )

    while needed or unneeded:
        removable = ev.removable(current)
        pool = needed if needed else unneeded
        movable = [i for i in pool if p.fingers[i] in removable]
        if not movable:
            names = ", ".join(p.fingers[i] for i in pool)
            raise stuck(f"none of the fingers still to move ({names}) is removable")
        i = movable[0]
        lifted = current[:i] + (LIFTED,) + current[i + 1 :]
        if lifted != current:
            if not step(lifted):
                raise stuck(f"lifting {p.fingers[i]} gives an invalid state ({ev.blocked_reason(lifted)})")
            path.append(lifted)
            current = lifted
        if pool is needed:
            landed = lifted[:i] + (p.goal[i],) + lifted[i + 1 :]
            if not step(landed):
                raise stuck(f"landing {p.fingers[i]} gives an invalid state ({ev.blocked_reason(landed)})")
            path.append(landed)
            current = landed
        pool.remove(i)
    for u, v in zip(path, path[1:]):
        if not G.has_edge(u, v):
            i = next(j for j in range(len(u)) if u[j] != v[j])
            G.add_edge(u, v, finger=p.fingers[i], action="lift" if v[i] == LIFTED else "land")
    for v in path:
        G.nodes[v].setdefault("removable", ev.removable(v))
    return _sequence(G, path)
