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
`LazyGraph` gives the same k best without building the whole graph: a best-first search
over the implicit graph that evaluates a state only when it is popped (see its docstring
for why the ranking stays exact). `greedy` is the thesis's Algorithm 2, kept as the
baseline. `explain_failure` says in words why no sequence exists (`failure_analysis`).

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

from planner.model import Friction
from planner.closure import Closure, batch_grasp_closure, min_grip_force
from planner.errors import InputError, NoSequenceError
from planner.grip import HOLD_FACTOR, Capacity, FingerStatics, grip_program, hold_capacity, holds_by_bound, torque_demand

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
        statics: the finger's contact Jacobians, gravity torques and joint limits at this
            contact (`planner.grip.FingerStatics`), or None: with them a problem with loads
            bounds the grip by the joints (`GaitProblem`).
    """

    finger: str
    label: str
    points: np.ndarray
    normals: np.ndarray
    q: np.ndarray | None = None
    statics: FingerStatics | None = None

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
        max_grip_force_n: per-finger normal force budget for the loads, N (None: none, only
            with ``load_gravity``).
        loads: optional (m, 6) further loads (e.g. the weight under several gravity
            directions); a state's grip force is the largest `min_grip_force` over
            ``load`` and every row of ``loads``, and must stay within the budget.
        load_names: one name per row of ``loads`` (default "load1", ...).
        grip_friction_margin: the grip force is computed with ``mu`` and ``gamma`` scaled by
            this (0 < margin <= 1): plans to be executed keep a friction reserve, so a state
            that holds its load only with the whole friction cone is not accepted.
        load_gravity: optional (m, 3) gravity vector of each load of `all_loads`, object
            frame, m/s^2. With it the grip is bounded by the hand's joints (the torque
            model, `planner.grip.hold_capacity`, every slot carrying its ``statics``): a
            state is valid when its fingers hold ``hold_factor`` times every load within
            their joint torque limits (and ``max_grip_force_n`` when given), with the
            friction scaled by ``grip_friction_margin``.
        hold_factor: the multiple of each load the torque model requires (default
            `planner.grip.HOLD_FACTOR`).
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
    load_gravity: np.ndarray | None = None
    hold_factor: float = HOLD_FACTOR

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
            if self.max_grip_force_n is None and self.load_gravity is None:
                raise InputError("max_grip_force_n is needed without load_gravity (the torque model)")
            if self.max_grip_force_n is not None and not (np.isfinite(self.max_grip_force_n) and self.max_grip_force_n > 0):
                raise InputError(f"max_grip_force_n must be > 0, got {self.max_grip_force_n!r}")
        if self.load_gravity is not None:
            object.__setattr__(self, "load_gravity", _frozen(self.load_gravity))
            if len(self.load_gravity) != len(self.all_loads()) or not np.all(np.isfinite(self.load_gravity)):
                raise InputError(f"load_gravity must be one finite (3,) vector per load, got {self.load_gravity.shape}")
            if not (isinstance(self.hold_factor, (int, float)) and 0 < self.hold_factor <= 100):
                raise InputError(f"hold_factor must be in (0, 100], got {self.hold_factor!r}")
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

    @property
    def grip_friction(self) -> Friction:
        """The friction the grip forces are computed with (``grip_friction_margin`` of it)."""
        fr, k = self.friction, self.grip_friction_margin
        return fr if k == 1 else Friction(fr.mu * k, fr.gamma * k, fr.edges)

    def load_refusal(self, patches, statics, order=None, grip=None) -> tuple[int, Capacity | None] | None:
        """Whether contacts hold every load as the problem asks; None when they do, else
        ``(j, capacity)`` for the first load they do not hold: ``j`` the load's index in
        `all_loads` (``-j - 1``: held ``hold_factor`` times but not the weight itself, where a
        finger cannot hold itself up alone) and the capacity None under the per-finger budget
        (no ``load_gravity``).

        Budget: the grip force (`min_grip_force`) of each load within ``max_grip_force_n``.
        Torque model (``load_gravity``): the grip force proves most holds by a bound
        (`planner.grip.holds_by_bound`), the capacity program decides the others.

        Args:
            patches, statics: the contacts (finger -> (points, normals)) and their statics.
            order: load indices in the order to try them (default all, in order).
            grip: a list with one grip force or None per load, filled as they are computed.
        """
        loads = self.all_loads()
        grip = [None] * len(loads) if grip is None else grip
        program = None
        for j in range(len(loads)) if order is None else order:
            if grip[j] is None:
                grip[j] = min_grip_force(patches, self.grip_friction, loads[j][1])
            if self.load_gravity is None:
                if grip[j] > self.max_grip_force_n:
                    return j, None
                continue
            g = self.load_gravity[j]
            if holds_by_bound(statics, grip[j], self.friction, g, factor=self.hold_factor,
                              margin=self.grip_friction_margin, force_cap_n=self.max_grip_force_n):
                continue
            program = program or grip_program(patches, statics, self.friction, margin=self.grip_friction_margin)
            cap = hold_capacity(patches, statics, self.friction, loads[j][1], g, force_cap_n=self.max_grip_force_n,
                                program=program, witness=False)
            if cap.factor < self.hold_factor:
                return j, cap
            # the multiples held form an interval; where a finger cannot hold itself up alone
            # (|g| > tau_max at a joint) it may not reach down to the weight itself
            if np.any(np.abs(program.tau_g(g)) > program.tau_max):
                d = torque_demand(patches, statics, self.friction, loads[j][1], g, factor=1.0,
                                  force_cap_n=self.max_grip_force_n, program=program)
                if d.ratio > 1.0:
                    return -j - 1, cap
        return None

    def statics(self, node: Node) -> dict[str, FingerStatics]:
        """Touching finger -> its slot's `FingerStatics` (fingers whose slot has none left out)."""
        out = {}
        for f, s in zip(self.fingers, node):
            if s != LIFTED and self.slots[f][s].statics is not None:
                out[f] = self.slots[f][s].statics
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


