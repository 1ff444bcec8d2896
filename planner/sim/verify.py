"""Replays under several gravity directions in parallel processes, and plan verification.

`replay_directions` runs one `planner.sim.replay.replay_plan` per direction, each in its own
pybullet client; with ``workers > 1`` in worker processes (forked on Linux, so the hand is
not loaded again). Every replay is deterministic and independent of the others, so the
reports are those of a serial run, in the directions' order.

`verify_plan` is what ``regrasp plan --execution`` runs before it returns a plan: the plan as
it will be written (numbers rounded as in the file) is replayed in every direction it was
planned for; the first failure says which plan step failed (`ReplayReport.failed_step`), so
the planner can remove that transition and search again.
"""

from __future__ import annotations

import math
import multiprocessing
import os
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

from planner.plan import Plan, plan_from_data
from planner.sim.replay import ReplayReport, replay_plan

#: The job the forked workers run (set before the pool forks; read only in the workers).
_JOB: dict = {}


def default_workers() -> int:
    """Worker processes for the directions: the cores this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def _one(i: int) -> ReplayReport:
    job = _JOB
    name, g = job["directions"][i]
    kw = dict(job["kwargs"])
    for key in ("gif", "mp4"):
        if kw.get(key) is not None:
            kw[key] = kw[key][i]
    return replay_plan(job["plan"], hand=job["hand"], gravity=g, **kw)


def replay_directions(plan: Plan, hand, directions: Sequence[tuple[str, Sequence[float]]], *,
                      workers: int | None = None, **kwargs) -> list[ReplayReport]:
    """One replay per named gravity direction (palm frame, m/s^2), in parallel processes.

    Args:
        plan: a `planner.plan.Plan` (read and checked).
        hand: its `planner.hand.Hand`.
        directions: (name, gravity (3,)) pairs.
        workers: processes (default `default_workers`; 1: in this process, one after the other).
        **kwargs: passed to `replay_plan`; ``gif``/``mp4`` are one path (or None) per direction.

    Returns:
        the `ReplayReport` of each direction, in order (identical to a serial run).
    """
    directions = [(str(n), tuple(float(v) for v in g)) for n, g in directions]
    n = len(directions)
    workers = default_workers() if workers is None else int(workers)
    _JOB.clear()
    _JOB.update(plan=plan, hand=hand, directions=directions, kwargs=kwargs)
    try:
        if workers <= 1 or n <= 1 or "fork" not in multiprocessing.get_all_start_methods():
            out = []
            for i in range(n):
                out.append(_one(i))
                _log_done(directions[i][0], out[-1], i + 1, n)
            return out
        from concurrent.futures import as_completed

        with ProcessPoolExecutor(max_workers=min(workers, n), mp_context=multiprocessing.get_context("fork")) as pool:
            futures = {pool.submit(_one, i): i for i in range(n)}
            done: dict[int, object] = {}
            for fut in as_completed(futures):
                i = futures[fut]
                done[i] = fut.result()
                _log_done(directions[i][0], done[i], len(done), n)
            return [done[i] for i in range(n)]
    finally:
        _JOB.clear()


def _log_done(name: str, report, k: int, n: int) -> None:
    """One progress record per replayed direction (`planner.regrasp.log`; the CLI shows it)."""
    import logging

    logging.getLogger("planner").info("replay %d/%d %s: %s", k, n, name, "PASS" if report.passed else "FAIL")


@dataclass(frozen=True)
class Verification:
    """The outcome of `verify_plan`.

    Attributes:
        passed: every direction passed.
        directions: (name, passed, verdict line, failed plan step or None, failed at the
            state it reaches (`ReplayReport.failed_at_state`), max drift mm, max drift deg)
            per direction.
        wall_time_s: wall-clock time of the replays.
    """

    passed: bool
    directions: tuple[tuple[str, bool, str, int | None, bool, float, float], ...]
    wall_time_s: float

    def first_failure(self) -> tuple[str, int, str, bool] | None:
        """(direction, plan step (-1: state 0), verdict, failed at the state the step reaches)
        of the earliest failing step over the directions (ties: the first direction), or None."""
        failed = [(d[3] if d[3] is not None else -1, i) for i, d in enumerate(self.directions) if not d[1]]
        if not failed:
            return None
        step, i = min(failed)
        return self.directions[i][0], step, self.directions[i][2], bool(self.directions[i][4])

    def record(self) -> dict:
        """What the plan records (deterministic: no times)."""
        def num(x: float):
            return round(x, 3) if math.isfinite(x) else None

        return {"passed": self.passed,
                "directions": {name: {"passed": ok, "max_drift_mm": num(mm), "max_drift_deg": num(deg)}
                               for name, ok, _, _, _, mm, deg in self.directions}}


def as_written(plan: Plan) -> Plan:
    """The plan as a file holds it (numbers rounded as `planner.plan` writes them), which is
    what a later `regrasp replay` of the written file simulates."""
    return plan_from_data(plan.to_dict())


def verify_plan(plan: Plan, hand, directions: Sequence[tuple[str, Sequence[float]]], *,
                workers: int | None = None) -> Verification:
    """Replay a plan as it will be written under each direction (`replay_directions`)."""
    t0 = time.perf_counter()
    reports = replay_directions(as_written(plan), hand, directions, workers=workers)
    rows = tuple((name, r.passed, r.verdict, r.failed_step, r.failed_at_state, float(r.max_drift_mm),
                  float(r.max_drift_deg))
                 for (name, _), r in zip(directions, reports))
    return Verification(all(r[1] for r in rows), rows, time.perf_counter() - t0)
