"""Replays under several gravity directions in parallel processes, and plan verification.

`replay_gravity_set` replays a plan under a gravity set of `planner.gravity` (its
`GravitySetReport` says which directions failed). `replay_directions` runs one
`planner.sim.replay.replay_plan` per direction, each in its own pybullet client; with
``workers > 1`` in worker processes (forked on Linux, so the hand is not loaded again). Every replay is deterministic and independent of the others, so the
reports are those of a serial run, in the directions' order.

`verify_plan` is what ``regrasp plan --execution`` runs before it returns a plan: the plan as
it will be written (numbers rounded as in the file) is replayed in every direction it was
planned for; the first failure says which plan step failed (`ReplayReport.failed_step`), so
the planner can remove that transition and search again.

Engines. Every function here takes ``engine``: "pybullet", "mujoco" (`planner.sim.engine`),
None (`planner.sim.engine.default_engine`) or, where a plan is verified or replayed as a
whole, "both": the plan must hold in each (`engines_of`; pybullet first, and when it fails
MuJoCo is not asked). Every verdict names its engine.
"""

from __future__ import annotations

import logging
import math
import multiprocessing
import os
import signal
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, replace
from pathlib import Path

from planner.errors import InputError
from planner.gravity import gravity_directions
from planner.helper import cores, die_with_parent
from planner.options import PLAN_OPTION_LIMITS, in_range, option_range
from planner.sim.engine import ENGINES, default_engine, require_engine
from planner.plan import plan_from_data
from planner.plan_data import Plan
from planner.sim import snapshots
from planner.sim.inputs import plan_hand, typed_plan
from planner.sim.replay import StopLine, replay_plan
from planner.sim.report import GravitySetReport, ReplayReport

#: The job the forked workers run (set before the pool forks; read only in the workers).
_JOB: dict = {}
#: The ``engine`` value that asks for every engine.
BOTH = "both"


def engines_of(engine: str | None) -> tuple[str, ...]:
    """The engines an ``engine`` option names, each installed: None the default engine,
    "both" every engine of `planner.sim.engine.ENGINES` (pybullet first).

    Raises:
        InputError: an unknown name (the valid ones listed).
        SimulationError: an engine it names is not installed.
    """
    if engine is None:
        return (default_engine(),)
    if engine == BOTH:
        return tuple(require_engine(e) for e in ENGINES)
    if engine not in ENGINES:
        raise InputError(f"unknown physics engine {engine!r}; choose from: {', '.join(ENGINES)}, {BOTH}")
    return (require_engine(engine),)


def one_engine(engine: str | None) -> str:
    """The one engine an ``engine`` option names (not "both"), installed."""
    if engine == BOTH:
        raise InputError(f"one replay runs in one engine: {', '.join(ENGINES)} (not {BOTH})")
    return engines_of(engine)[0]


def default_workers() -> int:
    """Worker processes for the directions: the cores this process may use."""
    return cores()


def _one(i: int) -> ReplayReport | None:
    job = _JOB
    if job.get("interrupted") is not None:  # a forked worker: Ctrl-C of the parent stops its replay
        if job["interrupted"].is_set():  # the command was interrupted: not started
            return None
        signal.signal(signal.SIGINT, signal.default_int_handler)  # (the parent's may be SIG_IGN)
    name, g = job["directions"][i]
    kw = dict(job["kwargs"])
    if isinstance(kw.get("stop_at_failure"), StopLine):  # this replay's place in the directions' order
        kw["stop_at_failure"] = kw["stop_at_failure"].at(i)
        if kw["stop_at_failure"].stopped():  # a direction before it failed: not started
            return None
    for key in ("gif", "mp4"):
        if kw.get(key) is not None:
            kw[key] = kw[key][i]
    return replay_plan(job["plan"], hand=job["hand"], gravity=g, **kw)


