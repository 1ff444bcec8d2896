"""The grasp-state graph (the planner's core data structure).

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
`Evaluator` caches what the states need (closure per state, collisions per slot pair,
grip forces); `seed_graph` starts the graph that `planner.gait_search.LazyGraph` and
`planner.gait_search.greedy` grow. Ranking paths through the graph: `planner.gait_search`; why no
path exists: `planner.explain`.

This module is pure numpy/networkx: it knows nothing of hands or simulators. Slots
carry finger joint values for the caller; collisions come in as a pairwise predicate.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from functools import cached_property
from types import MappingProxyType
from typing import Callable, Mapping, Sequence

import networkx as nx
import numpy as np

from planner import lp
from planner.closure import GripContacts, batch_grasp_closure
from planner.errors import InputError, NoSequenceError
from planner.grip import HOLD_FACTOR, Capacity, Demand, FingerStatics, grip_program, hold_capacity, holds_by_bound, torque_demand
from planner.hull import Closure
from planner.model import Friction, Patch

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
        links: the link each point is on (`planner.model.Patch.links`), or None.
    """

    finger: str
    label: str
    points: np.ndarray
    normals: np.ndarray
    q: np.ndarray | None = None
    statics: FingerStatics | None = None
    links: tuple | None = None

    @property
    def patch(self) -> Patch:
        """The slot's contacts as a `planner.model.Patch` (with their links)."""
        return Patch(self.points, self.normals, self.links)

    def __post_init__(self):
        if self.links is not None:
            object.__setattr__(self, "links", tuple(self.links))
            if len(self.links) != len(self.points):
                raise InputError(f"slot {self.finger}/{self.label}: {len(self.points)} points but {len(self.links)} links")
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
        support: contacts every state has and no move lifts: owner -> `Patch` (the palm,
            `planner.model.PALM`, when the object rests on it; rigid, so no statics: it pushes
            inside its friction cone with no joint limit). A finger may lift when the other
            fingers and the support keep the state valid.
        palm_hint: ``(patch, gap_m)`` when the palm does not hold: the contact the palm would
            make if the object rested on it (its nearest point, the palm's normal there) and how
            far the object is from it, m; explanations say whether that would let a blocked
            finger lift (`planner.explain`).
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
    support: Mapping[str, Patch] = field(default_factory=dict)
    palm_hint: tuple | None = None

    def __post_init__(self):
        object.__setattr__(self, "support", MappingProxyType(dict(self.support)))
        for owner in self.support:
            if owner in self.fingers:
                raise InputError(f"support {owner!r} is a finger: a finger's contacts are slots, lifted and landed")
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

    @cached_property
    def load_test(self) -> "LoadTest":
        """What testing a state's loads needs of the problem (`LoadTest`: it pickles, for a
        helper process), made once."""
        return LoadTest(tuple(self.all_loads()), self.friction, self.grip_friction, self.load_gravity,
                        self.max_grip_force_n, self.grip_friction_margin, self.hold_factor)

    def load_refusal(self, patches, statics, order=None, grip=None) -> tuple[int, Capacity | None] | None:
        """Whether contacts hold every load as the problem asks (`LoadTest.refusal`)."""
        return self.load_test.refusal(patches, statics, order, grip)

    def statics(self, node: Node) -> dict[str, FingerStatics]:
        """Touching finger -> its slot's `FingerStatics` (fingers whose slot has none left out)."""
        out = {}
        for f, s in zip(self.fingers, node):
            if s != LIFTED and self.slots[f][s].statics is not None:
                out[f] = self.slots[f][s].statics
        return out

    def patches(self, node: Node) -> dict[str, Patch]:
        """Owner -> `Patch` of a node: its touching fingers, then the `support` (the palm)."""
        out = {}
        for f, s in zip(self.fingers, node):
            if s != LIFTED:
                out[f] = self.slots[f][s].patch
        out.update(self.support)
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


@dataclass(frozen=True, eq=False)
class LoadTest:
    """The part of a `GaitProblem` that tests whether contacts hold its loads
    (`GaitProblem.load_test`): small and picklable, so a helper process can test a share of
    a batch of states (`Evaluator.evaluate_states`).

    Attributes:
        loads: (name, (6,) wrench) of every load (`GaitProblem.all_loads`).
        friction, grip_friction: the contact friction and the friction the grip forces are
            computed with (`GaitProblem.grip_friction`).
        load_gravity, max_grip_force_n, grip_friction_margin, hold_factor: the problem's.
    """

    loads: tuple
    friction: Friction
    grip_friction: Friction
    load_gravity: np.ndarray | None
    max_grip_force_n: float | None
    grip_friction_margin: float
    hold_factor: float

    def refusal(self, patches, statics, order=None, grip=None) -> tuple[int, Capacity | None] | None:
        """Whether contacts hold every load as the problem asks; None when they do, else
        ``(j, capacity)`` for the first load they do not hold: ``j`` the load's index in
        ``loads`` (``-j - 1``: held ``hold_factor`` times but not the weight itself, where a
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
        loads = self.loads
        grip = [None] * len(loads) if grip is None else grip
        program = contacts = None
        for j in range(len(loads)) if order is None else order:
            if grip[j] is None:
                contacts = contacts or GripContacts(patches, self.grip_friction)  # made once for the loads
                grip[j] = contacts.force(loads[j][1])
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

    def demand(self, patches, statics, why: tuple) -> Demand | None:
        """The torque demand to hold ``hold_factor`` times the load a refusal ``why`` (`refusal`'s
        answer) names, as `Evaluator.refusal` words it; None when its words name none (the
        budget, the weight itself, the force cap binding before a joint)."""
        j, cap = why
        if j < 0 or cap is None or (cap.limit is not None and cap.limit.joint is None):
            return None
        return torque_demand(patches, statics, self.friction, self.loads[j][1], self.load_gravity[j],
                             factor=self.hold_factor, margin=self.grip_friction_margin)


def _evaluate_half(friction: Friction, test: LoadTest | None, order, items) -> list[tuple]:
    """Half of a batch of `Evaluator.evaluate_states`, in this process or the helper's: items
    ``(patches, statics, force closure (None: not known yet), whether to test the loads, grip
    forces so far)`` -> ``(closure computed or None, (refusal, grip forces, the refusal's torque
    demand) or None)`` each; the closures not known in one `batch_grasp_closure` call, the loads
    tested where the state is force closure (and what `Evaluator.refusal` words of a refusal:
    the torque demand, a program of its own, computed here with the rest).

    The grip programs start from scratch at each half (`planner.lp.forget`), in either process:
    a program re-solved from another program's optimum may differ in its last digits, so each
    state's programs are solved in the same sequence wherever the half runs."""
    lp.forget()
    need = [i for i, it in enumerate(items) if it[2] is None]
    computed = dict(zip(need, batch_grasp_closure([items[i][0] for i in need], friction))) if need else {}
    out = []
    for i, (patches, statics, fc, untested, grip) in enumerate(items):
        closure = computed.get(i)
        tested = None
        if untested and (closure.is_force_closure if fc is None else fc):
            grip = list(grip)
            why = test.refusal(patches, statics, order, grip)
            tested = (why, grip, None if why is None else test.demand(patches, statics, why))
        out.append((closure, tested))
    return out


def _same_array(a, b) -> bool:
    return (a is None and b is None) or (a is not None and b is not None and np.array_equal(a, b))


def within_lift_bound(problem: GaitProblem, node: Node) -> bool:
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
        self._refusals = [0] * len(self._loads)  # states each load refused (`evaluate_states`)
        self._over: dict[Node, tuple[int, Capacity | None]] = {}  # refused: `GaitProblem.load_refusal`
        self._demand: dict[Node, Demand] = {}  # of refused states: the torque demand `refusal` words
        self.hold: set[Node] = set()  # torque model: states that hold every load
        self._factors: dict[Node, tuple[float, ...]] = {}  # their capacity factor per load (`hold_factors`)
        #: helper processes `evaluate_states` may use (0 or 1: one helper takes half of a batch)
        self.helpers = 0
        self._helper_proc = None

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
                and problem.max_lifted == old.max_lifted and dict(problem.support).keys() == dict(old.support).keys()
                and all(_same_array(problem.support[k][0], old.support[k][0]) for k in problem.support)
                and all(_same_array(getattr(problem, k), getattr(old, k)) for k in ("load", "loads", "load_gravity")))
        if not same:
            raise InputError("a problem can only be extended with the same friction, loads, grip limits and support")
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
            contacts = GripContacts(patches, self._grip_friction)
            f = self.grip[node] = tuple(contacts.force(w) for _, w in self._loads)
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
        if not within_lift_bound(p, node):
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
        name = self._loads[k][0]
        if j < 0:
            return (f"{name}: holds up to {cap.factor:.3g}x its weight but not the weight itself within the "
                    f"joint limits (a finger's own weight exceeds a joint's limit unless the object presses on it)")
        words = f"{name}: {cap.words(p.hold_factor)}"
        if cap.limit is not None and cap.limit.joint is None:  # the force cap binds, not a joint
            return words
        dem = self._demand.get(node) or p.load_test.demand(p.patches(node), p.statics(node), (j, cap))
        tail = " (but not within the per-finger force cap)" if p.max_grip_force_n is not None and dem.ratio <= 1 else ""
        return f"{words}; to hold {p.hold_factor:g}x, {dem.words()}{tail}"

    def _over_budget(self, node: Node) -> bool:
        """Some load is not held as the problem asks (`GaitProblem.load_refusal`; tested here
        unless `evaluate_states` tested the state in a batch)."""
        if not self._loads:
            return False
        if self._untested(node):
            self.evaluate_states([node])
        return node in self._over

    def evaluate_states(self, nodes: Sequence[Node]) -> None:
        """Closure and load test (`GaitProblem.load_refusal`) of a batch of states, what
        `blocked_reason` and `grip_forces` then read: `planner.gait_search.LazyGraph`'s batch
        of new collision-free states.

        The batch is cut in two halves, the second computed in the helper process when
        `helpers` allows one (while this process computes the first): each half's closures in
        one `batch_grasp_closure` call, then the load test of its force-closure states. The
        loads are tried in the order of how many states each has refused before the batch (one
        program for most refused states instead of all); a state that holds them all gets
        every grip force. The halves and the order are the same with or without a helper, so
        are the results."""
        p, n_loads = self.problem, len(self._loads)
        todo = [n for n in dict.fromkeys(nodes) if n not in self.closure or self._untested(n)]
        if not todo:
            return
        order = sorted(range(n_loads), key=lambda j: (-self._refusals[j], j))
        test = p.load_test if n_loads else None
        items = [(p.patches(n), p.statics(n) if n_loads else None,
                  self.closure[n].is_force_closure if n in self.closure else None, self._untested(n),
                  self.grip.get(n) or [None] * n_loads) for n in todo]
        k = len(items) - len(items) // 2
        halves = [(p.friction, test, order, half) for half in (items[:k], items[k:]) if half]
        helper = self._helper() if len(halves) == 2 else None
        results = helper.map(_evaluate_half, halves) if helper is not None else [_evaluate_half(*h) for h in halves]
        for n, (closure, tested) in zip(todo, itertools.chain.from_iterable(results)):
            if closure is not None:
                self.closure[n] = closure
            if tested is None:
                continue
            why, grip, demand = tested
            if why is not None:
                self._refusals[why[0] if why[0] >= 0 else -why[0] - 1] += 1
                self._over[n] = why
                if demand is not None:
                    self._demand[n] = demand
            else:
                self.grip[n] = tuple(grip)
                self.hold.add(n)

    def _untested(self, n: Node) -> bool:
        """The problem has loads and the state's are not tested yet."""
        return bool(self._loads) and n not in self.hold and n not in self._over

    def _helper(self):
        """The helper process (started at the first batch that needs one), None when this
        evaluator has none."""
        if self.helpers < 1:
            return None
        if self._helper_proc is None or not self._helper_proc.alive:
            if self._helper_proc is not None:  # it failed: the rest runs here
                return None
            from planner.helper import Helper, available  # noqa: PLC0415 - only when a helper is asked for

            try:
                self._helper_proc = Helper() if available() else None
            except OSError:  # the system cannot fork now: the search goes on in one process
                self._helper_proc = None
            if self._helper_proc is None:
                self.helpers = 0
                return None
        return self._helper_proc

    def close(self) -> None:
        """End the helper process, if one was started (the next batch starts another)."""
        if self._helper_proc is not None:
            self._helper_proc.close()
            self._helper_proc = None

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
    """A graph holding only the initial state (what `planner.gait_search.greedy` and `planner.gait_search.LazyGraph` grow).

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
    add_node(G, ev, problem.start)
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
        ev.evaluate([v for *_, v in moves if v not in G and v not in G.graph["blocked"] and within_lift_bound(problem, v)])
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
                add_node(G, ev, v)
                new.append(v)
            G.add_edge(u, v, finger=problem.fingers[i], action=action)
        frontier = new
    for v in G.nodes:
        G.nodes[v]["removable"] = ev.removable(v)
    return G


def add_node(G: nx.DiGraph, ev: Evaluator, v: Node) -> None:
    p = ev.problem
    c = ev.closure[v]
    forces = ev.grip_forces(v)
    G.add_node(v, labels=p.labels(v), patches=p.patches(v), closure=c, metric=float(c.metric),
               grip_force=None if forces is None else max(forces),
               grip_forces=None if forces is None else dict(zip((n for n, _ in p.all_loads()), forces)))


def annotate_removable(G: nx.DiGraph, nodes) -> None:
    """Set the ``removable`` attribute (thesis Algorithm 1) of the given nodes (`planner.gait_search.LazyGraph`
    leaves it unset: it needs the closure of every single-finger lift)."""
    ev: Evaluator = G.graph["evaluator"]
    for v in dict.fromkeys(nodes):
        if "removable" not in G.nodes[v]:
            G.nodes[v]["removable"] = ev.removable(v)
