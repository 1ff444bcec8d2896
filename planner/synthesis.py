"""Grasp synthesis: force-closure grasps of a hand on an object, written as grasp files.

``regrasp synth HAND OBJECT.yaml --fingers thumb,index,middle -n 20 -o DIR`` samples hand
pre-shapes, closes the chosen fingers onto the object with the thesis's closing procedure
(eqs. (8)-(9), `planner.hand.Hand.close_finger`: every closing joint advances by the same
fraction of its range, halving the step and reversing on contact, then backs off 0.1 % until
free), and keeps a candidate when it passes the same honest check as ``regrasp check``
(`planner.realization.realize`: every chosen finger touches, nothing penetrates the object, the
palm or another finger beyond `planner.realization.PENETRATION_TOL_M`, no closing joint at its
limit, force closure) and, with a gravity, holds twice the object's weight within the hand's
joint torque limits (`planner.grip`, the model `plan` uses). Near-duplicates are
removed, the rest ranked by the closure metric and written as grasp YAML files that
``regrasp check`` accepts unchanged: each file is built first, parsed and realized exactly
as ``check`` does, and kept only if that passes.

Object file (``OBJECT.yaml``): the ``object:`` block of the grasp schema on its own (keys
``shape``, ``size``, optional ``position``, ``quat_xyzw``, ``mesh``, ``mass_kg``), either at
the top level or under an ``object:`` key (so a grasp file works too; its friction is then
used unless ``--mu``/``--gamma`` are given).
- Without ``position``: the object pose is sampled too (an "approach"): the object centre
  is put where the chosen fingers' pads of a random pre-shape would all touch a ball of the
  object's inner radius (`planner.synth_sample.sample_candidate`), with a random
  orientation, and the fingers close onto it from the pre-shape.
- With ``position`` (and ``quat_xyzw``, default identity): the object stays there (all
  grasps share the pose, so any two of them can be a regrasp pair) and only the finger
  pre-shapes are sampled.

Whole-hand grasps (``--palm``, ``synthesize(..., palm=True)``): the object is placed AGAINST
the palm instead of clear of it (`planner.synth_sample.sample_candidate`: moved along the
hand's ``palm_normal`` until it is `planner.synth_sample.PALM_TOUCH_GAP_M` from the palm),
the palm's patch is part of every closure and hold test, and the written files say
``palm: hold`` (so ``check`` fails them if the palm does not touch). With all fingers (the
default fingers with ``--palm``) these are power grasps. A fixed pose is kept and must
touch the palm already (`check_palm_pose`).
"""

from __future__ import annotations

import math
import numbers
import os
import sys
import time
from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from planner.closure import CONTACT_MODELS, apply_contact_model, grasp_closure, min_grip_force
from planner.contacts import TOUCH_TOL_M
from planner.errors import OutputError, PlannerError, SpecError, UnknownNameError
from planner.fileio import MAX_GRASP_BYTES, Reader, read_yaml, resolve_path, write_atomic
from planner.grasp import load_hand, parse_friction, parse_grasp, resolve_hand_ref
from planner.gravity import gravity_label_of
from planner.grip import HOLD_FACTOR, grasp_statics, grip_program, hold_capacity, holds_by_bound
from planner.model import GAMMA_MAX_M, MU_MAX, PALM, Friction
from planner.objects import GraspObject, read_object
from planner.realization import PENETRATION_TOL_M, execution_refusal, realize
from planner.synth_sample import (PALM_CLEARANCE_M, Rejection, cannot_back_off, closes_onto, inner_radius,
                                  object_of, sample_candidate)

#: Two grasps are near-duplicates when every chosen finger's mean contact point (palm frame)
#: and the object centre differ by less than this, and the contact normals by less than
#: ``DUPLICATE_TOL_M / 0.01 m`` radians (0.5 rad).
DUPLICATE_TOL_M = 0.005
#: Default friction when the object file has none (the bundled grasps' values).
DEFAULT_FRICTION = {"mu": 0.9, "gamma": 0.004, "edges": 5}


class SynthGrasp:
    """One synthesized grasp: its file data, closure metric, grip force, the attempt that made it,
    and whether ``plan --execution`` accepts it (`planner.realization.execution_verdict`: None,
    or the planner's words for refusing it). ``grasp`` is the realized grasp that passed the
    check (re-realized from ``data`` on first use when a worker process made it)."""

    __slots__ = ("data", "grip_force_n", "attempt", "metric", "execution", "held_in", "_grasp", "_base")

    def __init__(self, data: dict, grasp=None, grip_force_n: float | None = None, attempt: int = 0, *,
                 metric: float | None = None, execution: str | None = None, base_dir="."):
        self.data, self.grip_force_n, self.attempt = data, grip_force_n, attempt
        self.metric = float(grasp.metric if metric is None else metric)
        self.execution, self._grasp, self._base = execution, grasp, str(base_dir)
        #: the physics engine that held it as plan --execution holds an end grasp (`hold_in_engine`),
        #: None when not replayed
        self.held_in: str | None = None

    @property
    def grasp(self):  # planner.realization.RealizedGrasp
        if self._grasp is None:
            self._grasp = realize(parse_grasp(self.data, Path(self._base) / "candidate.yaml"))
        return self._grasp

    @property
    def execution_ready(self) -> bool:
        return self.execution is None

    @property
    def not_held(self) -> bool:
        """Execution mode's static test accepted it and the physics engine did not hold it
        (`hold_in_engine`): refused as an initial grasp, a plan arriving at it may still end in it."""
        return self.execution is not None and self.execution.startswith(_NOT_HELD)

    def rank_key(self) -> tuple:
        """Execution-accepted grasps first, then the larger closure metric, then the earlier attempt."""
        return (self.execution is not None, -self.metric, self.attempt)