def replay_directions(plan: Plan, hand, directions: Sequence[tuple[str, Sequence[float]]], *,
                      workers: int | None = None, meanwhile: Callable[[], object] | None = None,
                      **kwargs) -> list[ReplayReport]:
    """One replay per named gravity direction (palm frame, m/s^2), in parallel processes.

    Args:
        plan: a `planner.plan_data.Plan` (read and checked).
        hand: its `planner.hand.Hand`.
        directions: (name, gravity (3,)) pairs.
        workers: processes (default `default_workers`; 1: in this process, one after the other).
        meanwhile: work that needs no replay, called once in this process on a core the
            worker processes leave free: the first ``workers - 1`` directions replay while it
            runs, the others start once it is done (a single direction has a worker process
            of its own); with one worker, before the replays.
        **kwargs: passed to `replay_plan`; ``gif``/``mp4`` are one path (or None) per direction.
            A `planner.sim.replay.StopLine` as ``stop_at_failure`` orders the directions as
            given: once one fails, the later ones stop, or are not started.

    Returns:
        the `ReplayReport` of each direction, in order (identical to a serial run up to the
        first failing direction with a stop line; after it, a stopped, finished or None (not
        started) report, as the timing made it).
    """
    directions = [(str(n), tuple(float(v) for v in g)) for n, g in directions]
    kwargs["engine"] = one_engine(kwargs.get("engine"))
    n = len(directions)
    low, high, open_low = PLAN_OPTION_LIMITS["workers"]
    if workers is not None and not in_range(workers, low, high, open_low):  # ('two' was a ValueError, 0 and -1 ran serially)
        raise InputError(f"workers must be an integer in {option_range(low, high, open_low)} (processes), got {workers!r}")
    workers = default_workers() if workers is None else int(workers)
    _JOB.clear()
    _JOB.update(plan=plan, hand=hand, directions=directions, kwargs=kwargs)
    forks = "fork" in multiprocessing.get_all_start_methods()
    # ``meanwhile`` beside the replays on a core they leave free (beside a worker on every
    # core it would only slow them down): the directions past the first workers - 1 wait
    beside = meanwhile is not None and forks and workers >= 2 and n >= 1
    first = min(n, workers - 1) if beside else n
    if meanwhile is not None and not beside:
        meanwhile()
    line = kwargs.get("stop_at_failure")
    line = line if isinstance(line, StopLine) else None

    def decided(report) -> bool:  # a failure that stops the directions after it
        return line is not None and not report.passed and report.stopped_after is None

    try:
        if workers <= 1 or (n <= 1 and not beside) or not forks:
            out = []
            for i in range(n):
                out.append(_one(i))
                if out[-1] is None:
                    continue
                _log_done(directions[i][0], out[-1], i + 1, n)
                if decided(out[-1]):
                    return out + [None] * (n - i - 1)
            return out
        _JOB["interrupted"] = multiprocessing.get_context("fork").Event()
        with ProcessPoolExecutor(max_workers=min(workers, n), mp_context=multiprocessing.get_context("fork"),
                                 initializer=die_with_parent, initargs=(os.getpid(),)) as pool:
            try:
                return _in_pool(pool, n, first, beside, meanwhile, directions, decided)
            except BaseException:  # Ctrl-C, SIGTERM: no replay starts after it and the running ones stop
                _interrupt(pool)
                raise
    finally:
        _JOB.clear()


def _interrupt(pool: ProcessPoolExecutor) -> None:
    """Stop the replays of an interrupted command: the ones not started are not (`_one`), the
    running ones get a KeyboardInterrupt in their worker (their films' temporary files are
    removed as they unwind). Without it, leaving the pool waited for every direction queued,
    minutes after Ctrl-C, and wrote their films."""
    _JOB["interrupted"].set()
    for proc in list((getattr(pool, "_processes", None) or {}).values()):  # (no public handle on them)
        try:
            os.kill(proc.pid, signal.SIGINT)
        except (ProcessLookupError, AttributeError, TypeError):
            pass


def _in_pool(pool, n, first, beside, meanwhile, directions, decided) -> list:
    """`replay_directions`'s replays in the worker processes of ``pool``."""
    futures = {pool.submit(_one, i): i for i in range(first)}
    if beside:
        meanwhile()
        futures.update({pool.submit(_one, i): i for i in range(first, n)})
    done: dict[int, object] = {}
    for fut in as_completed(futures):
        i = futures[fut]
        if fut.cancelled() or fut.result() is None:
            continue
        done[i] = fut.result()
        _log_done(directions[i][0], done[i], len(done), n)
        if decided(done[i]):  # the directions after it not started yet are not
            for f, j in futures.items():
                if j > i:
                    f.cancel()
    return [done.get(i) for i in range(n)]


