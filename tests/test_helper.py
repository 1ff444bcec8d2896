"""The search's helper process (`planner.helper`): a share of each batch of states tested in a
forked process gives the same states, grips, refusals and sequences as one process."""

import multiprocessing
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import planner.closure as closure
import planner.lp as lp
from planner import helper as helper_mod
from planner.graph import Evaluator
from planner.grasp import load_grasp
from planner.options import PlanOptions
from planner.realization import realize
from planner.regrasp import plan_regrasp

pytestmark = pytest.mark.skipif(not helper_mod.available(), reason="helpers need the fork start method")

ICUB = Path(__file__).resolve().parent.parent / "grasps" / "icub"


def _pid_square(x):
    return os.getpid(), x * x


def _fails_on(x, bad):
    if x == bad:
        raise ValueError(f"item {x}")
    return x


def test_map_is_the_serial_map_with_the_last_half_in_the_helper():
    with helper_mod.Helper() as h:
        items = [(i,) for i in range(7)]
        out = h.map(_pid_square, items)
        assert [sq for _, sq in out] == [i * i for i in range(7)]
        pids = [pid for pid, _ in out]
        assert pids[:4] == [os.getpid()] * 4  # the caller's share: the first n - n // 2
        assert len(set(pids[4:])) == 1 and pids[4] != os.getpid()
        assert [p for p, _ in h.map(_pid_square, items, share=0)] == [os.getpid()] * 7
        assert h.map(_pid_square, []) == []
    assert not h.alive
    assert [sq for _, sq in h.map(_pid_square, [(3,), (4,)])] == [9, 16]  # closed: all here


def test_an_error_in_either_share_raises_in_the_caller_as_without_a_helper():
    with helper_mod.Helper() as h:
        items = [(i, 5) for i in range(8)]
        with pytest.raises(ValueError, match="item 5"):  # the helper's share: re-run here, raising
            h.map(_fails_on, items)
        assert h.failure is not None and "ValueError" in h.failure and not h.alive
    with helper_mod.Helper() as h:
        with pytest.raises(ValueError, match="item 1"):  # the caller's share
            h.map(_fails_on, [(i, 1) for i in range(8)])
        assert h.alive and h.failure is None
        assert h.map(_fails_on, [(i, -1) for i in range(8)]) == list(range(8))  # the pipe is still in step


@pytest.fixture(scope="module")
def box_pair():
    """The bundled box pair, realized once per module."""
    return realize(load_grasp(ICUB / "box_parallel_extension.yaml")), realize(load_grasp(ICUB / "box_ir2m.yaml"))


def test_a_search_with_a_helper_equals_the_search_without(box_pair, monkeypatch):
    """The bundled box pair in execution mode (grip ranking, six gravity directions, the
    torque model): one process and one process with a helper give the same sequence, the
    same explored graph (states, their closure metrics exactly, grips per direction,
    blocked states and why) and the helper evaluated half of the batches' states."""
    shares = []
    real_map = helper_mod.Helper.map

    def counting(self, fn, items, share=None):
        out = real_map(self, fn, items, share)
        assert self.failure is None  # the helper did its share (no fallback to the caller)
        shares.append(len(items[-1][3]))  # the second half's states (the helper's)
        return out

    monkeypatch.setattr(helper_mod.Helper, "map", counting)
    a, b = box_pair
    runs = {}
    for workers in (1, 2):
        closure._GRIP_MEMO.clear()  # each run solves its own programs
        lp.forget()
        res = plan_regrasp(a, b, PlanOptions.for_execution(verify=False, motion=False, workers=workers))
        assert not [c for c in multiprocessing.active_children() if c.name == "regrasp-search-helper"]
        G = res.graph
        runs[workers] = (
            res.sequence.order(G.graph["problem"]), res.sequence.bottleneck_grip,
            {v: G.nodes[v]["grip_forces"] for v in G.nodes}, dict(G.graph["blocked"]),
            [s.order(G.graph["problem"]) for s in res.alternatives], {v: G.nodes[v]["metric"] for v in G.nodes})
        if workers == 1:
            assert not shares
    assert sum(shares) >= 8, shares  # the helper did evaluate states
    assert runs[1][0] == runs[2][0] and runs[1][1] == runs[2][1] and runs[1][4] == runs[2][4]
    # every state's grip in every direction, to the last digit (each half's programs start from
    # scratch, so a state's are solved in the same sequence in either process)
    assert runs[1][2] == runs[2][2]
    assert runs[1][3] == runs[2][3]  # the same states refused, for the same reasons
    assert runs[1][5] == runs[2][5]  # the same halves' closures, computed alike in either process


