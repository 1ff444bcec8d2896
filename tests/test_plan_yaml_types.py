"""A YAML plan may hold only what its JSON form holds (the digest is that JSON's): a date,
binary or set value, or a key that is not a string, in a part no other check reads (summary,
parameters) reached the digest as a TypeError traceback (exit 1). Now one line naming the
key, exit 2."""

import pytest

from planner.cli import main
from planner.resources import bundled_grasp


@pytest.fixture(scope="module")
def plan_text(tmp_path_factory):
    plan = tmp_path_factory.mktemp("types") / "plan.yaml"
    assert main(["plan", str(bundled_grasp("icub/box_parallel_extension.yaml")), str(bundled_grasp("icub/box_ir2m.yaml")),
                 "--no-motion", "-q", "-o", str(plan)]) == 0
    return plan.read_text()


@pytest.mark.parametrize("entry, words", [
    ("when: 2001-01-01", "summary.when: expected a string, number, true/false or null"),
    ("blob: !!binary aGVsbG8=", "summary.blob: expected a string, number"),
    ("s: !!set {a, b}", "summary.s: expected"),
    ("7: x", "summary: keys must be strings (the plan's JSON form), got int 7"),
    ("null: x", "summary: keys must be strings (the plan's JSON form), got null"),
])
@pytest.mark.parametrize("command", ["verify", "replay"])
def test_non_json_values_in_a_yaml_plan(plan_text, tmp_path, capsys, entry, words, command):
    assert "\nsummary:\n" in plan_text
    plan = tmp_path / "plan.yaml"
    plan.write_text(plan_text.replace("\nsummary:\n", f"\nsummary:\n  {entry}\n", 1))
    assert main([command, str(plan), "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0], err