def _same_array(a, b) -> bool:
    return (a is None and b is None) or (a is not None and b is not None and np.array_equal(a, b))


def _within_lift_bound(problem: GaitProblem, node: Node) -> bool:
    return problem.max_lifted is None or sum(s == LIFTED for s in node) <= problem.max_lifted


class Evaluator:
    """Caches closure per node and collision compatibility per slot pair."""

    def __init__(self, problem: GaitProblem):
        self.problem = problem
        self.closure: dict[Node, Closure] = {}
        self.grip: dict[Node, tuple[float, ...]] = {}
        self._loads = problem.all_loads()
        self._grip_friction = problem.grip_friction
        self._pairs: dict[tuple, bool] = {}
        self._refusals = [0] * len(self._loads)  # states each load refused (`_over_budget`)
        self._over: dict[Node, tuple[int, Capacity | None]] = {}  # refused: `GaitProblem.load_refusal`
        self.hold: set[Node] = set()  # torque model: states that hold every load
        self._factors: dict[Node, tuple[float, ...]] = {}  # their capacity factor per load (`hold_factors`)

    def evaluate(self, nodes: Sequence[Node]) -> None:
        todo = [n for n in dict.fromkeys(nodes) if n not in self.closure]
        if todo:
            results = batch_grasp_closure([self.problem.patches(n) for n in todo], self.problem.friction)
            self.closure.update(zip(todo, results))

    def extend(self, problem: GaitProblem) -> None:
        """Go on with a problem that only adds slots to this one's (the next round of
        intermediate contacts): every cached closure, grip force and collision stays valid,
        because existing slots keep their indices."""
        old = self.problem
        if (problem.fingers != old.fingers or problem.start != old.start or problem.goal != old.goal
                or any(problem.slots[f][: len(old.slots[f])] != old.slots[f] for f in old.fingers)):
            raise InputError("a problem can only be extended by appending slots")
        same = (problem.friction == old.friction and problem.max_grip_force_n == old.max_grip_force_n
                and problem.grip_friction_margin == old.grip_friction_margin and problem.hold_factor == old.hold_factor
                and problem.max_lifted == old.max_lifted
                and all(_same_array(getattr(problem, k), getattr(old, k)) for k in ("load", "loads", "load_gravity")))
        if not same:
            raise InputError("a problem can only be extended with the same friction, loads and grip limits")
        self.problem = problem

    def collision_pair(self, node: Node) -> tuple[str, str] | None:
        """The first two fingers (in finger order) that collide in a node, or None."""
        check = self.problem.compatible
        if check is None:
            return None
        fingers = self.problem.fingers
        for i, j in itertools.combinations(range(len(fingers)), 2):
            key = (i, node[i], j, node[j])
            ok = self._pairs.get(key)
            if ok is None:
                ok = bool(check(fingers[i], node[i], fingers[j], node[j]))
                self._pairs[key] = ok
            if not ok:
                return fingers[i], fingers[j]
        return None

    def collision_free(self, node: Node) -> bool:
        return self.collision_pair(node) is None

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
        pair = self.collision_pair(node)
        if pair is not None:
            return f"fingers collide ({pair[0]} and {pair[1]})"
        if not self.closure[node].is_force_closure:
            return "not force closure"
        if self._over_budget(node):
            return self.refusal(node)
        return None

    def refusal(self, node: Node) -> str:
        """Why a node's fingers cannot hold a load (after `_over_budget` refused it)."""
        p = self.problem
        j, cap = self._over[node]  # j < 0: load -j - 1 held twice over but not alone
        if cap is None:
            return f"need over {p.max_grip_force_n:g} N per finger to hold the load"
        k = j if j >= 0 else -j - 1
        name, w = self._loads[k]
        g = p.load_gravity[k]
        if j < 0:
            return (f"{name}: holds up to {cap.factor:.3g}x its weight but not the weight itself within the "
                    f"joint limits (a finger's own weight exceeds a joint's limit unless the object presses on it)")
        words = f"{name}: {cap.words(p.hold_factor)}"
        if cap.limit is not None and cap.limit.joint is None:  # the force cap binds, not a joint
            return words
        dem = torque_demand(p.patches(node), p.statics(node), self.problem.friction, w, g, factor=p.hold_factor,
                            margin=p.grip_friction_margin)
        tail = " (but not within the per-finger force cap)" if p.max_grip_force_n is not None and dem.ratio <= 1 else ""
        return f"{words}; to hold {p.hold_factor:g}x, {dem.words()}{tail}"

    def _over_budget(self, node: Node) -> bool:
        """Some load is not held as the problem asks (`GaitProblem.load_refusal`). Loads are
        tried in the order of how many states each has refused so far (one program for most
        refused states instead of all); a state that holds them all gets every grip force."""
        if not self._loads:
            return False
        if node in self.hold:
            return False
        if node in self._over:
            return True
        p = self.problem
        grip = list(self.grip.get(node) or [None] * len(self._loads))
        order = sorted(range(len(self._loads)), key=lambda j: (-self._refusals[j], j))
        why = p.load_refusal(p.patches(node), p.statics(node), order, grip)
        if why is not None:
            self._refusals[why[0] if why[0] >= 0 else -why[0] - 1] += 1
            self._over[node] = why
            return True
        self.grip[node] = tuple(grip)
        self.hold.add(node)
        return False

    def hold_factors(self, node: Node) -> dict[str, float] | None:
        """Load name -> the largest multiple of it the state's joints hold (the capacity
        program, computed when asked: for the states of a plan); None without the torque model."""
        p = self.problem
        if p.load_gravity is None or not self._loads:
            return None
        if node not in self._factors:
            patches, statics = p.patches(node), p.statics(node)
            program = grip_program(patches, statics, p.friction, margin=p.grip_friction_margin)
            self._factors[node] = tuple(
                hold_capacity(patches, statics, p.friction, w, g, force_cap_n=p.max_grip_force_n, program=program,
                              witness=False).factor for (_, w), g in zip(self._loads, p.load_gravity))
        return dict(zip((n for n, _ in self._loads), self._factors[node]))