def _log_done(name: str, report, k: int, n: int) -> None:
    """One progress record per replayed direction (`planner.regrasp.log`; the CLI shows it)."""
    verdict = ("PASS" if report.passed else "FAIL" if getattr(report, "stopped_after", None) is None
               else f"stopped after step {report.stopped_after} (a direction before it failed)")
    logging.getLogger("planner").info("replay %d/%d %s in %s: %s", k, n, name, report.engine, verdict)


def film_paths(path, names: Sequence[str], film: Sequence[str] | None = None) -> list[Path | None]:
    """The film of each gravity direction of a set: ``FILE_<direction>.ext`` beside ``path``
    (None for a direction not in ``film``; every direction when ``film`` is None)."""
    path = Path(path)
    return [None if film is not None and name not in film else path.with_name(f"{path.stem}_{name}{path.suffix}")
            for name in names]


def replay_gravity_set(plan: Mapping | str | os.PathLike, n: int = 6, *, hand=None, g_mps2: float = 9.81,
                       film: Sequence[str] | None = None, strict: bool = False, workers: int | None = None,
                       engine: str | None = None, **kwargs) -> GravitySetReport:
    """Replay a plan under several gravity directions of the palm frame (`planner.gravity`).

    Args:
        plan: plan data or file, as for `replay_plan`.
        n: set size (`planner.gravity.GRAVITY_SET_SIZES`): 1 palm down, 2 palm down and up,
            6 with the four sideways directions, 7 with gravity off too.
        hand: the plan's `planner.hand.Hand` (loaded from the plan when None).
        g_mps2: gravity magnitude.
        film: the direction names filmed when ``gif`` or ``mp4`` is given (a list, or one
            comma-separated string as ``--film``; default: all).
        strict: refuse a plan file whose recorded inputs changed or are gone (`replay_plan`).
        workers: processes the directions are replayed in (`planner.sim.verify.replay_directions`;
            default: the cores available; the reports are those of a serial run).
        engine: the physics engine (`one_engine`: "pybullet", "mujoco"; None: the default).
        **kwargs: passed to `replay_plan` (not ``gravity``; a ``gif`` path gets the direction
            name inserted before its suffix).

    Returns:
        GravitySetReport; ``passed`` only when every direction passed.
    """
    if "gravity" in kwargs:
        raise InputError("replay_gravity_set takes no gravity: it replays the set's directions")
    engine = one_engine(engine)
    rd = typed_plan(plan, strict)  # read and verified once for every direction
    if hand is None:
        hand = plan_hand(rd)
    directions = gravity_directions(hand.palm_normal, n, g_mps2)
    names = [name for name, _ in directions]
    if isinstance(film, str):  # "palm_down,palm_up", as --film (its letters were taken for names)
        film = [d.strip() for d in film.split(",") if d.strip()]
    if film is not None and not film:  # (--film '' filmed every direction, --film , none)
        raise InputError(f"--film names no direction; name those to film (comma-separated): the gravity set of {n} has "
                         f"{', '.join(names)}")
    unknown = sorted(set(film or ()) - set(names))
    if unknown:
        raise InputError(f"cannot film {', '.join(unknown)}: the gravity set of {n} has {', '.join(names)}")
    kw = dict(kwargs)
    for key in ("gif", "mp4"):
        if kw.get(key) is not None:
            kw[key] = film_paths(kw[key], names, film)
    reports = replay_directions(rd, hand, directions, workers=workers, engine=engine, **kw)
    out = [(name, g, r) for (name, g), r in zip(directions, reports)]
    failed = [(name, r) for name, _, r in out if not r.passed]
    if not failed:
        worst_mm = max(r.max_drift_mm for _, _, r in out)
        worst_deg = max(r.max_drift_deg for _, _, r in out)
        verdict = (f"PASS in all {len(out)} gravity directions in {engine}: max drift {worst_mm:.1f} mm / "
                   f"{worst_deg:.1f} deg")
    else:
        verdict = (f"FAIL in {len(failed)}/{len(out)} gravity directions in {engine}: "
                   + "; ".join(f"{name}: {r.verdict.removeprefix('FAIL: ')}" for name, r in failed))
    return GravitySetReport(not failed, verdict, tuple(out))