@dataclass(frozen=True)
class SynthResult:
    """Outcome of `synthesize`: the kept grasps (best metric first) and the effort."""

    grasps: tuple
    attempts: int
    #: candidates that passed every test, and the near-duplicates among them; a candidate that
    #: passed the check and is a near-duplicate of a kept grasp ranked no worse than it could be
    #: is counted in both without the remaining tests (weight, back-off, execution verdict),
    #: which could not change the kept grasps (`_outranked`)
    candidates_passed: int
    duplicates: int
    seconds: float
    rejected: dict = None   # reason -> attempts dropped for it
    palm: bool = False      # whole-hand grasps (the object against the palm)
    by_finger: dict = None  # finger -> {reason: attempts dropped for it that were about that finger}
    verified: bool = False  # the execution-ready grasps were held in a physics engine (`hold_in_engine`)
    fixed: bool = False     # the object's pose was the file's (else sampled per attempt)


def load_object_file(path) -> tuple[GraspObject, dict | None, bool]:
    """Read an object file: (the object, friction block or None, pose_fixed); an object
    file without a pose is at the palm frame's origin (synthesis samples its pose). The
    object block is checked by the one object-block validator
    (`planner.objects.check_object_block`), a friction block as a grasp file's
    (`planner.grasp.parse_friction`).

    Raises:
        SpecError: naming the file, the key path and the valid range.
    """
    path = Path(path)
    # the bounded reader: size, nesting, aliases and integer digits limited, a FIFO refused
    r = Reader(path, read_yaml(path, MAX_GRASP_BYTES, "object file"))
    data = r.mapping("a YAML mapping: the object block (shape, size, ...) or a file with an object: key",
                     string_keys=True).value
    friction = None
    o = r  # the block at the top level: its keys have no "object." prefix there
    if "object" in data:
        if data.get("friction") is not None:
            friction = parse_friction(r.child("friction")).to_data()
        o = r.child("object").mapping(string_keys=True)
    elif "shape" not in data:
        raise r.fail("expected an object block (keys shape, size[, position, quat_xyzw, mesh, mass_kg]) "
                     "at the top level or under an object: key")
    fixed = "position" in o.value
    block = {"position": [0.0, 0.0, 0.0], "quat_xyzw": [0.0, 0.0, 0.0, 1.0], **o.value}
    return read_object(o.at(block), path.parent), friction, fixed


def _grasp_data(hand_ref, obj: GraspObject, friction, fingers, preshape, name, description, palm=False) -> dict:
    block = obj.to_data()
    palm_key = {"palm": "hold"} if palm else {}
    return {
        "schema_version": 1,
        "name": name,
        "description": description,
        "hand": hand_ref,
        "object": {k: v for k, v in block.items() if v is not None},  # no mesh, no mass: not written
        "friction": dict(friction),
        "fingers": {f.name: {"posture": [float(v) for v in preshape[f.name]]} for f in fingers},
        **palm_key,
    }


def _features(grasp, fingers) -> np.ndarray:
    """Palm-frame mean contact point and mean normal of each chosen finger, and the object centre."""
    T = np.asarray(grasp.obj.T_palm_obj)
    R, t = T[:3, :3], T[:3, 3]
    rows = [t]
    for f in fingers:
        p, n = grasp.patches[f.name]
        rows.append(R @ np.mean(p, axis=0) + t)
        m = R @ np.mean(n, axis=0)
        rows.append(0.01 * m / max(np.linalg.norm(m), 1e-12))
    return np.array(rows)


def _is_duplicate(a: np.ndarray, b: np.ndarray) -> bool:
    return bool(np.max(np.linalg.norm(a - b, axis=1)) < DUPLICATE_TOL_M)


def _outranked(kept, features: np.ndarray, metric: float, attempt: int) -> bool:
    """Whether a candidate with these features (`_features`) and closure metric is a
    near-duplicate of a kept grasp (``kept``: (features, rank key) pairs, the first twin as
    `synthesize` finds it) that it could not replace even if it passed every remaining test
    and execution mode accepted it (`SynthGrasp.rank_key`: the kept one ranks no worse than
    the best key the candidate can get): the remaining tests cannot change the kept grasps."""
    twin = next((key for fk, key in kept if _is_duplicate(fk, features)), None)
    return twin is not None and twin <= (False, -float(metric), attempt)


def require_palm(hand) -> None:
    """PlannerError (one line) when the hand has no palm collision geometry (``--palm``)."""
    if not hand.collision.finger_links(None):
        raise PlannerError(f"synth: --palm: hand {hand.name} has no palm collision geometry (no link of its base has "
                           f"a <collision>): there is nothing to rest the object on")


def check_palm_pose(hand, obj: GraspObject) -> None:
    """With ``--palm`` and a fixed pose: PlannerError (one line) unless the object touches the
    palm there (within `planner.contacts.TOUCH_TOL_M`) without penetrating it (beyond
    `planner.realization.PENETRATION_TOL_M`)."""
    require_palm(hand)
    d = hand.state(hand.q_open).palm_object_distance(obj)
    at = "[" + ", ".join(f"{v:.4f}" for v in obj.position) + "]"
    n = "[" + ", ".join(f"{v:g}" for v in hand.palm_normal) + "]"
    if d > TOUCH_TOL_M:
        raise PlannerError(f"synth: --palm: the object at its fixed position {at} is {d * 1e3:.1f} mm from the palm "
                           f"(the palm touches within {TOUCH_TOL_M * 1e3:g} mm): move it onto the palm (palm_normal "
                           f"{n}), remove position to let synth place it, or drop --palm")
    if d < -PENETRATION_TOL_M:
        raise PlannerError(f"synth: --palm: the object at its fixed position {at} is {-d * 1e3:.1f} mm inside the palm "
                           f"(tolerance {PENETRATION_TOL_M * 1e3:g} mm): move it out along palm_normal {n}")


