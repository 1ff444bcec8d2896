"""Planner options: `PlanOptions`, the ranges their numbers are checked against
(`PLAN_OPTION_LIMITS`, read by the CLI too) and the gravity directions a plan is made for
(`gravity_directions_of`).
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

from planner.closure import CONTACT_MODELS
from planner.errors import InputError, PlannerError, UnknownNameError
from planner.gravity import GRAVITY_SET_SIZES, gravity_directions
from planner.grip import FRICTION_MARGIN, HOLD_FACTOR
from planner.gait_search import RANKS

STRATEGIES = ("graph", "greedy")
#: The plan options that are True or False (a plan file's too: `planner.plan`).
SWITCHES = ("motion", "execution", "verify", "repose")
#: Friction fraction execution-mode plans must hold their load with: the grip model's
#: (`planner.grip.FRICTION_MARGIN`), which the replay controller uses too. Measured on exp7
#: (43 pairs, with the 1 N budget of before): 1.0 plans 33 pairs, 26 hold in all 7 gravity
#: directions; 0.75 plans 24, 22 hold; 0.5 plans 17, 17 hold.
EXECUTION_FRICTION_MARGIN = FRICTION_MARGIN
#: Execution mode's contact model: one contact per touching link (a finger holding with two
#: phalanges pushes through two contacts, the palm through its own), as a physics engine's
#: rigid links do; "mean" (one contact per finger, the model before whole-hand grasps) is
#: still accepted for comparison.
EXECUTION_CONTACT_MODEL = "link"
EXECUTION_CONTACT_MODELS = ("link", "mean")


#: Work bound of one finger path: the OMPL planner stops after this many collision checks
#: (state validity checks, each one finger configuration against the object, the palm and
#: the other fingers) without a solution. A count, not a time, so a path, or its failure, is
#: the same on a loaded machine. 20 000 checks take about 1.5 s on one core here (the budget
#: was 2 s); a detour around the object needs a few hundred to a few thousand.
MOTION_CHECKS = 20_000

#: The motion planners (``--motion-planner``): name -> OMPL geometric planner class
#: (`planner.motion` uses those installed; a name is checked by `PlanOptions`, with or
#: without motion, as the plan records it). Asymptotically optimal planners stop at their
#: first solution (cost threshold +inf): the path is then shortened by PathSimplifier.
#: Every planner here is reproducible from the seed and stops on the work bound (collision
#: checks, `MOTION_CHECKS`). PRM and PRM* are left out: they grow their roadmap in a second
#: thread (paths not reproducible, and the work bound, evaluated from both threads,
#: deadlocks); so are FMT and BFMT: they stop after a fixed number of samples whatever the budget.
MOTION_PLANNER_CLASSES = {
    "rrtconnect": "RRTConnect",
    "rrt": "RRT",
    "rrtstar": "RRTstar",
    "informedrrtstar": "InformedRRTstar",
    "sorrtstar": "SORRTstar",
    "kpiece": "KPIECE1",
    "bkpiece": "BKPIECE1",
    "lbkpiece": "LBKPIECE1",
    "bitstar": "BITstar",
    "aorrtc": "AORRTC",
}

#: Ranges of the numeric planner options, checked by `PlanOptions` and, under their
#: command-line names (`PLAN_OPTION_FLAGS`), by the CLI (``planner.cli``): each bounds a loop
#: or a size (alternatives: ranked sequences; intermediate: contacts per finger, the graph
#: grows about quadratically with it). field -> (low, high, low is exclusive); a field with
#: several values (gravity) bounds each.
PLAN_OPTION_LIMITS = {
    "seed": (0, 2**32 - 1, False),
    "alternatives": (1, 100, False),
    "intermediate": (0, 8, False),
    "max_lifted": (1, 16, False),
    "verify_attempts": (1, 100, False),
    "max_rounds": (0, 1000, False),
    "workers": (1, 256, False),
    "motion_checks": (1, 10_000_000, False),
    "time_limit_s": (0.0, 3600.0, False),
    "max_finger_force_n": (0.0, 1000.0, True),
    "hold_factor": (0.0, 100.0, True),
    "gravity": (-1000.0, 1000.0, False),
}
#: The physics engines a plan can be verified in (`planner.sim.engine.ENGINES`, and "both":
#: it must hold in each); written out so that the options load no engine.
VERIFY_ENGINES = ("pybullet", "mujoco", "both")
#: `regrasp plan` option of each `PLAN_OPTION_LIMITS` field named differently (``--time-limit``).
PLAN_OPTION_FLAGS = {"time_limit_s": "time_limit", "max_finger_force_n": "max_finger_force"}


def option_range(low, high, open_low: bool) -> str:
    """'[low, high]' or '(low, high]'."""
    return f"{'(' if open_low else '['}{low}, {high}]"


def in_range(value, low, high, open_low: bool) -> bool:
    """A real number (an integer when ``low`` is one; never a bool) within the range."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral if isinstance(low, int) else numbers.Real):
        return False
    return math.isfinite(value) and (low < value if open_low else low <= value) and value <= high


