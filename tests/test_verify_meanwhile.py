"""The plan's physics check runs while its verification replays run (`planner.sim.verify`'s
``meanwhile``): in this process, once, while the first ``workers - 1`` forked workers replay
(the other directions start after it), or before the replays with one worker."""

from __future__ import annotations

import multiprocessing
import os
import time
from types import SimpleNamespace

import pytest

import planner.sim.verify as V

DIRS = [("palm_down", (0, 0, 9.81)), ("palm_up", (0, 0, -9.81)), ("side_+x", (9.81, 0, 0)), ("side_-x", (-9.81, 0, 0))]


def test_meanwhile_runs_once_with_the_replays(monkeypatch):
    """`verify_suspects_first` hands ``meanwhile`` to its one `verify_plan`, the suspects
    first in the order."""
    calls, done = [], []

    def fake(plan, hand, directions, *, workers=None, meanwhile=None):
        calls.append(([n for n, _ in directions], meanwhile is not None))
        if meanwhile is not None:
            meanwhile()
        rows = tuple((n, True, "v", None, False, 0.0, 0.0) for n, _ in directions)
        return V.Verification(True, rows, 1.0)

    monkeypatch.setattr(V, "verify_plan", fake)
    V.verify_suspects_first(None, None, DIRS, {"side_+x"}, meanwhile=lambda: done.append(1))
    assert calls == [(["side_+x", "palm_down", "palm_up", "side_-x"], True)] and done == [1]
    calls.clear(), done.clear()
    V.verify_suspects_first(None, None, DIRS, set(), meanwhile=lambda: done.append(1))
    assert calls == [([n for n, _ in DIRS], True)] and done == [1]


def _wait_for(path, seconds: float = 60.0) -> bool:
    t0 = time.monotonic()
    while not os.path.exists(path) and time.monotonic() - t0 < seconds:
        time.sleep(0.01)
    return os.path.exists(path)


def _slow_replay(flag: str):
    """A stand-in `replay_plan` that says it started (``flag`` + ".started") and holds until
    ``flag`` exists (at most 60 s): it passes when the parent's ``meanwhile`` ran while it
    was running."""
    def replay(plan, hand=None, gravity=None, **kw):
        open(flag + ".started", "w").close()
        t0 = time.monotonic()
        while not os.path.exists(flag) and time.monotonic() - t0 < 60:
            time.sleep(0.01)
        return SimpleNamespace(passed=os.path.exists(flag), engine="pybullet", stopped_after=None)
    return replay


def _first_look(flag: str):
    """A stand-in `replay_plan` passing only if ``flag`` existed when it started."""
    def replay(plan, hand=None, gravity=None, **kw):
        return SimpleNamespace(passed=os.path.exists(flag), engine="pybullet", stopped_after=None)
    return replay


FORKS = pytest.mark.skipif("fork" not in multiprocessing.get_all_start_methods(), reason="worker processes are forked")


@FORKS
@pytest.mark.parametrize("n, workers", [(1, 2), (2, 3), (2, 2), (4, 2), (4, 3)])
def test_meanwhile_runs_while_the_first_workers_replay(monkeypatch, tmp_path, n, workers):
    """With two workers or more, the parent's ``meanwhile`` runs once while the first
    ``workers - 1`` directions replay (on the core they leave free: a replay that waits for
    what ``meanwhile`` writes passes), and the other directions start once it is done."""
    flag = tmp_path / "audited"
    slow, look = _slow_replay(str(flag)), _first_look(str(flag))
    early = {g for _, g in DIRS[:max(1, min(n, workers - 1))]}

    def replay(plan, hand=None, gravity=None, **kw):
        return (slow if tuple(gravity) in early else look)(plan, hand, gravity, **kw)

    monkeypatch.setattr(V, "replay_plan", replay)
    monkeypatch.setattr(V, "one_engine", lambda e: "pybullet")
    runs = []

    def meanwhile():  # a replay has started by the time it runs
        runs.append(_wait_for(str(flag) + ".started"))
        flag.write_text("done")

    out = V.replay_directions(object(), None, DIRS[:n], workers=workers, meanwhile=meanwhile)
    assert runs == [True] and [r.passed for r in out] == [True] * n


@FORKS
@pytest.mark.parametrize("n, workers", [(1, 1), (2, 1), (4, 1)])
def test_meanwhile_runs_before_replays_in_this_process(monkeypatch, tmp_path, n, workers):
    """One worker (replaying here): ``meanwhile`` runs once, before any replay starts."""
    flag = tmp_path / "audited"
    monkeypatch.setattr(V, "replay_plan", _first_look(str(flag)))
    monkeypatch.setattr(V, "one_engine", lambda e: "pybullet")
    runs = []
    out = V.replay_directions(object(), None, DIRS[:n], workers=workers,
                              meanwhile=lambda: (runs.append(1), flag.write_text("done")))
    assert runs == [1] and [r.passed for r in out] == [True] * n
