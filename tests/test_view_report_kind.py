"""`view PLAN --report FILE` refuses a FILE that is not a replay report even when it has as
many states as the plan: a plan file given as the report (the same plan, say) was accepted
(exit 0) and the page showed its states as not reached by the simulator."""

import json

import pytest

from planner.cli import main
from planner.errors import SpecError
from planner.resources import bundled_grasp
from planner.view import write_view


@pytest.fixture(scope="module")
def plan_json(tmp_path_factory):
    path = tmp_path_factory.mktemp("vk") / "plan.json"
    assert main(["plan", str(bundled_grasp("icub/box_parallel_extension.yaml")), str(bundled_grasp("icub/box_ir2m.yaml")),
                 "--no-motion", "-q", "-o", str(path)]) == 0
    return path


def test_a_plan_given_as_the_report_is_refused(plan_json, tmp_path, capsys):
    out = tmp_path / "p.html"
    assert main(["view", str(plan_json), "-o", str(out), "--report", str(plan_json), "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is a plan file, not a replay report" in err[0] and not out.exists()


def test_states_without_the_simulator_s_fields_are_refused(plan_json, tmp_path):
    data = json.loads(plan_json.read_text())
    data.pop("kind")
    report = tmp_path / "r.json"
    report.write_text(json.dumps(data))
    with pytest.raises(SpecError, match="not a replay report") as err:
        write_view(plan_json, tmp_path / "p.html", report=report)
    assert err.value.key == "replay.states"
    states = [{"reached": True} for _ in data["states"]]
    report.write_text(json.dumps({"passed": True, "verdict": "PASS", "states": states}))
    write_view(plan_json, tmp_path / "p.html", report=report)
    assert (tmp_path / "p.html").is_file()