def seed_graph(problem: GaitProblem, evaluator: Evaluator | None = None) -> nx.DiGraph:
    """A graph holding only the initial state (what `greedy` and `LazyGraph` grow).

    Args:
        evaluator: caches to reuse (from an earlier round over fewer slots, see
            `Evaluator.extend`); a fresh one when None.

    Raises:
        NoSequenceError: the initial grasp itself is not a valid state.
    """
    ev = evaluator or Evaluator(problem)
    if ev.problem is not problem:
        ev.extend(problem)
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
    G.graph["blocked_moves"] = []  # (from state, finger index, action, to state) of refused moves
    frontier = [problem.start]
    while frontier:
        moves = [(u, i, action, v) for u in frontier for i, action, v in problem.neighbours(u)]
        ev.evaluate([v for *_, v in moves if v not in G and v not in G.graph["blocked"] and _within_lift_bound(problem, v)])
        new = []
        for u, i, action, v in moves:
            if v not in G:
                if v in G.graph["blocked"]:
                    G.graph["blocked_moves"].append((u, i, action, v))
                    continue
                reason = ev.blocked_reason(v)
                if reason is not None:
                    G.graph["blocked"][v] = reason
                    G.graph["blocked_moves"].append((u, i, action, v))
                    continue
                _add_node(G, ev, v)
                new.append(v)
            G.add_edge(u, v, finger=problem.fingers[i], action=action)
        frontier = new
    for v in G.nodes:
        G.nodes[v]["removable"] = ev.removable(v)
    return G