def synthesize(hand_ref: str, obj: GraspObject | Mapping, fingers, n: int, *, fixed: bool, friction=None, seed: int = 0,
               gravity=None, max_finger_force_n: float | None = None, max_attempts: int | None = None, base_dir=".",
               progress=None, contact_model: str = "patch", friction_margin: float = 1.0,
               hold_factor: float = HOLD_FACTOR, palm_clearance_m: float = PALM_CLEARANCE_M,
               palm: bool = False, workers: int = 1, verify: bool = False, engine: str | None = None,
               gravity_name: str | None = None) -> SynthResult:
    """Sample, close, check, de-duplicate and rank grasps.

    Args:
        hand_ref: hand name under robots/ or an absolute hand.yaml path.
        obj: the object (`load_object_file`), or its ``object:`` block; at its pose when ``fixed``.
        fingers: names of the fingers that grasp (the others stay open).
        n: grasps wanted.
        fixed: keep the object's pose (True) or sample it per attempt.
        friction: {mu, gamma, edges} (default `DEFAULT_FRICTION`).
        seed: seed of every random choice (the result depends on nothing else).
        gravity: None, a (3,) palm-frame gravity (m/s^2) or several, (k, 3): keep grasps holding
            ``hold_factor`` times the weight in every one within the hand's joint torque
            limits (`planner.grip.hold_capacity`, and each finger pressing at most
            ``max_finger_force_n`` when given); ``grip_force_n`` is the largest
            `min_grip_force` over the directions.
        max_finger_force_n: optional per-finger normal force cap, N.
        hold_factor: multiple of the weight the grasp must hold (`planner.grip.HOLD_FACTOR`).
        palm_clearance_m: a sampled object pose keeps this gap to the palm (default
            `PALM_CLEARANCE_M`); a grasp meant to be executed wants at least the replay's
            drift limit, or the object can settle onto the palm within the limits.
        contact_model: "patch" (the check's closure) or "mean": also require force closure with
            one contact per finger at its patch mean, and compute the grip force with those
            contacts (what `PlanOptions.for_execution` plans with).
        friction_margin: the grip force is computed with ``mu`` and ``gamma`` scaled by this
            (execution mode's friction reserve: `planner.options.EXECUTION_FRICTION_MARGIN`).
        max_attempts: candidates sampled at most (default 60 n).
        base_dir: where the grasp files will live (anchors relative paths in error messages).
        progress: None or callable(str) for progress lines.
        palm: whole-hand grasps: the object against the palm (``palm_clearance_m`` unused),
            the palm's patch in the closure and hold tests, ``palm: hold`` in the files; a
            fixed pose must touch the palm (`check_palm_pose`, before any sampling).
        workers: processes that run attempts (1: this one). Attempt k draws from a
            generator seeded by (seed, k) and the outcomes are taken in attempt order, so
            the result is the same for any number of workers.
        verify: hold the kept grasps execution mode's static test accepts in a physics engine
            (``engine``: None the default one), as ``plan --execution`` replays an initial grasp
            (`hold_in_engine`): those that drop are ranked after the accepted ones, with the
            engine's verdict; no other grasp is sought in their place (a bound on the work).
        gravity_name: the name of the one ``gravity`` given (``--gravity palm_down``), said in a
            replay's verdict instead of "gravity".

    Returns:
        `SynthResult` with up to n grasps ranked by `SynthGrasp.rank_key`: those
        ``plan --execution`` accepts first (`planner.realization.execution_verdict`: force
        closure with its contact model, the load held in every planned direction), then by
        the closure metric.
    """
    t0 = time.perf_counter()
    hand = load_hand(hand_ref)
    chosen = [hand.finger(f) for f in fingers]
    if not chosen:
        raise PlannerError("synth: give at least one finger (--fingers thumb,index,...)")
    friction = dict(DEFAULT_FRICTION if friction is None else friction)
    # counts of the Python API as the CLI's (a str was a TypeError, a negative seed numpy's ValueError)
    for name, value, low, high in (("n", n, 1, MAX_GRASPS), ("workers", workers, 1, MAX_WORKERS),
                                   ("seed", seed, 0, 2**32 - 1), ("max_attempts", max_attempts, 1, MAX_ATTEMPTS)):
        if value is None and name == "max_attempts":
            continue
        if isinstance(value, bool) or not isinstance(value, numbers.Integral) or not low <= value <= high:
            raise PlannerError(f"synth: {name} must be an integer in {low}..{high}, got {value!r}")
    if not isinstance(verify, bool):  # (verify="no" replayed)
        raise PlannerError(f"synth: verify must be True or False, got {verify!r}")
    if verify:  # an engine unknown or not installed: refused before the synthesis, not after it
        from planner.sim.verify import engines_of

        engines_of(engine)
    if contact_model not in CONTACT_MODELS:
        raise UnknownNameError("contact model", contact_model, CONTACT_MODELS)
    if not 0 < friction_margin <= 1:
        raise PlannerError(f"synth: friction_margin must be in (0, 1], got {friction_margin!r}")
    max_attempts = 60 * n if max_attempts is None else max_attempts
    obj = object_of(obj)
    if palm:
        require_palm(hand)
    if palm and fixed:
        check_palm_pose(hand, obj)
    ctx = _Context(hand_ref, hand, [f.name for f in chosen], obj, fixed, friction, seed, gravity, max_finger_force_n,
                   str(base_dir), contact_model, friction_margin, hold_factor, palm_clearance_m, palm)
    kept: list[tuple[np.ndarray, SynthGrasp]] = []
    passed = dups = 0
    rejected = Counter()
    by_finger: dict[str, Counter] = {f.name: Counter() for f in chosen}
    attempt = 0

    def view():  # what an attempt needs to know of the kept grasps (`_outranked`)
        return [(fk, c.rank_key()) for fk, c in kept]

    def ahead():  # attempts worth computing ahead: about what the missing grasps take at the rate so far
        return math.ceil((n - len(kept)) * max(attempt, 1) / max(len(kept), 1))

    for attempt, (why, out, probe) in _outcomes(ctx, max_attempts, workers, view, ahead):
        if probe is not None and _outranked(view(), *probe[:2], attempt):
            # a near-duplicate of a kept grasp it cannot replace: counted so whether or not the
            # attempt ran the remaining tests (a worker knows the kept grasps of when it started)
            passed += 1
            dups += 1
            why, out = "", None
        elif probe is not None and probe[2]:
            # the attempt skipped the remaining tests for a twin replaced since: run them here
            why, out, _ = _attempt(ctx, attempt)
        if out is None:
            if why:
                rejected[why] += 1
                for f in getattr(why, "fingers", ()):
                    if f in by_finger:  # (a collision may name a finger that does not grasp)
                        by_finger[f][str(why)] += 1
        else:
            passed += 1
            feat, cand = out
            twin = next((i for i, (fk, _) in enumerate(kept) if _is_duplicate(fk, feat)), None)
            if twin is not None:
                dups += 1
                if cand.rank_key() < kept[twin][1].rank_key():
                    kept[twin] = (feat, cand)
            else:
                kept.append((feat, cand))
        if progress is not None:
            top = max(rejected.items(), key=lambda kv: (kv[1], kv[0]))[0] if rejected else ""
            ready = sum(1 for _, c in kept if c.execution_ready)
            progress(f"synth: {len(kept)}/{n} grasps ({ready} execution-ready) after {attempt}/{max_attempts} "
                     f"attempts, {time.perf_counter() - t0:.1f} s" + (f"; most rejected: {top}" if top else ""))
        if len(kept) >= n:
            break
    ranked = [c for _, c in kept]
    if verify:
        hold_in_engine(ranked, gravity, engine, progress, gravity_name)
    ranked.sort(key=SynthGrasp.rank_key)
    return SynthResult(grasps=tuple(ranked), attempts=attempt, candidates_passed=passed, duplicates=dups,
                       seconds=time.perf_counter() - t0, rejected=dict(rejected), palm=palm,
                       by_finger={f: dict(c) for f, c in by_finger.items()}, verified=verify, fixed=bool(fixed))