@dataclass(frozen=True)
class PlanOptions:
    """Planner parameters (all written to the plan's ``parameters``).

    Attributes:
        strategy: "graph" (ranked search) or "greedy" (thesis Algorithm 2).
        alternatives: number of ranked sequences to return (graph strategy).
        intermediate: intermediate contacts per finger, fixed (0: none, or added in rounds
            when needed: see ``time_limit_s``).
        seed: seed for motion planning (intermediate contacts come from a fixed per-finger
            pool, `planner.slots.reachable_contacts`).
        motion: plan finger paths with OMPL (False: straight joint-space segments).
        motion_planner: OMPL planner name (see planner.motion).
        motion_checks: work bound of an OMPL finger path: collision checks before it gives up
            (`MOTION_CHECKS`; a count, not a time: the plan does not depend on
            the machine's load).
        max_lifted: at most this many fingers lifted at once (None = no bound).
        same_slot_tol_rad: initial and final contacts closer than this (max joint
            difference) are one slot: the finger does not move.
        contact_model: "patch" (every patch point has a friction cone, as in the thesis)
            or "mean" (one contact per finger at the patch mean) or "link" (one contact per
            touching link: what rigid links give in the simulator, execution mode's;
            `planner.closure.CONTACT_MODELS`). Every state's
            closure, removability and exported patches use it.
        gravity: None (default: force closure only, as in the thesis) or the gravity
            vector in the palm frame, m/s^2, e.g. (0, 0, 9.81) with the palm facing down.
            Every state must then hold ``hold_factor`` times the object's weight within the
            hand's joint torque limits (`planner.grip.hold_capacity`: contact forces in the
            friction cones scaled by ``friction_margin``, ``|g(q) + J^T f| <= tau_max`` at
            every joint of the touching fingers, weight at the object origin).
        friction_margin: the grip forces against gravity are computed with ``mu`` and
            ``gamma`` scaled by this (0 < margin <= 1); execution mode uses
            ``EXECUTION_FRICTION_MARGIN``: a plan for execution must hold its load with a
            friction reserve, as the replay's controller does.
        max_finger_force_n: optional extra cap on every finger's normal force against
            gravity, N (default None: the joints' torque limits alone bound the grip).
        hold_factor: the multiple of the weight every state must hold (default
            `planner.grip.HOLD_FACTOR`, the replay controller's squeeze safety factor).
        verify: replay the best sequence in a physics engine under every planned-for gravity
            direction before returning it (`planner.sim.verify`, directions in parallel
            processes); the transition that failed first is removed and the search goes on
            (execution mode's default; needs ``gravity`` or ``gravity_set``).
        engine: the physics engine of the verification: "pybullet", "mujoco", "both" (the
            plan is returned only if it holds in each) or None (`planner.sim.engine
            .default_engine`: pybullet when installed, else MuJoCo). Recorded in the plan's
            ``summary.verification.engine``.
        verify_attempts: sequences replayed at most before giving up (a bound on the work,
            not on the time, so the plan does not depend on the machine's load).
        workers: processes for the verification replays and the gait search (None: the
            cores available; with two or more the search evaluates half of each batch of states
            in a helper process, `planner.graph.Evaluator.evaluate_states`). The plan is the same for
            any number (the search's states are evaluated alike in either process; not written to
            its parameters).
        gravity_set: None or a set size of `planner.gravity.GRAVITY_SET_SIZES` (1, 2, 6, 7):
            plan for several hand orientations at once, the named gravity directions of
            `planner.gravity.gravity_directions` (from the hand's ``palm_normal``). A state
            must then hold the weight in each of them. Exclusive with ``gravity``.
        rank: how sequences are ranked (`planner.gait_search.RANKS`): "metric" (the thesis:
            largest worst-case closure metric first) or "grip" (smallest largest grip force
            along the sequence first, then fewest gait steps, then the metric ranking;
            needs ``gravity`` or ``gravity_set``).
        execution: label of plans meant to be executed (`PlanOptions.for_execution`): it
            requires the "link" (or "mean") contact model, the "grip" ranking and a gravity.
        max_rounds: with ``intermediate`` 0 the planner is anytime: when no sequence exists
            with the current contacts, it adds intermediate contacts
            (`planner.regrasp.INTERMEDIATE_PER_ROUND` per finger that blocks progress, from
            `planner.slots.reachable_contacts`) and searches again, round after round, until a sequence
            is found, no contact is left to add or ``max_rounds`` rounds were made. The
            rounds are deterministic and bounded by this count (and each search by its
            expanded states), not by the clock: the plan, or the explanation of a failure,
            is the same on a loaded machine. 0 disables the rounds.
        repose: let the hand move the object (in-grasp reposing, `planner.pose_search`): grasps
            whose object poses differ are joined by reposing moves, and when finger gaits
            alone find nothing the object may be rested on the palm first. False: the grasps
            must share the object's pose and only gaits are planned.
        time_limit_s: an optional cap on the search time (graph strategy), s; None (the
            default): no cap, the work bounds (``max_rounds``, expanded states) end the search,
            so the plan or the refusal is the same on a loaded machine; 0: no rounds. Reaching a
            cap is reported (the result then depends on the machine's speed). Finger paths are
            not counted.
    """

    strategy: str = "graph"
    alternatives: int = 4
    intermediate: int = 0
    seed: int = 0
    motion: bool = True
    motion_planner: str = "rrtconnect"
    motion_checks: int = MOTION_CHECKS
    max_lifted: int | None = None
    same_slot_tol_rad: float = 1e-3
    contact_model: str = "patch"
    gravity: tuple[float, float, float] | None = None
    max_finger_force_n: float | None = None
    friction_margin: float = 1.0
    gravity_set: int | None = None
    rank: str = "metric"
    execution: bool = False
    time_limit_s: float | None = None
    max_rounds: int = 4
    hold_factor: float = HOLD_FACTOR
    verify: bool = False
    verify_attempts: int = 6
    workers: int | None = None
    engine: str | None = None
    repose: bool = True

    @classmethod
    def for_execution(cls, **overrides) -> "PlanOptions":
        """Options for a plan that is to be executed: one contact per touching link (what
        rigid links give in a physics engine, `EXECUTION_CONTACT_MODEL`), gravity set 6 (palm down, palm up and the four sideways
        directions) unless ``gravity`` or ``gravity_set`` is given, grip ranking."""
        kw = dict(contact_model=EXECUTION_CONTACT_MODEL, rank="grip", execution=True, friction_margin=EXECUTION_FRICTION_MARGIN,
                  verify=True)
        if overrides.get("gravity") is None and overrides.get("gravity_set") is None:
            kw["gravity_set"] = 6
        kw.update({k: v for k, v in overrides.items() if v is not None or k not in kw})
        return cls(**kw)

    def __post_init__(self):
        for name in SWITCHES:  # motion="no" planned paths ("no" is truthy)
            if not isinstance(getattr(self, name), bool):
                raise InputError(f"PlanOptions.{name} must be True or False, got {getattr(self, name)!r}")
        if self.gravity is not None:
            try:
                g = tuple(self.gravity)
            except TypeError:
                raise PlannerError(f"gravity must be 3 numbers (palm frame, m/s^2), got {self.gravity!r}") from None
            if len(g) != 3:
                raise PlannerError(f"gravity must be 3 numbers (palm frame, m/s^2), got {self.gravity!r}")
            object.__setattr__(self, "gravity", g)  # as floats once their range is checked, below
        if not (isinstance(self.friction_margin, (int, float)) and 0 < self.friction_margin <= 1):
            raise PlannerError(f"friction_margin must be in (0, 1], got {self.friction_margin!r}")
        if self.gravity_set is not None:
            if self.gravity is not None:
                raise PlannerError("give either a gravity vector or a gravity set, not both")
            if isinstance(self.gravity_set, bool) or self.gravity_set not in GRAVITY_SET_SIZES:
                raise PlannerError(f"gravity set size must be one of {', '.join(map(str, GRAVITY_SET_SIZES))}, "
                                   f"got {self.gravity_set!r}")
        if self.rank not in RANKS:
            raise UnknownNameError("rank", self.rank, RANKS)
        if self.rank == "grip" and self.gravity is None and self.gravity_set is None:
            raise PlannerError("grip ranking needs a gravity: give --gravity GX GY GZ or --gravity-set N "
                               "(PlanOptions gravity or gravity_set)")
        if self.execution and (self.contact_model not in EXECUTION_CONTACT_MODELS or self.rank != "grip"):
            raise PlannerError(f"execution mode plans with the 'link' (or 'mean') contact model and grip ranking, got contact "
                               f"model {self.contact_model!r} and rank {self.rank!r}")
        if self.engine is not None and self.engine not in VERIFY_ENGINES:
            raise UnknownNameError("physics engine", str(self.engine), VERIFY_ENGINES)
        if self.strategy not in STRATEGIES:
            raise UnknownNameError("strategy", self.strategy, STRATEGIES)
        if self.contact_model not in CONTACT_MODELS:
            raise UnknownNameError("contact model", self.contact_model, CONTACT_MODELS)
        if self.motion_planner not in MOTION_PLANNER_CLASSES:  # also without motion: the plan records it
            raise UnknownNameError("motion planner", str(self.motion_planner), sorted(MOTION_PLANNER_CLASSES))
        for name, (low, high, open_low) in PLAN_OPTION_LIMITS.items():
            value = getattr(self, name)
            optional = value is None and name in ("max_lifted", "gravity", "max_finger_force_n", "workers", "time_limit_s")
            for v in () if optional else value if isinstance(value, tuple) else (value,):
                if not in_range(v, low, high, open_low):
                    kind = "an integer" if isinstance(low, int) else "a number"
                    raise InputError(f"PlanOptions.{name} must be {kind} in {option_range(low, high, open_low)}, got {v!r}")
        if self.gravity is not None:
            object.__setattr__(self, "gravity", tuple(float(v) for v in self.gravity))


def verifies(verify, strategy: str, directions, reposes: bool = False) -> bool:
    """Whether a plan is verified in the simulator (and records it, ``summary.verification``):
    asked (``verify``), made for gravity directions, by the graph search (`planner.regrasp`;
    the greedy strategy replays nothing) or with reposing moves (`planner.pose_search`
    verifies every plan it composes)."""
    return verify is True and bool(directions) and (strategy == "graph" or reposes)


def gravity_directions_of(options: PlanOptions, hand) -> list[tuple[str, tuple[float, float, float]]]:
    """The named gravity vectors (palm frame, m/s^2) a plan is made for: ``[("gravity",
    options.gravity)]``, the set of `planner.gravity.gravity_directions` for
    ``options.gravity_set`` (from ``hand.palm_normal``), or [] (force closure only)."""
    if options.gravity is not None:
        return [("gravity", tuple(float(v) for v in options.gravity))]
    if options.gravity_set is not None:
        # [:n]: planner.gravity returns palm down *and* palm up for n = 1 (its docstring says
        # palm down only); the first n entries are the documented set for every size.
        return gravity_directions(hand.palm_normal, options.gravity_set)[: options.gravity_set]
    return []