def test_a_state_is_tested_alike_alone_or_in_a_batch(box_pair):
    """`Evaluator.evaluate_states` of a batch (half in the helper; the loads in one order for
    the batch) agrees on every state with `GaitProblem.load_refusal` of that state alone in
    that order: holds with the same grips (to HiGHS's tolerance: a program re-solved from
    another optimum may differ in the 11th digit), or the same refused load and capacity."""
    a, b = box_pair
    res = plan_regrasp(a, b, PlanOptions.for_execution(verify=False, motion=False, workers=1))
    problem = res.graph.graph["problem"]
    rng = np.random.default_rng(3)
    nodes = list(res.graph.nodes) + list(res.graph.graph["blocked"])
    nodes = [nodes[i] for i in rng.permutation(len(nodes))[:60]]
    batch = Evaluator(problem)
    batch.helpers = 1
    batch.evaluate(nodes)
    ok = [n for n in nodes if batch.collision_free(n) and batch.closure[n].is_force_closure]
    assert len(ok) >= 8
    batch.evaluate_states(ok)  # a fresh evaluator: the loads in their own order
    batch.close()
    n_loads = len(problem.all_loads())
    refused = 0
    for n in ok:
        grip = [None] * n_loads
        why = problem.load_refusal(problem.patches(n), problem.statics(n), list(range(n_loads)), grip)
        if why is None:
            assert n in batch.hold and batch.grip[n] == pytest.approx(tuple(grip), rel=1e-9, abs=1e-12)
        else:
            refused += 1
            assert batch._over[n][0] == why[0]
            assert (batch._over[n][1] is None) == (why[1] is None)
            if why[1] is not None:
                assert batch._over[n][1].factor == pytest.approx(why[1].factor, rel=1e-9)
    assert 0 < len(ok) - refused


def test_a_helper_ends_when_its_caller_dies_without_closing_it():
    """A caller killed (here ``os._exit``) leaves no helper behind: the helper closes its copy
    of the caller's pipe end, so the pipe closes with the caller and the helper's loop ends."""
    code = ("import os, sys; from planner.helper import Helper; h = Helper(); "
            "print(h._proc.pid, flush=True); os._exit(0)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                         cwd=Path(__file__).resolve().parent.parent)
    pid = int(out.stdout.split()[0])
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline:
        try:
            os.kill(pid, 0)
            with open(f"/proc/{pid}/stat") as f:  # ended but not yet reaped by its new parent
                if f.read().rsplit(")", 1)[1].split()[0] == "Z":
                    return
        except (ProcessLookupError, FileNotFoundError):
            return
        time.sleep(0.1)
    os.kill(pid, 9)
    pytest.fail(f"the helper {pid} outlived its caller")


def test_a_helper_that_cannot_be_forked_leaves_the_search_in_one_process(box_pair, monkeypatch):
    """Forking fails (OSError, e.g. no memory): the search runs in the planner's process alone
    and plans as it does with ``workers=1``."""
    def no_fork(self):
        raise OSError(12, "Cannot allocate memory")

    monkeypatch.setattr(helper_mod.Helper, "__init__", no_fork)
    a, b = box_pair
    one = plan_regrasp(a, b, PlanOptions.for_execution(verify=False, motion=False, workers=1))
    two = plan_regrasp(a, b, PlanOptions.for_execution(verify=False, motion=False, workers=2))
    assert one.sequence.order(one.graph.graph["problem"]) == two.sequence.order(two.graph.graph["problem"])
    assert one.graph.number_of_nodes() == two.graph.number_of_nodes()


def _square_or_fail(x):
    if x == "boom":
        raise ValueError("boom")
    return os.getpid(), x * x


def test_fork_map_is_the_serial_map_with_the_last_half_in_a_copy():
    """Inputs inherited (a closure over an object that does not pickle works), results pickled
    back in order; one process when asked; an error in the copy's half raises here."""
    import threading

    lock = threading.Lock()  # does not pickle: the copy inherits it

    def square(x):
        with lock:
            return os.getpid(), x * x

    out = helper_mod.fork_map(square, list(range(5)))
    assert [sq for _, sq in out] == [0, 1, 4, 9, 16]
    pids = [p for p, _ in out]
    assert pids[:3] == [os.getpid()] * 3 and pids[3] == pids[4] != os.getpid()
    assert [p for p, _ in helper_mod.fork_map(square, [1, 2], processes=1)] == [os.getpid()] * 2
    with pytest.raises(ValueError, match="boom"):
        helper_mod.fork_map(_square_or_fail, [1, 2, "boom"])
    assert not [c for c in multiprocessing.active_children() if c.name == "regrasp-fork-map"]


def _first(x, _):
    return x


def test_a_share_that_does_not_pickle_is_computed_by_the_caller():
    """An item that does not pickle (a lock) cannot go to the helper: the caller computes the
    whole batch, the same answers, and the helper is closed with the reason."""
    import threading

    with helper_mod.Helper() as h:
        items = [(i, threading.Lock()) for i in range(4)]
        assert h.map(_first, items) == [0, 1, 2, 3]
        assert not h.alive and "could not send" in h.failure
