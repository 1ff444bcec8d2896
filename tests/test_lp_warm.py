"""The grip force of one set of contacts under several loads re-solved from HiGHS's last optimum
(`planner.lp.solve_highs_rhs`), and the grip ranking's indifference to HiGHS's last digits
(`planner.gait_search.GRIP_RANK_DECIMALS`)."""

import math

import numpy as np
import pytest

import planner.closure as closure_module
import planner.lp as lp_backend
from planner.closure import min_grip_force
from planner.gait_search import search
from planner.graph import build_graph
from planner.model import Friction

from tests.test_graph import loaded_deadlock

FRICTION = Friction(0.6, 0.004)
#: The six gravity directions of a 50 g object, as loads [f ; tau] about its centre.
LOADS = [np.r_[0.05 * 9.81 * s * np.eye(3)[i], np.zeros(3)] for i in range(3) for s in (1, -1)]


@pytest.fixture(autouse=True)
def _fresh(monkeypatch):
    monkeypatch.setattr(closure_module, "_GRIP_MEMO", {})
    lp_backend.forget()
    yield
    lp_backend.forget()  # (not restored: the program it named is no longer the one HiGHS holds)


def _contacts(rng, n_fingers):
    """Fingers touching a 25 mm sphere at points spread over it (a Fibonacci lattice, turned at
    random and jittered by ~0.2 rad: mostly force closure), inward normals, one point each."""
    i = np.arange(n_fingers) + 0.5
    z, phi = 1 - 2 * i / n_fingers, np.pi * (1 + 5 ** 0.5) * i
    d = np.c_[np.sqrt(1 - z * z) * np.cos(phi), np.sqrt(1 - z * z) * np.sin(phi), z] + rng.normal(0, 0.2, (n_fingers, 3))
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    d = (d / np.linalg.norm(d, axis=1, keepdims=True)) @ q.T
    return {f"f{k}": (0.025 * d[k][None, :], -d[k][None, :]) for k in range(n_fingers)}


def _cold(patches, load):
    """The grip force with nothing held: the program passed and solved from scratch."""
    closure_module._GRIP_MEMO.clear()
    lp_backend.forget()
    return min_grip_force(patches, FRICTION, load)


@pytest.mark.parametrize("seed", range(6))
def test_warm_answers_equal_the_answers_from_scratch(seed):
    """Random grasps of 2-5 fingers under the six gravity loads, one after the other (each
    after the first re-solved from the last optimum): the same grip force as each solved
    alone from scratch, to 1e-8, and infeasible (inf) exactly where it is."""
    rng = np.random.default_rng(seed)
    for n in (2, 3, 4, 5):
        patches = _contacts(rng, n)
        closure_module._GRIP_MEMO.clear()
        warm = [min_grip_force(patches, FRICTION, w) for w in LOADS]
        cold = [_cold(patches, w) for w in LOADS]
        for a, b in zip(warm, cold):
            assert math.isinf(a) == math.isinf(b)
            if math.isfinite(b):
                assert a == pytest.approx(b, rel=1e-8, abs=1e-12)


def test_the_other_loads_pass_no_model_and_another_program_in_between_is_solved_from_scratch(monkeypatch):
    """Six loads on one grasp: one model passed (the first load), five re-solves. A program of
    other contacts in between is passed and solved from scratch, and the first grasp's next load
    then too (the instance no longer holds it), with the right answers."""
    passed = []
    real = lp_backend.highs_lp
    monkeypatch.setattr(lp_backend, "highs_lp", lambda *a: passed.append(1) or real(*a))
    rng = np.random.default_rng(7)
    a, b = _contacts(rng, 4), _contacts(rng, 3)
    ta = [min_grip_force(a, FRICTION, w) for w in LOADS[:3]]
    assert len(passed) == 1
    tb = min_grip_force(b, FRICTION, LOADS[0])
    assert len(passed) == 2
    ta += [min_grip_force(a, FRICTION, w) for w in LOADS[3:]]
    assert len(passed) == 3
    assert tb == pytest.approx(_cold(b, LOADS[0]), rel=1e-8)
    assert ta == pytest.approx([_cold(a, w) for w in LOADS], rel=1e-8)