def _add_node(G: nx.DiGraph, ev: Evaluator, v: Node) -> None:
    p = ev.problem
    c = ev.closure[v]
    forces = ev.grip_forces(v)
    G.add_node(v, labels=p.labels(v), patches=p.patches(v), closure=c, metric=float(c.metric),
               grip_force=None if forces is None else max(forces),
               grip_forces=None if forces is None else dict(zip((n for n, _ in p.all_loads()), forces)))


def _gaits_lower_bound(start: Node, goal: Node, v: Node) -> int:
    """Fewest gaits any start-goal path through ``v`` can have: every finger whose slot
    differs between start and v needs a gait before v, every finger differing between v and
    goal one after it; at most one gait (a lift right before v and that finger's landing
    right after it) is counted twice."""
    before = sum(a != b for a, b in zip(start, v))
    after = sum(a != b for a, b in zip(v, goal))
    straddle = any(s == LIFTED and a != LIFTED and g != LIFTED for a, s, g in zip(start, v, goal))
    return before + after - int(straddle)


class LazyGraph:
    """The state graph grown lazily, best-first, as far as the ranked search needs it.

    States are expanded in order of (their best possible primary cost from the start, a
    lower bound of the gait steps of any path through them): the primary cost of a path is
    its ranking's bottleneck (``metric``: minus the worst closure metric; ``grip``: the
    largest grip force), and a state's is the smallest bottleneck over the paths reaching
    it (a widest-path Dijkstra). A generated state is queued unevaluated, keyed by its
    parent's value (a lower bound of its own); closure, collisions and grip force are
    evaluated only when it is popped (one batch closure call per batch, with the caches of
    `Evaluator`), then it is queued again with its true key, and expanded when popped
    again. States keyed above what the ranking needs are never evaluated.

    Exactness: once every queued state keyed at most (c, g) is popped, every path whose
    (primary, gait steps) is at most (c, g) lies wholly in the explored graph (each of its
    states has a primary cost <= c and a gait bound <= g, and so had its lower-bound key
    when its predecessor on the path generated it). `best` goes on until that holds for the
    k-th sequence `search` finds on the explored graph, so its ranking equals the ranking
    over the whole graph (`build_graph`), up to ``max_expansions``.

    Attributes:
        G: the explored graph (same attributes as `build_graph`'s, without ``removable``
            until `annotate_removable`); ``G.graph["expanded"]`` counts expanded states.
        complete: True when every reachable valid state has been expanded.
        timed_out: True when the deadline stopped an expansion.
    """

    BATCH = 16
    """States popped per batch (evaluated together in one batch closure call)."""

    def __init__(self, problem: GaitProblem, rank: str = "metric", evaluator: Evaluator | None = None,
                 deadline: float | None = None):
        if rank not in RANKS:
            from planner.errors import UnknownNameError

            raise UnknownNameError("rank", rank, RANKS)
        if rank == "grip" and not problem.all_loads():
            raise InputError("grip ranking needs the grip force of every state: plan with a gravity (a load)")
        self.problem, self.rank, self.deadline = problem, rank, deadline
        self.G = seed_graph(problem, evaluator)
        self.ev: Evaluator = self.G.graph["evaluator"]
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
        return -data["metric"] if self.rank == "metric" else data["grip_force"]

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
        is evaluated (closure, collisions, grip; one batch closure call per batch) and pushed
        again with its true key, an evaluated one is expanded: its successors are pushed
        unevaluated, keyed by the best value they can have (their parent's). Returns how many
        states were expanded."""
        import time

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
            # collisions first (cached per slot pair): colliding states need no closure
            ev.evaluate([w for w in fresh if _within_lift_bound(p, w) and ev.collision_free(w)])
            for w in fresh:
                reason = ev.blocked_reason(w)
                parents = pending.pop(w)
                if reason is not None:
                    blocked[w] = reason
                    G.graph["blocked_moves"].extend((u, i, action, w) for u, i, action in parents)
                    continue
                _add_node(G, ev, w)
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
        return -s.bottleneck if self.rank == "metric" else s.bottleneck_grip

    def best(self, k: int = 1, *, max_expansions: int = 200_000, alternative_expansions: int = 5_000) -> list[GaitSequence]:
        """The k best sequences (`search`'s ranking), growing the graph as needed.

        The best one is exact unless ``max_expansions`` states were expanded or the deadline
        passed first; alternatives 2..k are exact unless completing them needed more than
        ``alternative_expansions`` further states. ``G.graph["search_exact"]`` says whether
        all k are. Empty when the goal cannot be reached (then `complete` is True, unless a
        limit stopped the growth).
        """
        G, goal, inf = self.G, self.problem.goal, (np.inf, np.inf)

        def more(bound, budget) -> bool:
            """Expand up to ``bound``; False when nothing was left to do or a limit stopped it."""
            left, top = max_expansions - len(self.expanded), self._top()
            if top is None or top > bound or self.timed_out or left <= 0 or budget <= 0:
                return False
            self._expand(bound, min(left, budget))
            return True

        def key(s: GaitSequence) -> tuple:
            return (-s.bottleneck if self.rank == "metric" else s.bottleneck_grip, s.gait_steps)

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

    def remove_edge(self, u: Node, v: Node) -> None:
        """Drop a move (e.g. a finger path that cannot be planned) for good."""
        self.removed.add((u, v))
        if self.G.has_edge(u, v):
            self.G.remove_edge(u, v)

    def forbid(self, finger_index: int, slot: int) -> None:
        """Drop, for good, every move lifting a finger off a contact or landing it there (a
        contact the finger cannot back off in any state: `planner.motion.retreat_blocked`)."""
        self.forbidden.add((finger_index, slot))
        for u, v in list(self.G.edges):
            if u[finger_index] == slot and v[finger_index] == LIFTED or \
                    u[finger_index] == LIFTED and v[finger_index] == slot:
                self.remove_edge(u, v)

    def remove_state(self, v: Node) -> None:
        """Drop every move into a state (e.g. one that failed in the simulator), for good:
        the moves already in the graph and any found later."""
        self.removed_states.add(v)
        for u in list(self.G.predecessors(v)) if v in self.G else ():
            self.remove_edge(u, v)


def annotate_removable(G: nx.DiGraph, nodes) -> None:
    """Set the ``removable`` attribute (thesis Algorithm 1) of the given nodes (`LazyGraph`
    leaves it unset: it needs the closure of every single-finger lift)."""
    ev: Evaluator = G.graph["evaluator"]
    for v in dict.fromkeys(nodes):
        if "removable" not in G.nodes[v]:
            G.nodes[v]["removable"] = ev.removable(v)


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


def _gaits_to_goal(G: nx.DiGraph, goal: Node, allowed=None) -> dict[tuple[Node, str | None], int]:
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
    # fewest gaits to the goal, over the whole graph and over the states whose primary cost
    # (the first ranking component) is at most the best bottleneck's: a path that can still
    # reach the goal with that bottleneck is bounded by the second, tighter table
    primary, hb_primary = (neg_metric, hb_metric) if grip is None else (grip, hb_grip)
    best_primary = hb_primary[start]
    gaits_all = _gaits_to_goal(G, goal)
    gaits_best = _gaits_to_goal(G, goal, {v for v, c in primary.items() if c <= best_primary})

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


def _slot_words(problem: GaitProblem, finger: str, s: int) -> str:
    if s == LIFTED:
        return "lifted"
    label = problem.slots[finger][s].label
    return {"initial": "its initial contact", "final": "its final contact"}.get(label, f"intermediate contact {label}")


def _state_words(problem: GaitProblem, node: Node) -> str:
    """'thumb initial, index final, middle lifted' (fingers free in both grasps left out)."""
    labels = problem.labels(node)
    keep = [f for i, f in enumerate(problem.fingers) if not (problem.start[i] == problem.goal[i] == node[i] == LIFTED)]
    return ", ".join(f"{f} {labels[f]}" for f in keep)


def _move_words(problem: GaitProblem, u: Node, v: Node) -> str:
    i = next(j for j in range(len(u)) if u[j] != v[j])
    f = problem.fingers[i]
    return f"lift {f}" if v[i] == LIFTED else f"land {f} on {_slot_words(problem, f, v[i])}"


def _reason_words(ev: Evaluator, finger: str, action: str, w: Node, reason: str) -> str:
    """A refused move in words: what goes wrong in the state it would lead to."""
    pair = ev.collision_pair(w) if reason.startswith("fingers collide") else None
    if pair is not None:
        other = pair[1] if pair[0] == finger else pair[0] if pair[1] == finger else None
        if other is not None:
            return f"it would collide with {other}" + (" (in its open posture)" if w[ev.problem.fingers.index(other)] == LIFTED else "")
        return f"{pair[0]} and {pair[1]} would collide"
    if reason == "not force closure":
        c = ev.closure.get(w)
        metric = f", metric {c.metric:.3g}" if c is not None else ""
        rest = ", ".join(f for f in ev.problem.patches(w)) or "no finger"
        return f"{'without it' if action == 'lift' else 'with it'} the grasp ({rest}) is not force closure{metric}"
    return reason


def _cannot_hold(reason: str) -> bool:
    """A state refused because its contacts cannot hold the object (not force closure, or
    over the grip force budget), not because fingers collide or too many are lifted."""
    return reason == "not force closure" or reason.startswith("need over")


def failure_analysis(G: nx.DiGraph) -> dict:
    """What stops the graph's start from reaching its goal (for `explain_failure` and for
    choosing the fingers that get intermediate contacts).

    Returns a dict: ``closest`` (the reached state fewest fingers from the goal, best metric
    first), ``partial`` (the fewest-move path to it), ``lift_blocked`` (finger that has to
    move -> (state, why) for a finger never lifted in any reached state where it touches),
    ``unheld`` (those of them refused because the other fingers cannot hold the object
    without them), ``landing_blocked`` (finger -> {why: count of states} for refused
    landings on the final contact), ``stuck`` ((finger, action, why) of each refused next
    move from the closest state), ``blockers`` (fingers worth giving intermediate contacts, most implicated
    first), ``needs`` ((finger, state) pairs: a new contact of that finger would help if,
    added to the state, where it is lifted, it made a valid grasp: the other fingers when a
    lift leaves a state that cannot hold the object (not force closure, or over the grip
    force budget), the finger in the way of a landing),
    ``goal_reason`` (why the final grasp itself is invalid, or None).
    """
    p: GaitProblem = G.graph["problem"]
    ev: Evaluator = G.graph["evaluator"]
    start, goal = G.graph["start"], G.graph["goal"]
    reach = nx.descendants(G, start) | {start}
    dist = {v: sum(a != b for a, b in zip(v, goal)) for v in reach}
    closest = min(reach, key=lambda v: (dist[v], -G.nodes[v]["metric"], v))
    partial = nx.shortest_path(G, start, closest)
    moves = [m for m in G.graph.get("blocked_moves", []) if m[0] in reach]
    on_partial = {v: k for k, v in enumerate(partial)}
    lift_blocked, landing_blocked, score = {}, {}, {f: 0 for f in p.fingers}
    needs: list[tuple[str, Node]] = []
    unheld: list[str] = []

    def need_holders(w: Node, lifted: str) -> None:
        """Lifting ``lifted`` left ``w`` unable to hold the object: another finger could help by a
        new contact: a lifted one added to ``w``, a touching one moved within ``w``."""
        for j, g in enumerate(p.fingers):
            if g != lifted:
                needs.append((g, w[:j] + (LIFTED,) + w[j + 1:]))

    def need_room(f: str, w: Node) -> None:
        """Landing ``f`` gives ``w``, where it collides: the finger in the way could move."""
        for g in ev.collision_pair(w) or ():
            if g != f:
                j = p.fingers.index(g)
                if w[j] != LIFTED:
                    needs.append((g, w[:j] + (LIFTED,) + w[j + 1:]))

    for i, f in enumerate(p.fingers):
        if p.start[i] == p.goal[i]:
            continue
        touching = [v for v in reach if v[i] != LIFTED]
        if touching and not any(G.has_edge(v, v[:i] + (LIFTED,) + v[i + 1:]) for v in touching):
            tried = [m for m in moves if m[1] == i and m[2] == "lift"]
            if tried:  # the refused lift nearest the end of the best partial sequence
                u, _, _, w = max(tried, key=lambda m: (on_partial.get(m[0], -1), -dist[m[0]]))
                lift_blocked[f] = (u, _reason_words(ev, f, "lift", w, G.graph["blocked"][w]))
                score[f] += 3
                if _cannot_hold(G.graph["blocked"][w]):
                    need_holders(w, f)
                if any(_cannot_hold(G.graph["blocked"][m[3]]) for m in tried):
                    unheld.append(f)
        if p.goal[i] != LIFTED:
            why: dict[str, int] = {}
            for u, j, action, w in moves:
                if j == i and action == "land" and w[i] == p.goal[i]:
                    text = _reason_words(ev, f, "land", w, G.graph["blocked"][w])
                    why[text] = why.get(text, 0) + 1
                    if why[text] <= 2:
                        need_room(f, w)
                    pair = ev.collision_pair(w)
                    for g in pair or ():
                        if g != f:
                            score[g] += 2
            if why and not any(v[i] == p.goal[i] for v in reach):
                landing_blocked[f] = dict(sorted(why.items(), key=lambda kv: (-kv[1], kv[0])))
                score[f] += 1
        if closest[i] != goal[i]:
            score[f] += 1
    # the next move of every finger not yet at its final slot, from the closest state
    stuck = []
    for i, f in enumerate(p.fingers):
        if closest[i] == goal[i]:
            continue
        action = "lift" if closest[i] != LIFTED else "land"
        w = closest[:i] + ((LIFTED,) if action == "lift" else (goal[i],)) + closest[i + 1:]
        if w in G.graph["blocked"]:
            stuck.append((f, action, _reason_words(ev, f, action, w, G.graph["blocked"][w])))
            if _cannot_hold(G.graph["blocked"][w]) and action == "lift":
                need_holders(w, f)
            need_room(f, w)
            for g in ev.collision_pair(w) or ():
                score[g] += 2 if g != f else 0
            if action == "lift":
                score[f] += 2
    goal_reason = None
    if goal in ev.closure or goal in G.graph["blocked"]:
        goal_reason = G.graph["blocked"].get(goal) or ev.blocked_reason(goal)
    blockers = [f for f in sorted(p.fingers, key=lambda f: (-score[f], p.fingers.index(f))) if score[f] > 0]
    return {"closest": closest, "partial": partial, "lift_blocked": lift_blocked, "unheld": unheld,
            "landing_blocked": landing_blocked,
            "stuck": stuck, "needs": list(dict.fromkeys(needs)),
            "blockers": blockers, "goal_reason": goal_reason, "distance": dist[closest]}


def explain_failure(G: nx.DiGraph, intermediate_tried: bool, tried: str | None = None) -> NoSequenceError:
    """Why no sequence connects start and goal, in words: the error the CLI prints.

    Says whether the final grasp itself is invalid, which finger that has to move cannot be
    lifted in any reached state and why (the grasp without it is not force closure, with its
    metric, or it would collide with a named finger), which landings on the final contacts
    are refused and why, the best partial sequence and where it ends, and what was tried
    (``tried``: a sentence from the caller, e.g. the rounds of intermediate contacts).
    Fingers free in both grasps are never mentioned.
    """
    p: GaitProblem = G.graph["problem"]
    a = failure_analysis(G)
    lines = []
    if a["goal_reason"]:
        lines.append(f"the final grasp itself is not a valid state ({a['goal_reason']})")
    for f, (u, why) in a["lift_blocked"].items():
        where = "the initial grasp" if u == p.start else f"any reached state (e.g. {_state_words(p, u)})"
        lines.append(f"{f} cannot be lifted in {where}: {why}")
    for f, why in a["landing_blocked"].items():
        parts = [text + (f" ({n} states)" if n > 1 else "") for text, n in why.items()]
        lines.append(f"{f} cannot land on its final contact: {'; '.join(parts)}")
    steps = [_move_words(p, u, v) for u, v in zip(a["partial"], a["partial"][1:])]
    lines.append(f"best partial sequence ({len(steps)} moves{': ' + ', '.join(steps) if steps else ''}) ends "
                 f"{a['distance']} finger(s) from the final grasp in: {_state_words(p, a['closest'])}")
    for f, action, why in a["stuck"]:
        if f not in a["lift_blocked"] and f not in a["landing_blocked"]:
            move = "be lifted" if action == "lift" else "land on its final contact"
            lines.append(f"there {f} cannot {move}: {why}")
    if not (a["lift_blocked"] or a["landing_blocked"] or a["stuck"] or a["goal_reason"]):
        # nothing was refused: the search stopped before it tried the moves that remain
        left = [f for i, f in enumerate(p.fingers) if a["closest"][i] != G.graph["goal"][i]]
        if left:
            lines.append(f"{', '.join(left)} still {'has' if len(left) == 1 else 'have'} to move and no such move "
                         "was refused: the search stopped before it evaluated them (a longer --time-limit lets "
                         "it go on)")
    if tried:
        lines.append(tried)
    elif not intermediate_tried:
        lines.append("no intermediate contacts were tried (give --intermediate N or a --time-limit)")
    else:
        lines.append("intermediate contacts were tried")
    reasons: dict[str, int] = {}
    for r in G.graph["blocked"].values():
        reasons[r] = reasons.get(r, 0) + 1
    report = {
        "never_removable": sorted(a["lift_blocked"]),
        "lift_blocked": {f: why for f, (_, why) in a["lift_blocked"].items()},
        "landing_blocked": a["landing_blocked"],
        "closest": p.labels(a["closest"]),
        "stuck": [{"finger": f, "action": action, "why": why} for f, action, why in a["stuck"]],
        "partial": [p.labels(v) for v in a["partial"]],
        "blocked": reasons,
        "blockers": a["blockers"],
        "intermediate_tried": intermediate_tried,
    }
    return NoSequenceError("no finger-gaiting sequence: " + "; ".join(lines), report=report)
