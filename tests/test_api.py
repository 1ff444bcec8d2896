"""The one-call API (planner.api): the obvious calls work with paths and with loaded objects,
give what the CLI gives, and refuse bad options in one line."""

from __future__ import annotations

import pytest

import planner
from planner.errors import PlannerError, UnknownNameError
from planner.resources import bundled_grasp

A, B = bundled_grasp("icub/box_ir2m.yaml"), bundled_grasp("icub/box_parallel_extension.yaml")


@pytest.fixture(scope="module")
def planned(tmp_path_factory):
    out = tmp_path_factory.mktemp("api") / "plan.yaml"
    return planner.plan(str(A), str(B), motion=False, output=out), out


def test_plan_takes_paths_writes_and_records_the_inputs(planned):
    result, out = planned
    assert result.sequence.gait_steps >= 1
    assert set(result.plan.inputs) == {"initial", "final"}
    again = planner.plan.read_plan(out)  # planner.plan is also the plan-file module
    assert again.to_dict() == result.plan.to_dict()
    assert "plan" in planner.__all__ and callable(planner.plan)


def test_plan_regrasp_accepts_paths_and_gives_the_same_plan(planned):
    result, _ = planned
    direct = planner.plan_regrasp(str(A), str(B), planner.PlanOptions(motion=False))
    assert direct.plan.to_dict()["states"] == result.plan.to_dict()["states"]
    # loaded objects give the same states (the inputs are not recorded then)
    a, b = planner.check(A), planner.check(B)
    assert planner.plan(a, b, motion=False).plan.to_dict()["states"] == result.plan.to_dict()["states"]


def test_verify_and_replay_of_the_written_plan(planned):
    _, out = planned
    audit = planner.verify(out)
    assert audit.ok and audit.checked["steps"] >= 2
    report = planner.replay(out)
    assert report.passed, report.verdict


def test_bad_options_are_planner_errors_naming_the_choices():
    with pytest.raises(UnknownNameError, match="unknown plan option 'bogus'.*time_limit_s"):
        planner.plan(str(A), str(B), bogus=1)
    with pytest.raises(PlannerError):
        planner.plan(str(A), str(B), output="plan.txt")  # bad suffix, before any work


def test_check_realizes_a_grasp_file():
    g = planner.check(A)
    assert g.closure.is_force_closure and not g.problems
    assert planner.check(g) is g