@dataclass(frozen=True)
class EnginesReport:
    """A replay (one direction or a gravity set) in several engines (``engine="both"``).

    Attributes:
        passed: it passed in every engine.
        verdict: one line naming the engines it failed in, with the first one's verdict.
        engines: (engine, its `ReplayReport` or `GravitySetReport`) per engine, pybullet first.
    """

    passed: bool
    verdict: str
    engines: tuple[tuple[str, ReplayReport | GravitySetReport], ...]

    def to_dict(self) -> dict:
        """Plain data for JSON."""
        return {"passed": self.passed, "verdict": self.verdict,
                "engines": [{"engine": e, "report": r.to_dict()} for e, r in self.engines]}


def engine_path(path, engine: str) -> Path:
    """A film of one engine among several: ``FILE_<engine>.ext`` beside ``path``."""
    path = Path(path)
    return path.with_name(f"{path.stem}_{engine}{path.suffix}")


def in_engines(results: Sequence[tuple[str, ReplayReport | GravitySetReport]]) -> EnginesReport:
    """The `EnginesReport` of one replay's results in several engines."""
    failed = [(e, r) for e, r in results if not r.passed]
    names = " and ".join(e for e, _ in results)
    if not failed:
        verdict = f"PASS in {names}"
    else:
        e, r = failed[0]
        held = [x for x, rr in results if rr.passed]
        verdict = (f"FAIL in {', '.join(x for x, _ in failed)}" + (f" (holds in {', '.join(held)})" if held else "")
                   + f": {e}: {r.verdict}")
    return EnginesReport(not failed, verdict, tuple(results))


@dataclass(frozen=True)
class Verification:
    """The outcome of `verify_plan`.

    Attributes:
        passed: every direction passed (in every engine).
        directions: (name, passed, verdict line, failed plan step or None, failed at the
            state it reaches (`ReplayReport.failed_at_state`), max drift mm, max drift deg)
            per direction; with several engines the worst of them (failed in any, the
            earliest failing step, the largest drift), the verdict naming the engine. A
            failed verification has the rows of the one direction that failed and of those
            replayed before it in the replays' order (`planner.sim.replay.StopLine`).
        wall_time_s: wall-clock time of the replays.
        engine: the engine option verified with ("pybullet", "mujoco" or "both").
        by_engine: (engine, its rows as ``directions``) per engine replayed.
    """

    passed: bool
    directions: tuple[tuple[str, bool, str, int | None, bool, float, float], ...]
    wall_time_s: float
    engine: str = "pybullet"
    by_engine: tuple[tuple[str, tuple], ...] = ()

    @property
    def engine_names(self) -> str:
        """The engines replayed in, in words ("pybullet", "pybullet and mujoco" for ``both``)."""
        return " and ".join(e for e, _ in self.by_engine) or self.engine

    def first_failure(self) -> tuple[str, int, str, bool] | None:
        """(direction, plan step (-1: state 0), verdict, failed at the state the step reaches)
        of the direction that failed (the first in the order its replays decided in: a failed
        verification's rows hold that one only; of several failing rows, the first), or None."""
        failed = [d for d in self.directions if not d[1]]
        if not failed:
            return None
        d = failed[0]
        return d[0], (d[3] if d[3] is not None else -1), d[2], bool(d[4])

    def record(self) -> dict:
        """What the plan records (deterministic: no times)."""
        def num(x: float):
            return round(x, 3) if math.isfinite(x) else None

        def rows(directions) -> dict:
            return {name: {"passed": ok, "max_drift_mm": num(mm), "max_drift_deg": num(deg)}
                    for name, ok, _, _, _, mm, deg in directions}

        out = {"passed": self.passed, "engine": self.engine, "directions": rows(self.directions)}
        if len(self.by_engine) > 1:  # "both": each engine's own verdicts and drifts
            out["engines"] = {e: rows(d) for e, d in self.by_engine}
        return out


def as_written(plan: Plan) -> Plan:
    """The plan as a file holds it (numbers rounded as `planner.plan` writes them), which is
    what a later `regrasp replay` of the written file simulates."""
    return plan_from_data(plan.to_dict())


