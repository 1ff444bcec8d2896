"""A YAML alias inside the value it names (a recursive structure) is refused when the file is
read, naming the file and the line: in a plan's summary or parameters it reached the digest
(json.dumps: 'ValueError: Circular reference detected', a traceback, exit 1)."""

import pytest

from planner.cli import main
from planner.errors import SpecError
from planner.fileio import load_yaml
from planner.resources import bundled_grasp


@pytest.mark.parametrize("text", [
    "a: &s\n  self: *s\n",
    "a: &l [1, *l]\n",
    "a: &m {b: {c: *m}}\n",
])
def test_a_recursive_alias_is_malformed_yaml(text):
    with pytest.raises(SpecError, match=r"recursive structure \(line \d+\)"):
        load_yaml(text, "f.yaml", "plan")


def test_a_shared_alias_is_still_read():
    data = load_yaml("a: &x {b: 1}\nc: *x\nd: *x\n", "f.yaml", "plan")
    assert data["c"] == data["d"] == {"b": 1}


def test_verify_a_plan_whose_summary_contains_itself(tmp_path, capsys):
    plan = tmp_path / "plan.yaml"
    assert main(["plan", str(bundled_grasp("icub/box_parallel_extension.yaml")), str(bundled_grasp("icub/box_ir2m.yaml")),
                 "--no-motion", "-q", "-o", str(plan)]) == 0
    text = plan.read_text()
    assert "\nsummary:\n" in text
    plan.write_text(text.replace("\nsummary:\n", "\nsummary: &s\n  self: *s\n", 1))
    capsys.readouterr()
    assert main(["verify", str(plan), "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "recursive structure" in err[0], err
