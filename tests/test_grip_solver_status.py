"""`planner.closure.min_grip_force`: infeasible (``inf``) and a solver failure (an error) never look the same."""

import math
from types import SimpleNamespace

import numpy as np
import pytest
import scipy.optimize

import planner.closure as closure_module
import planner.lp as lp_backend
from planner.model import Friction
from planner.closure import min_grip_force
from planner.errors import PlannerError

WEIGHT = [0.0, 0.0, -1.0, 0.0, 0.0, 0.0]


@pytest.fixture(autouse=True)
def _fresh_answers(monkeypatch):
    """min_grip_force remembers its answers (and a grasp's wrenches) by their exact inputs: each
    test starts without them, so a solver stood in by a test is asked, not an answer remembered
    from another test's real solver."""
    monkeypatch.setattr(closure_module, "_GRIP_MEMO", {})
    # nor from a program HiGHS still holds at an optimum (`planner.lp.solve_highs_rhs`)
    lp_backend.forget()
    yield
    lp_backend.forget()  # (not restored: the program it named is no longer the one HiGHS holds)


def _antipodal(r=0.02):
    return {"a": (np.array([[r, 0.0, 0.0]]), np.array([[-1.0, 0.0, 0.0]])),
            "b": (np.array([[-r, 0.0, 0.0]]), np.array([[1.0, 0.0, 0.0]]))}


def _solver_says(monkeypatch, status: int, message: str):
    """Make HiGHS (`planner.lp.highs_lp`, in scipy's status codes) answer with this status and no solution."""
    monkeypatch.setattr(lp_backend, "highs_lp", lambda *a, **k: SimpleNamespace(status=status, message=message, x=None))


def test_an_infeasible_load_is_inf_and_a_feasible_one_is_finite():
    """Without torsional friction no normal force resists a moment about the contact axis
    (infeasible: inf); with friction a weight across the axis is held by W / (2 mu) or a bit more."""
    moment = [0.0, 0.0, 0.0, 0.01, 0.0, 0.0]
    assert min_grip_force(_antipodal(), Friction(0.5, 0.0), moment) == math.inf
    assert min_grip_force({}, Friction(0.5, 0.0), WEIGHT) == math.inf  # no contact holds anything
    t = min_grip_force(_antipodal(), Friction(0.5, 0.0), WEIGHT)
    assert 1.0 / (2 * 0.5) <= t <= 1.0 / (2 * 0.5 * math.cos(math.pi / 16)) + 1e-9


def test_the_solver_proving_infeasibility_is_inf(monkeypatch):
    """scipy status 2 is HiGHS's proof of infeasibility: the documented ``inf``."""
    _solver_says(monkeypatch, 2, "The problem is infeasible. (HiGHS Status 8: ...)")
    assert min_grip_force(_antipodal(), Friction(0.5, 0.0), WEIGHT) == math.inf


def test_unbounded_or_infeasible_is_infeasible_for_this_bounded_program(monkeypatch):
    """HiGHS's 'unbounded or infeasible' (scipy status 4) can only be infeasible: t >= 0 is minimized."""
    _solver_says(monkeypatch, 4, "The problem is unbounded or infeasible. (HiGHS Status 10: ...)")
    assert min_grip_force(_antipodal(), Friction(0.5, 0.0), WEIGHT) == math.inf


@pytest.mark.parametrize("status, message", [
    (1, "Iteration limit reached. (HiGHS Status 14: ...)"),
    (4, "The HiGHS status code was not recognized. (HiGHS Status 99: ...)"),
    (4, "(HiGHS Status 4: numerical difficulties)"),
])
def test_a_solver_failure_raises_instead_of_reading_as_infeasible(monkeypatch, status, message):
    """An iteration limit or numerical trouble is an unknown grip force: a PlannerError
    naming the solver's status, not ``inf`` (which callers read as 'cannot hold')."""
    _solver_says(monkeypatch, status, message)
    with pytest.raises(PlannerError, match=f"grip force LP failed \\(HiGHS status {status}: "):
        min_grip_force(_antipodal(), Friction(0.5, 0.0), WEIGHT)


def test_an_unsure_end_is_decided_by_the_interior_point_method(monkeypatch):
    """HiGHS's default can end 'model_status is Unknown' (scipy status 4); the interior-point
    method then decides: its optimum is the answer, not an error."""
    calls = []

    def lp(*a):
        method = a[-1]
        calls.append(method)
        if method == "highs":
            return SimpleNamespace(status=4, message="model_status is Unknown; primal_status is Infeasible", x=None)
        return SimpleNamespace(status=0, message="Optimization terminated successfully.", x=np.full(len(a[0]), 0.7))  # t = x[k] = 0.7

    monkeypatch.setattr(lp_backend, "highs_lp", lp)
    assert min_grip_force(_antipodal(), Friction(0.5, 0.0), WEIGHT) == pytest.approx(0.7)
    assert calls == ["highs", "highs-ipm"]


def test_the_recorded_unsure_grasp_is_infeasible_and_nnls_agrees():
    """A synthesized Allegro thumb-index-middle grasp on which HiGHS's default ended unsure
    (it crashed exp8's synthesis): inf, and a non-negative least-squares fit of the weight by
    the contact wrenches (another algorithm) leaves a residual, so no contact forces hold it."""
    import json
    from pathlib import Path

    from planner.closure import _finger_wrenches

    d = json.loads((Path(__file__).parent / "data" / "grip_lp_unsure.json").read_text())
    patches = {f: (np.array(v["points"]), np.array(v["normals"])) for f, v in d["patches"].items()}
    fr = Friction(**d["friction"])
    assert min_grip_force(patches, fr, d["load"]) == math.inf
    W, _ = _finger_wrenches(patches, Friction(fr.mu, fr.gamma, 16))
    load = np.asarray(d["load"])
    residual = scipy.optimize.nnls(W.T, -load / np.abs(load).max())[1]
    assert residual > 1e-3