#: How `hold_in_engine` words a grasp the physics engine did not hold.
_NOT_HELD = "does not hold in the simulator"


def hold_in_engine(grasps, gravity=None, engine: str | None = None, progress=None,
                   gravity_name: str | None = None) -> None:
    """Hold each grasp that execution mode's static test accepts in a physics engine, as ``plan
    --execution``'s verification replays an initial grasp (`planner.regrasp.end_grasp_replay`,
    what ``check --execution`` runs): one that holds gets ``held_in`` (the engine), one that does
    not gets the engine's verdict as its ``execution`` refusal (ranked after the accepted ones).
    ``gravity``: synthesize's (one direction: replayed there; none or several: execution mode's
    six; ``gravity_name``: how the one direction is named in a verdict, else "gravity"). Of 54
    synthesized grasps the static test accepted (a sweep of 11 objects on 4 hands), the
    simulator dropped or turned 8, which synth had said plan --execution accepts. The replay
    is how a plan tests its initial grasp: a plan arriving at a grasp that fails it may still
    end in it (`verdict_words` says so)."""
    from planner.errors import NoSequenceError
    from planner.regrasp import end_grasp_replay  # deferred: the physics engine

    dirs = None if gravity is None else np.asarray(gravity, dtype=float).reshape(-1, 3)
    one = dirs[0] if dirs is not None and len(dirs) == 1 else None
    ready = [c for c in grasps if c.execution_ready]
    for k, c in enumerate(ready, start=1):
        if progress is not None:
            progress(f"synth: holding grasp {k}/{len(ready)} in a physics engine (--no-verify skips it)")
        try:
            v = end_grasp_replay(c.grasp, one, engine=engine)
        except NoSequenceError as err:
            c.execution = f"{_NOT_HELD}: {err}"
            continue
        failure = v.first_failure()
        if failure is None:
            c.held_in = v.engine_names
        else:
            where = (gravity_name or failure[0]) if one is not None else failure[0]  # ("gravity": the one given)
            c.execution = f"{_NOT_HELD} ({where}: {failure[2]})"


@dataclass
class _Context:
    """What one attempt needs (`_attempt`); a worker process builds its own hand from ``hand_ref``."""

    hand_ref: str
    hand: object
    fingers: list
    obj: GraspObject
    fixed: bool
    friction: dict
    seed: int
    gravity: object
    max_finger_force_n: float | None
    base_dir: str
    contact_model: str
    friction_margin: float
    hold_factor: float
    palm_clearance_m: float
    palm: bool

    def __getstate__(self):
        return {**self.__dict__, "hand": None}

    def __setstate__(self, state):
        self.__dict__.update(state)
        self.hand = load_hand(self.hand_ref)


#: Attempts a worker process runs per job (`_outcomes`): one, so that at most
#: ``2 x workers`` attempts (``workers`` when the missing grasps need fewer at the rate so
#: far) are computed past the one that completes the n grasps.
ATTEMPTS_PER_JOB = 1
_WORKER_CTX: _Context | None = None  # the context of the running synthesis, in its workers
_IN_WORKER = False


def _worker_init(ctx: _Context | None, parent: int | None = None) -> None:
    global _WORKER_CTX, _IN_WORKER
    _IN_WORKER = True
    if parent is not None:  # end with synth's process, however it ends (`planner.helper.die_with_parent`)
        from planner.helper import die_with_parent

        die_with_parent(parent)
    if ctx is not None:  # spawned: the context came pickled (the hand re-loaded); forked: inherited
        _WORKER_CTX = ctx


def _worker_job(first: int, count: int, kept) -> list:
    return [_attempt(_WORKER_CTX, k, kept) for k in range(first, first + count)]


