"""Replays resumed from snapshots (`planner.sim.snapshots`): the report of a replay resumed
where an earlier replay of a plan with the same beginning stood is the report of a replay of
it from the start (to the last digit; only the wall time differs), a snapshot that is gone
means a replay from the start, and the digests name exactly the shared beginning."""

from __future__ import annotations

import copy
import dataclasses
import json
import math
import multiprocessing
import os
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pybullet")

from planner.plan import plan_from_data, read_plan  # noqa: E402
from planner.sim import snapshots  # noqa: E402
from planner.sim.inputs import plan_hand  # noqa: E402
from planner.sim.replay import StopLine  # noqa: E402
from planner.sim.verify import as_written, replay_directions  # noqa: E402

PLAN = Path(__file__).parent / "data" / "plans" / "schema2_cylinder_execution.json"
PALM_DOWN = [("palm_down", (0.0, 0.0, 9.81))]
FORKS = pytest.mark.skipif("fork" not in multiprocessing.get_all_start_methods(), reason="replays run in forked workers")


def _differ(a, b, path="report"):
    """The first place two reports differ (exactly: arrays element by element, NaN equal to
    NaN), or None; the wall time is not compared."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a2, b2 = np.asarray(a), np.asarray(b)
        same = a2.shape == b2.shape and np.array_equal(a2, b2, equal_nan=a2.dtype.kind == "f")
        return None if same else path
    if dataclasses.is_dataclass(a) and not isinstance(a, type):
        if type(a) is not type(b):
            return path
        for f in dataclasses.fields(a):
            if f.name != "wall_time_s":
                d = _differ(getattr(a, f.name), getattr(b, f.name), f"{path}.{f.name}")
                if d:
                    return d
        return None
    if isinstance(a, dict):
        if not isinstance(b, dict) or set(a) != set(b):
            return path
        return next((d for k in a if (d := _differ(a[k], b[k], f"{path}[{k!r}]"))), None)
    if isinstance(a, (list, tuple)):
        if not isinstance(b, (list, tuple)) or len(a) != len(b):
            return path
        return next((d for i, (x, y) in enumerate(zip(a, b)) if (d := _differ(x, y, f"{path}[{i}]"))), None)
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return None
    return None if a == b else path


def _plans(j: int):
    """The bundled plan, and the same plan with step ``j``'s inner waypoints moved 0.01 rad:
    equal up to step j - 1."""
    data = read_plan(PLAN).to_dict()
    other = copy.deepcopy(data)
    path = other["steps"][j]["path"]
    assert len(path) >= 3
    other["steps"][j]["path"] = [w if i in (0, len(path) - 1) else [v + 0.01 for v in w] for i, w in enumerate(path)]
    return as_written(plan_from_data(data)), as_written(plan_from_data(other))


def _setting():
    return ({"dt": 1 / 240}, "pybullet")


def test_digests_name_the_shared_beginning():
    """Two plans equal up to step j - 1 share the digests of state 0 and steps 0..j-1 and no
    later one; another replay setting shares none."""
    j = 4
    plan, other = _plans(j)
    a, b = snapshots.Chain(plan, _setting()), snapshots.Chain(other, _setting())
    assert len(a.digests) == len(plan.steps) + 1
    assert all(a.at(k) == b.at(k) for k in range(-1, j))
    assert all(a.at(k) != b.at(k) for k in range(j, len(plan.steps)))
    c = snapshots.Chain(plan, ({"dt": 1 / 480}, "pybullet"))
    assert not set(c.digests) & set(a.digests)
    assert len(set(a.digests)) == len(a.digests)


def _replay(plan, hand, scoped: bool):
    kw = {"snapshots": snapshots.current()} if scoped else {}
    # one direction on two workers: it runs in a forked worker, as a verification's does
    return replay_directions(plan, hand, PALM_DOWN, workers=2, meanwhile=lambda: None, stop_at_failure=StopLine(),
                             **kw)[0]


def _spy_resume(monkeypatch, log: Path):
    """Record, from the worker, the step each replay resumed at (-2: from the start)."""
    real = snapshots.Snapshots.resume

    def resume(self, plan, line):
        got = real(self, plan, line)
        with open(log, "a") as fh:
            fh.write("resumed\n" if got is not None else "start\n")
        return got

    monkeypatch.setattr(snapshots.Snapshots, "resume", resume)


@FORKS
def test_a_resumed_replay_is_the_replay_from_the_start(monkeypatch, tmp_path):
    """The plan replayed after another that shares its first steps resumes from that one's
    snapshot, and reports exactly what its replay from the start reports; the snapshots
    end with their scope."""
    j = 4
    plan, other = _plans(j)
    hand = plan_hand(plan)
    fresh = _replay(plan, hand, scoped=False)
    log = tmp_path / "resumed.txt"
    _spy_resume(monkeypatch, log)
    with snapshots.scope() as d:
        first = _replay(other, hand, scoped=True)
        left = sorted(os.listdir(d))
        resumed = _replay(plan, hand, scoped=True)
        after = sorted(os.listdir(d))
    assert log.read_text().split() == ["start", "resumed"]
    # one snapshot per measured state of the first replay (state 0 and every step), then
    # the resumed one's own from step j on
    assert len(left) == len(other.steps) + 1
    assert len(after) == len(left) + len(plan.steps) - j
    assert _differ(fresh, resumed) is None
    assert first.passed == fresh.passed  # (the other plan is another replay: its own report)
    assert not os.path.exists(d)


@FORKS
def test_a_snapshot_gone_means_a_replay_from_the_start(monkeypatch, tmp_path):
    """A replay whose snapshots were removed (their files gone) runs from the start, with the
    same report."""
    plan, other = _plans(4)
    hand = plan_hand(plan)
    log = tmp_path / "resumed.txt"
    _spy_resume(monkeypatch, log)
    with snapshots.scope() as d:
        _replay(other, hand, scoped=True)
        for name in os.listdir(d):
            os.remove(os.path.join(d, name))
        again = _replay(plan, hand, scoped=True)
    assert log.read_text().split() == ["start", "start"]
    assert _differ(_replay(plan, hand, scoped=False), again) is None


def test_no_snapshots_in_the_scope_process():
    """A replay in the process that opened the scope (one worker) leaves no snapshot: it
    would fork the planner."""
    plan, _ = _plans(4)
    hand = plan_hand(plan)
    with snapshots.scope() as d:
        replay_directions(plan, hand, PALM_DOWN, workers=1, stop_at_failure=StopLine(), snapshots=snapshots.current())
        assert os.listdir(d) == []


@FORKS
def test_the_snapshots_of_a_killed_planner_remove_its_scope(tmp_path):
    """A planner killed before it closes its scope leaves no directory behind: its snapshots
    see it gone, remove the scope's directory and exit."""
    plan, _ = _plans(4)
    hand = plan_hand(plan)
    where = tmp_path / "scope.txt"
    pid = os.fork()
    if pid == 0:  # the planner: replays in a worker, then dies with its scope open
        try:
            with snapshots.scope() as d:
                _replay(plan, hand, scoped=True)
                where.write_text(d)
                os._exit(0)  # inside the scope: its own cleanup never runs
        finally:
            os._exit(1)
    assert os.waitpid(pid, 0)[1] == 0
    d = where.read_text()
    for _ in range(200):  # a snapshot looks every POLL_S (0.5 s)
        if not os.path.exists(d):
            break
        time.sleep(0.05)
    assert not os.path.exists(d)


