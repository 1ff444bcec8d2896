"""How `planner.sim.verify` schedules a plan's verification: the directions the model holds
with the least margin are replayed first, and the plan's physics check runs while the
replays do (`replay_directions`' ``meanwhile``)."""

from __future__ import annotations

import multiprocessing
import os
import time
from types import SimpleNamespace

import pytest

import planner.sim.verify as V

DIRS = [("palm_down", (0, 0, 9.81)), ("palm_up", (0, 0, -9.81)), ("side_+x", (9.81, 0, 0)), ("side_-x", (-9.81, 0, 0))]


def _plan(*factors):
    """A stand-in plan: one state per mapping of direction name -> hold factor (None: none)."""
    return SimpleNamespace(states=[SimpleNamespace(hold_factor_by_gravity=f) for f in factors])


def test_weakest_first_orders_by_the_smallest_hold_factor_over_the_states():
    plan = _plan({"palm_down": 40.0, "palm_up": 9.0, "side_+x": 30.0},
                 {"palm_down": 3.0, "palm_up": 12.0, "side_+x": 30.0},
                 None)
    # palm_down's weakest state holds 3x, palm_up's 9x, side_+x's 30x; side_-x has no factor: last
    assert V.weakest_first(plan, DIRS) == ["palm_down", "palm_up", "side_+x", "side_-x"]
    # ties keep the directions' order; no plan: the directions' order
    assert V.weakest_first(_plan({"palm_up": 5.0, "palm_down": 5.0}), DIRS)[:2] == ["palm_down", "palm_up"]
    assert V.weakest_first(None, DIRS) == [n for n, _ in DIRS]
    # a permutation of the directions, whatever the factors
    assert sorted(V.weakest_first(plan, DIRS[::-1])) == sorted(n for n, _ in DIRS)


def _fake_verify(monkeypatch, failing: set[str], calls: list):
    def fake(plan, hand, directions, *, workers=None, meanwhile=None):
        calls.append([n for n, _ in directions])
        if meanwhile is not None:
            meanwhile()
        rows = tuple((n, n not in failing, "v", 4 if n in failing else None, False, 0.0, 0.0) for n, _ in directions)
        return V.Verification(all(r[1] for r in rows), rows, 1.0)

    monkeypatch.setattr(V, "verify_plan", fake)


def test_without_suspects_the_two_weakest_directions_decide_first(monkeypatch):
    """No direction rejected an earlier sequence: the plan's `FIRST_BATCH` weakest are replayed
    first; when one fails the others are not replayed; when they hold, every direction is,
    and the rows are in the directions' order. ``meanwhile`` runs once, in the first batch."""
    plan = _plan({"palm_down": 50.0, "palm_up": 2.0, "side_+x": 60.0, "side_-x": 4.0})
    calls, done = [], []
    _fake_verify(monkeypatch, {"side_-x"}, calls)
    got = V.verify_suspects_first(plan, None, DIRS, set(), meanwhile=lambda: done.append(1))
    assert calls == [["palm_up", "side_-x"]] and not got.passed and got.first_failure()[:2] == ("side_-x", 4)
    assert done == [1]
    calls.clear(), done.clear()
    _fake_verify(monkeypatch, set(), calls)
    got = V.verify_suspects_first(plan, None, DIRS, set(), meanwhile=lambda: done.append(1))
    assert calls == [["palm_up", "side_-x"], ["palm_down", "side_+x"]] and got.passed
    assert [r[0] for r in got.directions] == [n for n, _ in DIRS] and done == [1]
    # a direction that rejected before goes first alone, whatever the factors
    calls.clear()
    V.verify_suspects_first(plan, None, DIRS, {"palm_down"})
    assert calls[0] == ["palm_down"]


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