def _outcomes(ctx: _Context, max_attempts: int, workers: int, view=None, ahead=None):
    """(attempt, `_attempt` outcome) for attempts 1..max_attempts, in order; with ``workers``
    > 1 computed ahead by that many processes (forked where the platform can: they inherit
    the loaded hand). Each attempt draws from its own generator (seeded by (seed, attempt)),
    so the outcomes, and the grasps kept from them in order, do not depend on the number of
    workers or on which worker ran what. ``view()``: the kept grasps when an attempt starts
    (`_attempt`'s ``kept``). ``ahead()``: how many attempts are worth computing ahead (the
    missing grasps at the rate so far): between ``workers`` and ``2 x workers`` are pending,
    so that near the end fewer attempts are computed past the one that completes the grasps
    (the outcomes are taken in attempt order all the same)."""
    global _WORKER_CTX
    if workers == 1 or max_attempts <= 1:
        for k in range(1, max_attempts + 1):
            yield k, _attempt(ctx, k, None if view is None else view())
        return
    import multiprocessing
    from collections import deque
    from concurrent.futures import ProcessPoolExecutor

    fork = "fork" in multiprocessing.get_all_start_methods()
    _WORKER_CTX = ctx
    pool = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("fork" if fork else "spawn"),
                               initializer=_worker_init, initargs=(None if fork else ctx, os.getpid()))
    pending = deque()
    nxt = 1
    try:
        while nxt <= max_attempts or pending:
            window = 2 * workers if ahead is None else min(2 * workers, max(workers, ahead()))
            while nxt <= max_attempts and len(pending) < window:
                count = min(ATTEMPTS_PER_JOB, max_attempts - nxt + 1)
                pending.append((nxt, pool.submit(_worker_job, nxt, count, None if view is None else view())))
                nxt += count
            first, fut = pending.popleft()
            for i, out in enumerate(fut.result()):
                yield first + i, out
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
        _WORKER_CTX = None


def _attempt(ctx: _Context, attempt: int, kept=None):
    """One synthesis attempt: (why it was rejected, None, probe) or ("", (features,
    `SynthGrasp`), probe). ``probe``: None when it was dropped before its contacts were known,
    else (features, closure metric, skipped): with ``kept`` (the kept grasps' (features,
    rank key) when it started) a candidate `_outranked` by one of them skips the remaining
    tests (the weight, the back-off, the execution verdict; ("", None, (..., True))), which
    could not change the kept grasps."""
    hand, obj = ctx.hand, ctx.obj
    chosen = [hand.finger(f) for f in ctx.fingers]
    rng = np.random.default_rng([ctx.seed, attempt])
    friction = ctx.friction
    fr = Friction(friction["mu"], friction["gamma"], friction.get("edges", 5))
    placed, preshape, why = sample_candidate(hand, chosen, obj, ctx.fixed, rng, inner_radius(obj),
                                             ctx.palm_clearance_m, palm=ctx.palm, mu=fr.mu * ctx.friction_margin)
    if preshape is None:
        return why, None, None
    q_closed, why = closes_onto(hand, chosen, placed, preshape, palm=ctx.palm)
    if q_closed is None:
        return why, None, None
    data = _grasp_data(ctx.hand_ref, placed, friction, chosen, preshape, "candidate", "", palm=ctx.palm)
    try:
        spec = parse_grasp(data, Path(ctx.base_dir) / "candidate.yaml")
    except SpecError:
        return "", None, None
    g = realize(spec, hand)
    # the pre-filter's force closure: the chosen fingers' patches (and the palm's with palm)
    own = {k: v for k, v in g.patches.items() if k in ctx.fingers or (ctx.palm and k == PALM)}
    pre = g.closure if (own.keys() == g.patches.keys() and g.friction == fr) else grasp_closure(own, fr)
    if set(ctx.fingers) <= set(own) and not pre.is_force_closure:
        return "not force closure", None, None
    if not g.ok:
        return _check_reason(g, hand), None, None
    # the contacts are known: a near-duplicate of a kept grasp it cannot replace is not tested
    # further (near-duplicates were 24 of the 64 iCub candidates passing every test, 30 mm ball)
    features = _features(g, chosen)
    if kept is not None and _outranked(kept, features, g.metric, attempt):
        return "", None, (features, g.metric, True)
    probe = (features, g.metric, False)
    patches = dict(g.patches)  # with palm: hold, the palm's patch among them (rigid in the grip model)
    if ctx.contact_model != "patch":
        if not g.closure_under(ctx.contact_model).is_force_closure:
            return f"not force closure with {ctx.contact_model} contacts", None, probe
        patches = apply_contact_model(patches, ctx.contact_model)
    grip = None
    dirs = None if ctx.gravity is None else np.asarray(ctx.gravity, dtype=float).reshape(-1, 3)
    if dirs is not None:
        grip = _hold_grip(ctx, hand, g, patches, fr, dirs)
        if grip is None:
            return "weight beyond the hand's limits", None, probe
    # a finger held against the object by its own joint limits can never let go: no regrasp
    # (nor release) can start from this grasp or reach it. Last but the ranking: the dearest
    # test (a lift planned per finger, ~10 ms each), and asked before the check it cost more
    # than it saved (the candidates the check and the weight drop had it computed too)
    stuck = _stuck_finger(hand, g.obj, chosen, g.q)
    if stuck is not None:
        return Rejection("a finger cannot back off its contact", [stuck]), None, probe
    # the ranking: does execution mode accept it as an end grasp (its own test, in the
    # directions it plans for: the one gravity given, else execution mode's set; its load
    # table, which only explains a refusal, is not computed)
    reason = execution_refusal(g, dirs[0] if dirs is not None and len(dirs) == 1 else None)
    cand = SynthGrasp(data=data, grasp=None if _IN_WORKER else g, grip_force_n=grip, attempt=attempt,
                      metric=g.metric, execution=reason, base_dir=ctx.base_dir)
    return "", (features, cand), probe


def _stuck_finger(hand, obj, chosen, q) -> str | None:
    """The first chosen finger that cannot back off its contact at ``q`` (`cannot_back_off`), or None."""
    q = np.asarray(q)
    return next((f.name for f in chosen if cannot_back_off(hand, obj, q[list(f.q_index)], f.name)), None)