def test_a_warm_solve_ending_infeasible_is_decided_from_scratch():
    """Two opposed contacts without torsional friction hold a weight across their axis but no
    moment about it: after the weight's optimum, the moment is inf (infeasible), and the next
    load is solved right again."""
    opposed = {"a": (np.array([[0.02, 0.0, 0.0]]), np.array([[-1.0, 0.0, 0.0]])),
               "b": (np.array([[-0.02, 0.0, 0.0]]), np.array([[1.0, 0.0, 0.0]]))}
    fr = Friction(0.5, 0.0)
    weight, moment = [0.0, 0.0, -1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.01, 0.0, 0.0]
    t = min_grip_force(opposed, fr, weight)
    assert 1.0 <= t <= 1.0 / math.cos(math.pi / 16) + 1e-9  # W / (2 mu), the 16-gon's bound
    assert min_grip_force(opposed, fr, moment) == math.inf
    assert min_grip_force(opposed, fr, [0.0, -1.0, 0.0, 0.0, 0.0, 0.0]) == pytest.approx(t, rel=1e-8)


@pytest.mark.parametrize("seed", range(4))
def test_grip_ranking_ignores_differences_below_a_micronewton(seed):
    """Every state needing the same grip force, but for a random 1e-10 N each (what HiGHS's last
    digits do between programs with the same optimum): the grip ranking's best sequences are
    those of the exactly equal forces, where gait steps and the closure metric decide."""
    rng = np.random.default_rng(seed)
    G = build_graph(loaded_deadlock([tuple(rng.normal(size=3)) for _ in range(2)]))
    for v in G.nodes:
        G.nodes[v]["grip_force"] = 0.5
    tied = search(G, k=6, rank="grip")
    for v in G.nodes:
        G.nodes[v]["grip_force"] = 0.5 + float(rng.uniform(-1e-10, 1e-10))
    noisy = search(G, k=6, rank="grip")
    assert [s.nodes for s in noisy] == [s.nodes for s in tied]
    assert [s.gait_steps for s in noisy] == sorted(s.gait_steps for s in noisy)


def test_a_warm_zero_is_zero_not_a_hair_below():
    """Recorded from exp9 v2's Allegro mesh 0.3 kg plan (tests/data/grip_warm_zero.npz: the
    wrenches of thumb, middle and the palm, the weight palm down then palm up): palm up the palm
    carries the weight and no finger force is needed. From the palm-down optimum, HiGHS's warm
    objective read -4.0e-13, and the plan file was refused for a negative grip force; the
    program's bound t >= 0 makes it 0."""
    from pathlib import Path

    data = np.load(Path(__file__).parent / "data" / "grip_warm_zero.npz")
    W, spans, (down, up) = data["W"], [tuple(int(v) for v in s) for s in data["spans"]], data["loads"]
    assert closure_module._grip_lp(W, spans, down) > 0.1
    assert closure_module._grip_lp(W, spans, up) == 0.0


@pytest.mark.parametrize("seed", range(3))  # (seed 3's extra contacts leave no sequence)
def test_the_lazy_search_ignores_differences_below_a_micronewton(monkeypatch, seed):
    """`LazyGraph.best` (the planner's search) where every state needs 0.5 N per finger but
    for a 1e-10 N of its own (a function of its contacts): the same best sequences as with
    exactly 0.5 N everywhere."""
    import zlib

    import planner.graph as graph_module
    from planner.gait_search import LazyGraph

    rng = np.random.default_rng(seed)
    extra = [tuple(rng.normal(size=3)) for _ in range(3)]

    def grip(noise):
        class Fake:  # stands in for the grip program of a state's contacts
            def __init__(self, patches, friction, **kw):
                self.patches = patches

            def force(self, load):
                if not noise:
                    return 0.5
                data = b"".join(np.asarray(p[0], dtype=float).tobytes() for _, p in sorted(self.patches.items()))
                return 0.5 + (zlib.crc32(data + np.asarray(load, dtype=float).tobytes()) / 2 ** 32 - 0.5) * 2e-10
        return Fake

    found = {}
    for noise in (False, True):
        monkeypatch.setattr(graph_module, "GripContacts", grip(noise))
        found[noise] = [s.nodes for s in LazyGraph(loaded_deadlock(extra), "grip").best(6)]
    assert found[True] == found[False] and found[False]