def verify_plan(plan: Plan, hand, directions: Sequence[tuple[str, Sequence[float]]], *,
                workers: int | None = None, engine: str | None = None,
                meanwhile: Callable[[], object] | None = None) -> Verification:
    """Replay a plan as it will be written under each direction (`replay_directions`), in
    the engine(s) of ``engine`` (`engines_of`; with "both" the next engine only when the
    plan held in the previous one: a refusal needs one failing engine). ``meanwhile``: as
    `replay_directions`', during the first engine's replays. Inside a
    `planner.sim.snapshots.scope` the replays resume from the snapshots earlier ones left of
    the same beginning (the same verdicts)."""
    t0 = time.perf_counter()
    engines = engines_of(engine)
    written = as_written(plan)
    by_engine = []
    for e in engines:
        # the verdict is all a verification needs: a replay stops at its first failure, and
        # the directions after the first failing one in ``directions`` order stop too (their
        # rows are left out, as the rows after it of those that ran to their end: what the
        # verification says depends on the order only, not on which replay ran first)
        reports = replay_directions(written, hand, directions, workers=workers, engine=e, stop_at_failure=StopLine(),
                                    meanwhile=meanwhile, snapshots=snapshots.current())
        meanwhile = None
        last = next((i for i, r in enumerate(reports) if r is not None and not r.passed and r.stopped_after is None),
                    len(reports) - 1)
        rows = tuple((name, r.passed, f"{e}: {r.verdict}", r.failed_step, r.failed_at_state, float(r.max_drift_mm),
                      float(r.max_drift_deg))
                     for (name, _), r in zip(directions[:last + 1], reports))
        by_engine.append((e, rows))
        if len(rows) < len(directions) or not all(r[1] for r in rows):
            break
    # each direction the last engine has a row for (every engine before it replayed every direction)
    by_name = [{r[0]: r for r in rows} for _, rows in by_engine]
    merged = tuple(_worst([rows[name] for rows in by_name]) for name, *_ in by_engine[-1][1])
    return Verification(all(r[1] for r in merged), merged, time.perf_counter() - t0,
                        engine if engine == BOTH else engines[0], tuple(by_engine))


def _worst(rows):
    """One direction's row over several engines: the first failing engine's verdict and step
    (the earliest step), the largest drifts."""
    failed = [r for r in rows if not r[1]]
    if not failed:
        first = rows[0]
        return (first[0], True, first[2], None, False, max(r[5] for r in rows), max(r[6] for r in rows))
    f = min(failed, key=lambda r: -1 if r[3] is None else r[3])
    return (f[0], False, f[2], f[3], f[4], max(r[5] for r in rows), max(r[6] for r in rows))


def verify_suspects_first(plan: Plan, hand, directions: Sequence[tuple[str, Sequence[float]]], suspects,
                          *, workers: int | None = None, engine: str | None = None,
                          meanwhile: Callable[[], object] | None = None) -> Verification:
    """`verify_plan` in the order: the ``suspects`` first (direction names that rejected an
    earlier sequence, in the order given: the one that rejected the latest first, as the next
    sequence mostly repeats the last), then the others as in ``directions``. The first
    direction in that order to fail decides and the replays after it stop (deterministic: the
    order depends only on the earlier verdicts); the rows come back in ``directions`` order.
    ``meanwhile``: as `replay_directions`'."""
    gravity = dict(directions)
    if isinstance(suspects, (set, frozenset)):  # (no order of its own: a set's depends on the hash seed)
        suspects = sorted(suspects)
    suspects = list(dict.fromkeys(n for n in suspects if n in gravity))
    first = set(suspects)
    order = [(n, gravity[n]) for n in suspects] + [d for d in directions if d[0] not in first]
    kw = {} if engine is None else {"engine": engine}  # (the default engine: verify_plan's call as before)
    if meanwhile is not None:
        kw["meanwhile"] = meanwhile
    v = verify_plan(plan, hand, order, workers=workers, **kw)
    if order == list(directions):
        return v

    def ordered(rows):
        by_name = {r[0]: r for r in rows}
        return tuple(by_name[name] for name, _ in directions if name in by_name)

    return replace(v, directions=ordered(v.directions), by_engine=tuple((e, ordered(rows)) for e, rows in v.by_engine))