def _hold_grip(ctx, hand, g, patches, fr: Friction, dirs) -> float | None:
    """The grip force (N) of a realized grasp, the largest `min_grip_force` over the
    gravity directions ``dirs``, when it holds ``ctx.hold_factor`` times the weight in every
    one within the joints' torque limits (`planner.grip.hold_capacity`, the force cap), else
    None. A direction the grip force proves held (`planner.grip.holds_by_bound`: a witness,
    the planner's own shortcut) skips the capacity program: the same answer as
    `planner.grip.grasp_hold` with less work."""
    R = np.asarray(g.obj.T_palm_obj)[:3, :3]
    grip_fr = Friction(fr.mu * ctx.friction_margin, fr.gamma * ctx.friction_margin, fr.edges)
    statics = grasp_statics(hand, g.q, patches, g.obj.T_palm_obj)
    grips, program = [], None
    for gv in dirs:
        g_obj = R.T @ np.asarray(gv, dtype=float)
        load = np.r_[float(g.obj.mass_kg) * g_obj, np.zeros(3)]
        f = min_grip_force(patches, grip_fr, load)
        grips.append(f)
        if holds_by_bound(statics, f, fr, g_obj, factor=ctx.hold_factor, margin=ctx.friction_margin,
                          force_cap_n=ctx.max_finger_force_n):
            continue
        program = program or grip_program(patches, statics, fr, margin=ctx.friction_margin)
        cap = hold_capacity(patches, statics, fr, load, g_obj, force_cap_n=ctx.max_finger_force_n, program=program)
        if not cap.factor >= ctx.hold_factor:
            return None
    return max(grips)


def _check_reason(g, hand=None) -> str:
    """The rejection reason of a candidate `realize` did not pass: "check: " and the first
    problem's first word (the palm's own: "check: the palm does not touch the object"), a
    `Rejection` naming the fingers of the problem (``fingers.X: ...``, or the links of a
    ``collision a - b``) when ``hand`` is given."""
    if not g.problems:
        return "check: not force closure"
    first = g.problems[0]
    if first.startswith("palm:"):
        return "check: the palm does not touch the object" if "does not touch" in first else "check: palm"
    text = "check: " + first.split(":")[0].split(" ")[0]
    if hand is None:
        return text
    head = first.split(":")[0]
    if head.startswith("fingers."):
        return Rejection(text, [head.removeprefix("fingers.").split(".")[0]])
    if head.startswith("collision "):
        return Rejection(text, _fingers_of(hand, head.removeprefix("collision ").split(" - ")))
    return text


def _fingers_of(hand, links) -> list[str]:
    """The fingers (hand.yaml order, each once) that carry any of these links (a palm link: none)."""
    return [name for name, f in hand.fingers.items() if any(l in f.links for l in links)]


def output_names(out_dir, hand_name: str, shape: str, n: int) -> list[Path]:
    """The files `write_grasps` writes: ``DIR/<hand>_<shape>_<rank>.yaml``, rank 01..n."""
    width = max(2, len(str(n)))
    return [Path(out_dir) / f"{hand_name}_{shape}_{i:0{width}d}.yaml" for i in range(1, n + 1)]


def execution_words(gravity_label: str | None = None) -> str:
    """The command a synthesized grasp's verdict is about: ``plan --execution`` (its six
    directions), or with one ``--gravity`` ``plan --execution --gravity LABEL``, the one
    direction the verdict was computed for (a grasp held palm down may drop palm up)."""
    return "plan --execution" if gravity_label is None else f"plan --execution --gravity {gravity_label}"


def _role(g: SynthGrasp) -> str:
    """" as an initial grasp" for a grasp the simulator did not hold from the start (a plan may
    still end in it), else ""."""
    return " as an initial grasp" if g.not_held else ""


def verdict_words(g: SynthGrasp, gravity_label: str | None = None) -> str:
    """A synthesized grasp's execution verdict in its file's description: ``plan --execution
    accepts it`` once a physics engine held it too, ``... refuses it: why``, or, not replayed
    (``--no-verify``), what the static test says."""
    words = execution_words(gravity_label)
    if g.not_held:
        return f"{words} refuses it as an initial grasp: {g.execution}; a plan arriving at it may still end in it"
    if not g.execution_ready:
        return f"{words} refuses it: {g.execution}"
    if g.held_in is None:
        return f"the static test of {words} accepts it (not held in a physics engine: check --execution does that)"
    return f"{words} accepts it (held in {g.held_in})"


def write_grasps(result: SynthResult, out_dir, hand_name: str, *, seed: int, fingers, inputs=(),
                 gravity_label: str | None = None) -> list[Path]:
    """Write the ranked grasps; refuse (PlannerError) to overwrite any existing file or an input.
    No grasp: nothing written, no folder made. ``gravity_label``: the one ``--gravity`` the
    verdicts were computed for (`gravity_label_of`), named in each file's description."""
    grasps = result.grasps
    if not grasps:
        return []
    shape = grasps[0].data["object"]["shape"] if grasps else "object"
    paths = output_names(out_dir, hand_name, shape, len(grasps))
    _refuse_overwrite(paths, inputs)
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    written = []
    try:
        for rank, (path, g) in enumerate(zip(paths, grasps), start=1):
            data = dict(g.data)
            data["name"] = path.stem
            grip = f", grip force {g.grip_force_n:.3f} N" if g.grip_force_n is not None else ""
            data["description"] = (f"synthesized by regrasp synth (seed {seed}, fingers {','.join(fingers)}, "
                                   f"attempt {g.attempt}): rank {rank}, closure metric {g.metric:.4g}{grip}, "
                                   + verdict_words(g, gravity_label))
            obj = dict(data["object"])
            if obj.get("mesh"):
                obj["mesh"] = os.path.relpath(obj["mesh"], Path(out_dir).resolve())
            data["object"] = obj
            if os.path.isabs(str(data.get("hand", ""))):  # a hand.yaml path moves with the files
                data["hand"] = os.path.relpath(data["hand"], Path(out_dir).resolve())
            # never over a file: one that appeared since the names were checked stops the writing
            write_atomic(path, yaml.safe_dump(data, sort_keys=False, default_flow_style=None), exclusive=True)
            written.append(path)
    except OutputError as err:
        for p in written:
            p.unlink(missing_ok=True)
        raise OutputError(f"synth: {err}; nothing was kept, choose another -o DIR") from None
    return written


