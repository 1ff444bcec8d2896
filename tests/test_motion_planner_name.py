"""An unknown --motion-planner is refused with or without motion: with --no-motion it was
accepted (exit 0) and the plan recorded `motion_planner: foo`."""

import pytest

from planner.cli import main
from planner.errors import UnknownNameError
from planner.options import MOTION_PLANNER_CLASSES, PlanOptions
from planner.resources import bundled_grasp


def test_plan_options_refuse_an_unknown_motion_planner_without_motion():
    with pytest.raises(UnknownNameError, match="unknown motion planner 'foo'; .*rrtconnect"):
        PlanOptions(motion=False, motion_planner="foo")
    assert PlanOptions(motion=False, motion_planner="rrt").motion_planner == "rrt"
    assert "rrtconnect" in MOTION_PLANNER_CLASSES


def test_the_cli_exits_2_and_writes_nothing(tmp_path, capsys):
    out = tmp_path / "plan.yaml"
    code = main(["plan", str(bundled_grasp("icub/box_parallel_extension.yaml")), str(bundled_grasp("icub/box_ir2m.yaml")),
                 "--no-motion", "--motion-planner", "foo", "-o", str(out), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "motion planner 'foo'" in err[0]
    assert not out.exists()