def _in_child(fn, out: Path):
    """``fn()``'s dict, computed in a forked child (a replay that may resume: not the scope's
    own process)."""
    pid = os.fork()
    if pid == 0:
        try:
            out.write_text(json.dumps(fn()))
        finally:
            os._exit(0)
    os.waitpid(pid, 0)
    return json.loads(out.read_text())


@FORKS
def test_a_resumed_replay_takes_the_stop_line_through_its_requester(monkeypatch, tmp_path):
    """A replay resumed from a snapshot is stopped, unfailed, when a replay before it in the
    order has failed (the requester says so), and its own failure marks its place on the
    requester's line."""
    from planner.sim.replay import _Sim, replay_plan

    plan, other = _plans(4)
    hand = plan_hand(plan)
    log = tmp_path / "resumed.txt"
    _spy_resume(monkeypatch, log)
    force = tmp_path / "fail"
    real_swap = _Sim.swap_plan

    def swap(self, rd, line):  # a copy that fails as soon as it resumes, when asked
        real_swap(self, rd, line)
        if force.exists():
            self.failure, self.fail_step = "made up", 4

    monkeypatch.setattr(_Sim, "swap_plan", swap)

    def run(line):
        def fn():
            r = replay_plan(plan, hand=hand, gravity=PALM_DOWN[0][1], stop_at_failure=line,
                            snapshots=snapshots.current())
            return {"stopped_after": r.stopped_after, "passed": r.passed, "failed_step": r.failed_step}
        return fn

    with snapshots.scope():
        _replay(other, hand, scoped=True)
        line = StopLine()
        line.at(0).fail()
        stopped = _in_child(run(line.at(1)), tmp_path / "a.json")
        force.touch()
        line = StopLine()
        failed = _in_child(run(line.at(3)), tmp_path / "b.json")
    assert log.read_text().split() == ["start", "resumed", "resumed"]
    assert stopped["stopped_after"] is not None and not stopped["passed"] and stopped["failed_step"] is None
    assert not failed["passed"] and failed["stopped_after"] is None and line.first() == 3