def _refuse_overwrite(paths, inputs) -> None:
    ins = {Path(p).resolve() for p in inputs}
    for p in paths:
        if p.resolve() in ins:
            raise PlannerError(f"synth: {p} is an input file; choose another -o DIR")
        if p.exists():
            raise PlannerError(f"synth: {p} exists; refusing to overwrite it (choose an empty -o DIR or remove it)")


#: Most grasps `run_synth` writes (``-n``) and candidates it samples (``--max-attempts``):
#: bounds on the work and memory a command line can ask for.
MAX_GRASPS = 10_000
MAX_ATTEMPTS = 10_000_000
#: Most worker processes `run_synth` starts (``--workers``).
MAX_WORKERS = 256


def _check_out_dir(out_dir) -> None:
    """``-o DIR`` before any work: a folder, or a new one in an existing folder; never a
    regular file or under one; not an empty name (the current folder: files landed there)."""
    if not os.fspath(out_dir):
        raise PlannerError("synth: -o: an empty name; name a folder for the grasp files")
    d = Path(out_dir)
    try:
        resolve_path(d)
    except OSError as err:  # a symlink loop
        raise PlannerError(f"synth: -o {d}: cannot be resolved: {err}") from None
    if d.exists() and not d.is_dir():
        raise PlannerError(f"synth: -o {d}: exists and is not a folder")
    parent = d.parent if not d.exists() else d
    for anc in [parent, *parent.parents]:
        if anc.exists():
            if not anc.is_dir():
                raise PlannerError(f"synth: -o {d}: {anc} is a file, not a folder")
            break
    if not d.exists() and not d.parent.is_dir():
        raise PlannerError(f"synth: -o {d}: the folder {d.parent} does not exist (a typo? create it first)")
    if not os.access(d if d.exists() else d.parent, os.W_OK):
        raise PlannerError(f"synth: -o {d}: {'the folder' if d.exists() else d.parent} is not writable")


def default_fingers(hand, palm: bool = False) -> list[str]:
    """The default finger set of `run_synth`: a tripod, the thumb and the hand's next two
    fingers in its hand.yaml order (the first three fingers when it has no thumb); with
    ``palm`` every finger (a power grasp)."""
    names = list(hand.fingers)
    if palm:
        return names
    if "thumb" in names:
        return ["thumb"] + [f for f in names if f != "thumb"][:2]
    return names[:3]


def run_synth(hand: str, object_path, fingers: str, n: int, out_dir, *, gravity=None, seed: int = 0,
              max_finger_force_n: float | None = None, mu=None, gamma=None, max_attempts=None, quiet=False,
              palm: bool = False, workers: int = 1, gravity_name: str | None = None, verify: bool = True,
              engine: str | None = None) -> int:
    """``regrasp synth``: synthesize, write, print a summary. ``gravity_name``: the name the
    one ``gravity`` was given by (``--gravity palm_down``), said in the verdicts. Exit 0 when n grasps were written,
    1 when fewer (those found are written), 2 (PlannerError) on bad input. ``palm``: whole-hand
    grasps (``--palm``, `synthesize`), every finger by default."""
    if not 1 <= n <= MAX_GRASPS:
        raise PlannerError(f"synth: -n must be in 1..{MAX_GRASPS}, got {n}")
    if max_attempts is not None and not 1 <= max_attempts <= MAX_ATTEMPTS:
        raise PlannerError(f"synth: --max-attempts must be in 1..{MAX_ATTEMPTS}, got {max_attempts}")
    if not 1 <= workers <= MAX_WORKERS:
        raise PlannerError(f"synth: --workers must be in 1..{MAX_WORKERS}, got {workers}")
    # as a grasp file's friction (`planner.grasp.parse_friction`): every written file passes check
    if mu is not None and not (math.isfinite(mu) and 0 < mu <= MU_MAX):
        raise PlannerError(f"synth: --mu must be in (0, {MU_MAX:g}] (friction coefficient), got {mu:g}")
    if gamma is not None and not (math.isfinite(gamma) and 0 <= gamma <= GAMMA_MAX_M):
        raise PlannerError(f"synth: --gamma must be in [0, {GAMMA_MAX_M:g}] m (torsional friction), got {gamma:g}")
    _check_out_dir(out_dir)
    try:
        hand_ref = resolve_hand_ref(hand, Path.cwd())
    except (RuntimeError, OSError) as err:  # a symlink loop, an unreadable folder
        raise PlannerError(f"synth: hand {hand}: cannot be resolved: {err}") from None
    h = load_hand(hand_ref)
    if palm:
        require_palm(h)
    if fingers is None:
        fingers = ",".join(default_fingers(h, palm))
        if not quiet:
            what = "every finger: power grasps with --palm" if palm else "the default tripod"
            print(f"synth: --fingers {fingers} ({what})", file=sys.stderr, flush=True)
    names = [f.strip() for f in fingers.split(",") if f.strip()]
    twice = sorted({f for f in names if names.count(f) > 1})
    if twice:
        raise PlannerError(f"synth: --fingers names {', '.join(twice)} twice; give each finger once "
                           f"(fingers of {h.name}: {', '.join(h.fingers)})")
    for f in names:
        h.finger(f)
    obj, file_friction, fixed = load_object_file(object_path)
    friction = dict(DEFAULT_FRICTION)
    if isinstance(file_friction, dict):
        friction.update({k: file_friction[k] for k in ("mu", "gamma", "edges") if k in file_friction})
    if mu is not None:
        friction["mu"] = mu
    if gamma is not None:
        friction["gamma"] = gamma
    # refuse before any work when the first names are taken
    _refuse_overwrite(output_names(out_dir, h.name, obj.shape, n), [object_path])
    progress = None if quiet else _Progress()
    if palm and fixed:  # before any work: the fixed pose must touch the palm
        check_palm_pose(h, obj)
    result = synthesize(hand_ref, obj, names, n, fixed=fixed, friction=friction, seed=seed, gravity=gravity,
                        max_finger_force_n=max_finger_force_n, max_attempts=max_attempts, base_dir=out_dir,
                        progress=progress, palm=palm, workers=workers, verify=verify, engine=engine,
                        gravity_name=gravity_name)
    label = gravity_label_of(gravity, gravity_name)
    paths = write_grasps(result, out_dir, h.name, seed=seed, fingers=names, inputs=[object_path], gravity_label=label)
    for path, g in zip(paths, result.grasps):
        grip = f"  grip {g.grip_force_n:.3f} N" if g.grip_force_n is not None else ""
        ex = (("execution-ready" + (f", held in {g.held_in}" if g.held_in else " by the static test"))
              if g.execution_ready else f"not for --execution{_role(g)}: {g.execution}") \
            + ("" if label is None else f" (--gravity {label} only)")
        print(f"{path}  metric {g.metric:.4g}{grip}  {ex}")
    rate = len(paths) / result.seconds if result.seconds > 0 else math.inf
    print(f"synth: {len(paths)}/{n} grasps of {obj.shape} with {h.name} ({','.join(names)}) in "
          f"{result.seconds:.1f} s ({rate:.2f} grasps/s), {result.attempts} attempts, {result.candidates_passed} "
          f"passed the check, {result.duplicates} near-duplicates removed, pose "
          f"{'fixed by the object file' if fixed else 'sampled'}{' against the palm (palm: hold)' if palm else ''}, "
          f"seed {seed}" + (_held_words(result) if result.verified else ""))
    if len(paths) < n:
        print(rejection_table(result))
        if any(result.by_finger.values()):
            print(finger_table(result))
    return 0 if len(paths) >= n else 1


