"""The plan's physics check runs while its verification replays run (`planner.sim.verify`'s
``meanwhile``): in this process, once, while forked workers replay."""

from __future__ import annotations

import multiprocessing
import os
import time
from types import SimpleNamespace

import pytest

import planner.sim.verify as V

DIRS = [("palm_down", (0, 0, 9.81)), ("palm_up", (0, 0, -9.81)), ("side_+x", (9.81, 0, 0)), ("side_-x", (-9.81, 0, 0))]


def test_meanwhile_runs_once_in_the_first_replays(monkeypatch):
    """`verify_suspects_first` hands ``meanwhile`` to the first replays only: the suspects'
    when a direction rejected before, else every direction's."""
    calls, done = [], []

    def fake(plan, hand, directions, *, workers=None, meanwhile=None):
        calls.append(([n for n, _ in directions], meanwhile is not None))
        if meanwhile is not None:
            meanwhile()
        rows = tuple((n, True, "v", None, False, 0.0, 0.0) for n, _ in directions)
        return V.Verification(True, rows, 1.0)

    monkeypatch.setattr(V, "verify_plan", fake)
    V.verify_suspects_first(None, None, DIRS, {"side_+x"}, meanwhile=lambda: done.append(1))
    assert calls == [(["side_+x"], True), (["palm_down", "palm_up", "side_-x"], False)] and done == [1]
    calls.clear(), done.clear()
    V.verify_suspects_first(None, None, DIRS, set(), meanwhile=lambda: done.append(1))
    assert calls == [([n for n, _ in DIRS], True)] and done == [1]


def _slow_replay(flag: str):
    """A stand-in `replay_plan` that holds until ``flag`` exists (at most 60 s): it can only
    finish when the parent's ``meanwhile`` ran while it was running."""
    def replay(plan, hand=None, gravity=None, **kw):
        t0 = time.monotonic()
        while not os.path.exists(flag) and time.monotonic() - t0 < 60:
            time.sleep(0.01)
        return SimpleNamespace(passed=os.path.exists(flag), engine="pybullet", stopped_after=None)
    return replay


@pytest.mark.skipif("fork" not in multiprocessing.get_all_start_methods(), reason="worker processes are forked")
@pytest.mark.parametrize("n", [1, 2])
def test_meanwhile_runs_while_the_workers_replay(monkeypatch, tmp_path, n):
    """With worker processes (one direction too) the parent's ``meanwhile`` runs once while
    the replays run: a replay that waits for what ``meanwhile`` writes passes."""
    flag = tmp_path / "audited"
    monkeypatch.setattr(V, "replay_plan", _slow_replay(str(flag)))
    monkeypatch.setattr(V, "one_engine", lambda e: "pybullet")
    runs = []

    def meanwhile():
        runs.append(1)
        flag.write_text("done")

    out = V.replay_directions(object(), None, DIRS[:n], workers=2, meanwhile=meanwhile)
    assert runs == [1] and [r.passed for r in out] == [True] * n


def test_meanwhile_runs_before_replays_in_this_process(monkeypatch, tmp_path):
    """One worker: the replays run here, after ``meanwhile`` (called once)."""
    flag = tmp_path / "audited"
    monkeypatch.setattr(V, "replay_plan", _slow_replay(str(flag)))
    monkeypatch.setattr(V, "one_engine", lambda e: "pybullet")
    runs = []
    out = V.replay_directions(object(), None, DIRS[:2], workers=1,
                              meanwhile=lambda: (runs.append(1), flag.write_text("done")))
    assert runs == [1] and all(r.passed for r in out)
