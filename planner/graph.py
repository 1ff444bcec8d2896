"""Grasp-state graph and its ranked search (the planner's core).

A grasp state assigns every finger a contact *slot* (a realized contact: joint values
and contact patch) or ``LIFTED``. Two states are joined when exactly one finger
changes: *lift* (slot -> lifted) or *land* (lifted -> slot). A state is a node of the
graph only when it is valid: its contacts are force closure and no two fingers (nor a
finger and the palm) collide, and, when the problem carries loads (the object's weight
under one or several gravity directions), the fingers can hold every load pressing at
most ``max_grip_force_n`` each (`planner.closure.min_grip_force`; a state's *grip force*
is the largest of those per-load minima). Any path from the initial to the final state is
thus a finger-gaiting sequence that keeps force closure throughout.

`build_graph` grows the graph breadth-first from the initial state, evaluating each
new layer of states in one batch closure call; states that are not force closure are
recorded as blocked and never expanded, so states that cannot matter are never built.
`search` ranks paths in one of two ways (`RANKS`):

* ``metric`` (the thesis): (1) the bottleneck, the worst closure metric along the path,
  larger is better; (2) fewer gait steps (then fewer edges); (3) a larger mean metric.
* ``grip`` (for execution): (1) the grip bottleneck, the largest grip force any state of the
  path needs, smaller is better; (2) fewer gait steps; (3) the metric ranking (larger
  metric bottleneck, fewer edges, larger mean metric).

The search is exact for both: it returns the k best simple paths under the key.
`greedy` is the thesis's Algorithm 2, kept as the baseline.

This module is pure numpy/networkx: it knows nothing of hands or simulators. Slots
carry finger joint values for the caller; collisions come in as a pairwise predicate.
"""

from __future__ import annotations

import heapq
import itertools
from dataclasses import dataclass, field
from typing import Callable, Mapping, Sequence

import networkx as nx
import numpy as np

from planner.closure import Closure, Friction, batch_grasp_closure, min_grip_force
from planner.errors import InputError, NoSequenceError

RANKS = ("metric", "grip")
"""Sequence rankings of `search` (module docstring)."""

LIFTED = -1
"""Slot index of a finger that does not touch the object."""

Node = tuple  # tuple[int, ...]: slot index per finger (LIFTED = -1), in problem.fingers order


def _frozen(a, shape_tail=(3,)) -> np.ndarray:
    arr = np.array(a, dtype=float).reshape((-1,) + shape_tail)
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class Slot:
    """A realized contact of one finger.

    Attributes:
        finger: finger name.
        label: "initial", "final", "int0", ... (unique per finger).
        points: (n, 3) contact points of the finger's patch, object frame, metres.
        normals: (n, 3) unit normals pointing INTO the object, object frame.
        q: the finger's joint values (radians) realizing the contact, or None.
    """

    finger: str
    label: str
    points: np.ndarray
    normals: np.ndarray
    q: np.ndarray | None = None

    def __post_init__(self):
        object.__setattr__(self, "points", _frozen(self.points))
        object.__setattr__(self, "normals", _frozen(self.normals))
        if self.q is not None:
            object.__setattr__(self, "q", _frozen(self.q, ()))
        if len(self.points) != len(self.normals):
            raise InputError(f"slot {self.finger}/{self.label}: {len(self.points)} points but {len(self.normals)} normals")


Compatible = Callable[[str, int, str, int], bool]
"""compatible(finger_a, slot_a, finger_b, slot_b) -> True when the two do not collide
(slot LIFTED = the finger at its open posture). Must be symmetric."""