def _held_words(result: SynthResult) -> str:
    """How many of the grasps the static test accepted a physics engine held (`hold_in_engine`)."""
    held = sum(1 for g in result.grasps if g.held_in)
    dropped = sum(1 for g in result.grasps if g.not_held)
    return f"; held in a physics engine: {held} of the {held + dropped} the static test accepts"


def finger_table(result: SynthResult) -> str:
    """Which finger fails (what `run_synth` prints with `rejection_table` when it found fewer
    grasps than asked): per chosen finger, how many candidates were dropped for a reason about
    it (its sweep or closing missed the object, it started inside it, it collides, it cannot
    back off), by reason, most frequent first; a reason about the whole grasp (force closure,
    the weight) names no finger and is not counted here."""
    rows = [(f, sum(c.values()), sorted(c.items(), key=lambda kv: (-kv[1], kv[0])))
            for f, c in (result.by_finger or {}).items()]
    width = max((len(f) for f, _, _ in rows), default=6)
    lines = [f"  {'finger':<{width}}  dropped  (candidates, by reason)"]
    for f, total, reasons in rows:
        lines.append(f"  {f:<{width}}  {total:>7}  " + (", ".join(f"{k} {r}" for r, k in reasons) if reasons else "-"))
    # one finger whose closing motion misses in most of the drops: its closing joints or their
    # directions are the first suspects (a thumb closing toward its lower limits, set up upward)
    total = sum(t for _, t, _ in rows)
    worst = max(rows, key=lambda r: r[1], default=None)
    if worst and 2 * worst[1] > total and any("miss" in r for r, _ in worst[2]):
        lines.append(f"  try: fingers.{worst[0]}: its closing motion misses the object; check its close_joints and "
                     "close_toward in the hand.yaml (the limit each joint closes toward; hand init writes them)")
    return "\n".join(lines)


class _Progress:
    """`synthesize`'s progress as INFO records of the ``planner.synth`` logger, at most one per
    `PERIOD_S`: the command line shows the ``planner`` logger's records as lines on the
    terminal only when stderr is one and without -q (`planner.cli._progress`, as ``plan``'s
    rounds), and the records cost nothing otherwise."""

    PERIOD_S = 1.0

    def __init__(self, log=None):
        import logging

        self.log, self.last = log or logging.getLogger("planner.synth"), -math.inf

    def __call__(self, line: str) -> None:
        now = time.monotonic()
        if now - self.last >= self.PERIOD_S:
            self.last = now
            self.log.info("%s", line.removeprefix("synth: "))


def rejection_table(result: SynthResult) -> str:
    """Why candidates were dropped, most frequent first (what `run_synth` prints when it found
    fewer grasps than asked), with what to try. With ``--palm`` the palm's own reasons are
    among them (`planner.synth_sample.sample_candidate`: "object not against the palm", "an
    unused finger is inside the object on the palm", "sweeps miss the object on the palm";
    "check: the palm does not touch the object")."""
    rows = sorted((result.rejected or {}).items(), key=lambda kv: (-kv[1], kv[0]))
    if not rows:
        return "no candidate was rejected: raise --max-attempts"
    width = max(len(r) for r, _ in rows)
    lines = [f"  {'rejected because':<{width}}  candidates"] + [f"  {r:<{width}}  {k:>10}" for r, k in rows]
    hints = []
    top = rows[0][0]
    if "inside" in top and result.palm:
        hints.append("the object on the palm is where a finger lies: fewer fingers (--fingers) or another size")
    elif any(w in top for w in ("on the palm", "against the palm", "palm does not touch")) or (
            result.palm and "miss" in top):
        hints.append("the fingers meet away from the palm, or cannot reach back to an object on it: a larger "
                     "object, fewer fingers (e.g. --fingers thumb,index,middle: a palm-supported tripod), or "
                     "drop --palm")
    elif any(w in top for w in ("reach", "IK", "touch", "miss")):
        hints.append("the fingers do not reach the object there: move it (position) or let synth sample the pose "
                     "(an object file without position)" if result.fixed else
                     "the fingers do not reach the object at the poses sampled: other fingers (--fingers), another "
                     "size, or more attempts (--max-attempts)")
    if "force closure" in top:
        hints.append("add a finger that opposes the others (e.g. the thumb) or raise --max-attempts")
    if "limits" in top:
        hints.append("a lighter object (mass_kg) or a hand.yaml effort: with the motors' real stall torque")
    if "overlap" in top:
        hints.append("fewer fingers, or a larger object")
    return "\n".join(lines + ([f"  try: {'; '.join(hints)}"] if hints else []))
