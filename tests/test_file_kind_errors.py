"""A grasp file given where a plan goes (verify, replay) and a plan file given where a grasp
goes (check, plan) are named for what they are: they were refused with the first key that
did not fit ('joints: missing key', "kind: unknown key 'kind'")."""

import pytest

from planner.cli import main
from planner.resources import bundled_grasp

INITIAL, FINAL = bundled_grasp("icub/box_parallel_extension.yaml"), bundled_grasp("icub/box_ir2m.yaml")


@pytest.fixture(scope="module")
def plan_yaml(tmp_path_factory):
    path = tmp_path_factory.mktemp("kinds") / "plan.yaml"
    assert main(["plan", str(INITIAL), str(FINAL), "--no-motion", "-q", "-o", str(path)]) == 0
    return path


@pytest.mark.parametrize("command", ["verify", "replay"])
def test_a_grasp_file_where_a_plan_goes(command, capsys):
    assert main([command, str(FINAL), "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is a grasp file (it has fingers:), not a plan" in err[0], err


@pytest.mark.parametrize("command", ["check", "plan"])
def test_a_plan_file_where_a_grasp_goes(command, plan_yaml, tmp_path, capsys):
    args = [str(plan_yaml)] if command == "check" else [str(plan_yaml), str(FINAL), "-o", str(tmp_path / "p.yaml")]
    assert main([command, *args, "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "kind: is a plan file (kind: regrasp-plan), not a grasp file" in err[0], err
    assert not (tmp_path / "p.yaml").exists()