@dataclass(frozen=True)
class GaitProblem:
    """Everything the graph needs: fingers, their slots, the two grasps.

    Attributes:
        fingers: finger names, fixing the order of node tuples.
        slots: finger -> its slots; node entries index into this tuple.
        start: initial node; goal: final node (LIFTED for fingers free at the end).
        friction: contact model for closure.
        compatible: optional pairwise collision predicate (see `Compatible`).
        max_lifted: optional bound on the number of fingers lifted at once.
        load: optional (6,) external wrench on the object, object frame (e.g. its weight
            ``[m g_obj ; 0]``); with it a state is valid only if its fingers hold the load
            pressing at most ``max_grip_force_n`` each.
        max_grip_force_n: per-finger normal force budget for the loads, N.
        loads: optional (m, 6) further loads (e.g. the weight under several gravity
            directions); a state's grip force is the largest `min_grip_force` over
            ``load`` and every row of ``loads``, and must stay within the budget.
        load_names: one name per row of ``loads`` (default "load1", ...).
        grip_friction_margin: the grip force is computed with ``mu`` and ``gamma`` scaled by
            this (0 < margin <= 1): plans to be executed keep a friction reserve, so a state
            that holds its load only with the whole friction cone is not accepted.
    """

    fingers: tuple[str, ...]
    slots: Mapping[str, tuple[Slot, ...]]
    start: Node
    goal: Node
    friction: Friction
    compatible: Compatible | None = None
    max_lifted: int | None = None
    load: np.ndarray | None = None
    max_grip_force_n: float = 1.0
    loads: np.ndarray | None = None
    load_names: tuple[str, ...] = ()
    grip_friction_margin: float = 1.0

    def __post_init__(self):
        if not (isinstance(self.grip_friction_margin, (int, float)) and 0 < self.grip_friction_margin <= 1):
            raise InputError(f"grip_friction_margin must be in (0, 1], got {self.grip_friction_margin!r}")
        if self.load is not None:
            object.__setattr__(self, "load", _frozen(self.load, ()))
            if self.load.shape != (6,) or not np.all(np.isfinite(self.load)):
                raise InputError(f"load must be 6 finite numbers [fx fy fz tx ty tz], got {self.load.tolist()}")
        if self.loads is not None:
            object.__setattr__(self, "loads", _frozen(self.loads, (6,)))
            if not np.all(np.isfinite(self.loads)):
                raise InputError("loads must be finite rows [fx fy fz tx ty tz]")
            names = tuple(self.load_names) or tuple(f"load{i + 1}" for i in range(len(self.loads)))
            if len(names) != len(self.loads):
                raise InputError(f"load_names has {len(names)} names for {len(self.loads)} loads")
            object.__setattr__(self, "load_names", names)
        if self.load is not None or self.loads is not None:
            if not (np.isfinite(self.max_grip_force_n) and self.max_grip_force_n > 0):
                raise InputError(f"max_grip_force_n must be > 0, got {self.max_grip_force_n!r}")
        n = len(self.fingers)
        for name, node in (("start", self.start), ("goal", self.goal)):
            if len(node) != n:
                raise InputError(f"{name} node has {len(node)} entries for {n} fingers")
            for f, s in zip(self.fingers, node):
                if s != LIFTED and not 0 <= s < len(self.slots[f]):
                    raise InputError(f"{name} node: finger {f!r} has no slot {s}")

    def all_loads(self) -> list[tuple[str, np.ndarray]]:
        """(name, (6,) wrench) of every load a state must hold: ``load`` (named "load")
        then the rows of ``loads``; empty when the problem carries none."""
        out = [("load", self.load)] if self.load is not None else []
        if self.loads is not None:
            out += list(zip(self.load_names, self.loads))
        return out

    def patches(self, node: Node) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Touching finger -> (points, normals) of a node."""
        out = {}
        for f, s in zip(self.fingers, node):
            if s != LIFTED:
                slot = self.slots[f][s]
                out[f] = (slot.points, slot.normals)
        return out

    def labels(self, node: Node) -> dict[str, str]:
        """Finger -> slot label ("lifted" when not touching)."""
        return {f: ("lifted" if s == LIFTED else self.slots[f][s].label) for f, s in zip(self.fingers, node)}

    def neighbours(self, node: Node):
        """Yield (finger index, action, next node) for every single-finger change."""
        for i, f in enumerate(self.fingers):
            if node[i] != LIFTED:
                yield i, "lift", node[:i] + (LIFTED,) + node[i + 1 :]
            else:
                for s in range(len(self.slots[f])):
                    yield i, "land", node[:i] + (s,) + node[i + 1 :]


def _within_lift_bound(problem: GaitProblem, node: Node) -> bool:
    return problem.max_lifted is None or sum(s == LIFTED for s in node) <= problem.max_lifted


class _Evaluator:
    """Caches closure per node and collision compatibility per slot pair."""

    def __init__(self, problem: GaitProblem):
        self.problem = problem
        self.closure: dict[Node, Closure] = {}
        self.grip: dict[Node, tuple[float, ...]] = {}
        self._loads = problem.all_loads()
        fr, k = problem.friction, problem.grip_friction_margin
        self._grip_friction = fr if k == 1 else Friction(fr.mu * k, fr.gamma * k, fr.edges)
        self._pairs: dict[tuple, bool] = {}

    def evaluate(self, nodes: Sequence[Node]) -> None:
        todo = [n for n in dict.fromkeys(nodes) if n not in self.closure]
        if todo:
            results = batch_grasp_closure([self.problem.patches(n) for n in todo], self.problem.friction)
            self.closure.update(zip(todo, results))

    def collision_free(self, node: Node) -> bool:
        check = self.problem.compatible
        if check is None:
            return True
        fingers = self.problem.fingers
        for i, j in itertools.combinations(range(len(fingers)), 2):
            key = (i, node[i], j, node[j])
            ok = self._pairs.get(key)
            if ok is None:
                ok = bool(check(fingers[i], node[i], fingers[j], node[j]))
                self._pairs[key] = ok
            if not ok:
                return False
        return True

    def grip_forces(self, node: Node) -> tuple[float, ...] | None:
        """Per-finger normal force the state needs for each of the problem's loads, in
        `GaitProblem.all_loads` order (None: no load)."""
        if not self._loads:
            return None
        f = self.grip.get(node)
        if f is None:
            patches = self.problem.patches(node)
            f = self.grip[node] = tuple(min_grip_force(patches, self._grip_friction, w) for _, w in self._loads)
        return f

    def grip_force(self, node: Node) -> float | None:
        """Per-finger normal force the state needs to hold every load: the largest over the
        loads (None: no load)."""
        f = self.grip_forces(node)
        return None if f is None else max(f)

    def removable(self, node: Node) -> frozenset[str]:
        """Thesis Algorithm 1 from cached closures: lifted fingers are removable."""
        if not self.closure[node].is_force_closure:
            return frozenset()
        fingers = self.problem.fingers
        lifts = [node[:i] + (LIFTED,) + node[i + 1 :] for i in range(len(fingers)) if node[i] != LIFTED]
        self.evaluate(lifts)
        return frozenset(f for i, f in enumerate(fingers) if node[i] == LIFTED or self.closure[node[:i] + (LIFTED,) + node[i + 1 :]].is_force_closure)

    def blocked_reason(self, node: Node) -> str | None:
        """Why a node is not a valid state, or None when it is."""
        p = self.problem
        if not _within_lift_bound(p, node):
            return "too many fingers lifted"
        if not self.closure[node].is_force_closure:
            return "not force closure"
        if not self.collision_free(node):
            return "fingers collide"
        f = self.grip_force(node)
        if f is not None and f > p.max_grip_force_n:
            return f"need over {p.max_grip_force_n:g} N per finger to hold the load"
        return None


def seed_graph(problem: GaitProblem) -> nx.DiGraph:
    """A graph holding only the initial state (what `greedy` grows lazily).

    Raises:
        NoSequenceError: the initial grasp itself is not a valid state.
    """
    ev = _Evaluator(problem)
    G = nx.DiGraph(problem=problem, start=problem.start, goal=problem.goal, blocked={}, evaluator=ev)
    ev.evaluate([problem.start, problem.goal])
    reason = ev.blocked_reason(problem.start)
    if reason is not None:
        raise NoSequenceError(f"the initial grasp is not a valid state: {reason}")
    _add_node(G, ev, problem.start)
    return G


def build_graph(problem: GaitProblem) -> nx.DiGraph:
    """Grow the graph of valid grasp states reachable from ``problem.start``.

    Node attributes: ``labels`` (finger -> slot label), ``patches``, ``closure``,
    ``metric``, ``removable``. Edge attributes: ``finger``, ``action`` (lift|land).
    Graph attributes: ``problem``, ``start``, ``goal``, ``blocked`` (node -> reason for
    every state that was generated but is not valid), ``evaluator`` (caches).

    Raises:
        NoSequenceError: the initial grasp itself is not a valid state.
    """
    G = seed_graph(problem)
    ev = G.graph["evaluator"]
    frontier = [problem.start]
    while frontier:
        moves = [(u, i, action, v) for u in frontier for i, action, v in problem.neighbours(u)]
        ev.evaluate([v for *_, v in moves if v not in G and v not in G.graph["blocked"] and _within_lift_bound(problem, v)])
        new = []
        for u, i, action, v in moves:
            if v not in G:
                if v in G.graph["blocked"]:
                    continue
                reason = ev.blocked_reason(v)
                if reason is not None:
                    G.graph["blocked"][v] = reason
                    continue
                _add_node(G, ev, v)
                new.append(v)
            G.add_edge(u, v, finger=problem.fingers[i], action=action)
        frontier = new
    for v in G.nodes:
        G.nodes[v]["removable"] = ev.removable(v)
    return G


def _add_node(G: nx.DiGraph, ev: _Evaluator, v: Node) -> None:
    p = ev.problem
    c = ev.closure[v]
    forces = ev.grip_forces(v)
    G.add_node(v, labels=p.labels(v), patches=p.patches(v), closure=c, metric=float(c.metric),
               grip_force=None if forces is None else max(forces),
               grip_forces=None if forces is None else dict(zip((n for n, _ in p.all_loads()), forces)))


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
            return (self.bottleneck_grip, self.gait_steps, -self.bottleneck, len(self.actions), -self.mean_metric)
        return (-self.bottleneck, self.gait_steps, len(self.actions), -self.mean_metric)

    def order(self, problem: GaitProblem) -> tuple[str, ...]:
        """Compact ordering: "finger:lift" / "finger:land>label" per edge."""
        out = []
        for (finger, action), node in zip(self.actions, self.nodes[1:]):
            if action == "land":
                out.append(f"{finger}:land>{problem.labels(node)[finger]}")
            else:
                out.append(f"{finger}:lift")
        return tuple(out)


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
    The search stops once the next partial path is keyed above the k-th goal path found;
    ties on all but the mean metric are all collected, then sorted by the full key. No
    partial path is dropped for any other reason, so the result is exact unless
    ``max_expansions`` partial paths were expanded first (then it is the best found and
    ``G.graph["search_exact"]`` is False; it is True otherwise).

    Returns:
        Up to k sequences, best first; empty when the goal is unreachable.

    Raises:
        InputError: unknown ``rank``, or ``rank="grip"`` on a graph without grip forces.
    """
    if rank not in RANKS:
        from planner.errors import UnknownNameError

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
        grip = {v: G.nodes[v].get("grip_force") for v in G.nodes}
        if any(g is None for g in grip.values()):
            raise InputError("grip ranking needs the grip force of every state: plan with a gravity (a load)")
        hb_grip = _bottleneck_to_goal(G, goal, grip)
    hops = nx.single_target_shortest_path_length(G, goal)
    hops = dict(hops) if not isinstance(hops, dict) else hops
    fingers = G.graph["problem"].fingers if "problem" in G.graph else None
    index = {f: i for i, f in enumerate(fingers)} if fingers is not None else {}

    def gaits_left(v: Node, last) -> int:
        differ = [i for i in range(len(v)) if v[i] != goal[i]]
        free = last is not None and last[1] == "lift" and index.get(last[0]) in differ and goal[index[last[0]]] != LIFTED
        return len(differ) - int(free)

    def key(neg_b, g_max, gaits, n_edges, v, last) -> tuple:
        b = max(neg_b, hb_metric[v])
        g = gaits + gaits_left(v, last)
        e = n_edges + hops[v]
        if rank == "grip":
            return (max(g_max, hb_grip[v]), g, b, e)
        return (b, g, e)

    tie = itertools.count()
    g0 = grip[start] if grip is not None else 0.0
    heap = [(key(neg_metric[start], g0, 0, 0, start, None), next(tie), neg_metric[start], g0, 0, 0, (start,), None)]
    found: list[GaitSequence] = []
    bound = None  # key (without the mean) of the k-th goal path found
    expansions = 0
    while heap:
        f, _, neg_b, g_max, gaits, n_edges, path, last = heapq.heappop(heap)
        if bound is not None and f > bound:
            break
        v = path[-1]
        if v == goal:
            found.append(_sequence(G, path, rank))
            if len(found) >= k:
                found.sort(key=lambda s: s.rank_key)
                bound = found[k - 1].rank_key[:-1]
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
            fw = key(nb, gm, gw, n_edges + 1, w, act)
            if bound is not None and fw > bound:
                continue
            heapq.heappush(heap, (fw, next(tie), nb, gm, gw, n_edges + 1, path + (w,), act))
    found.sort(key=lambda s: s.rank_key)
    return found[:k]


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
    ev: _Evaluator = G.graph["evaluator"]
    current = p.start
    path = [current]
    needed = [i for i, s in enumerate(p.goal) if s != LIFTED and p.start[i] != s]
    unneeded = [i for i, s in enumerate(p.goal) if s == LIFTED and p.start[i] != LIFTED]

    def step(node: Node) -> bool:
        ev.evaluate([node])
        if ev.blocked_reason(node) is not None:
            return False
        if node not in G:
            _add_node(G, ev, node)
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


def explain_failure(G: nx.DiGraph, intermediate_tried: bool) -> NoSequenceError:
    """Why no sequence connects start and goal: the error the CLI prints.

    Names the fingers never removable in any reachable state, the reachable state closest
    to the goal (and its best path), the count of blocked states by reason, and whether
    intermediate contacts were tried.
    """
    p: GaitProblem = G.graph["problem"]
    start, goal = G.graph["start"], G.graph["goal"]
    ev: _Evaluator = G.graph["evaluator"]
    reach = nx.descendants(G, start) | {start}
    never = [f for f in p.fingers if not any(f in G.nodes[v]["removable"] for v in reach if G.nodes[v]["labels"][f] != "lifted")]
    dist = {v: sum(a != b for a, b in zip(v, goal)) for v in reach}
    closest = min(reach, key=lambda v: (dist[v], -G.nodes[v]["metric"], v))
    partial = nx.shortest_path(G, start, closest)
    reasons: dict[str, int] = {}
    for r in G.graph["blocked"].values():
        reasons[r] = reasons.get(r, 0) + 1
    goal_reason = ev.blocked_reason(goal) if goal in ev.closure else None
    parts = []
    if goal_reason:
        parts.append(f"the final grasp itself is invalid ({goal_reason})")
    if never:
        parts.append(f"never removable: {', '.join(never)}")
    parts.append(f"closest state reached ({dist[closest]} finger(s) from the goal): {p.labels(closest)}")
    parts.append("blocked states: " + (", ".join(f"{n} {r}" for r, n in sorted(reasons.items())) or "none"))
    parts.append("intermediate contacts were tried" if intermediate_tried else "try intermediate contacts (--intermediate N)")
    report = {
        "never_removable": never,
        "closest": p.labels(closest),
        "partial": [p.labels(v) for v in partial],
        "blocked": reasons,
        "intermediate_tried": intermediate_tried,
    }
    return NoSequenceError("no finger-gaiting sequence: " + "; ".join(parts), report=report)
