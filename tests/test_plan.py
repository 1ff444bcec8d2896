"""Plan export: schema, determinism, atomic writes and validation of plan files."""

import json

import numpy as np
import pytest
import yaml

from planner.model import Friction
from planner.closure import grasp_closure
from planner.errors import PlannerWarning, SpecError
from planner.plan import read_plan
from planner.plan_data import SCHEMA_VERSION, Alternative, Plan, PlanState, PlanStep, dumps_plan, write_plan

FRICTION = Friction(0.9, 0.003, 5)
PTS = np.array([[0.01, 0.0, 0.02], [0.011, 0.001, 0.02]])
NRM = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, -1.0]])


def _closure(patches):
    c = grasp_closure(patches, FRICTION)
    return bool(c.is_force_closure), float(c.metric)


def tiny_plan():
    """Two states (fingers a, b; then b lifted) whose recorded closures are their patches'."""
    both, one = {"a": (PTS, NRM), "b": (-PTS, -NRM)}, {"a": (PTS, NRM)}
    s0 = PlanState({"a": "initial", "b": "initial"}, both, *_closure(both), ("b",), (0.1, 0.2))
    s1 = PlanState({"a": "initial", "b": "lifted"}, one, *_closure(one), (), (0.1, 0.0))
    step = PlanStep("b", "lift", 0, 1, ("jb",), ((0.2,), (0.1,), (0.0,)))
    return Plan(
        hand={"name": "h", "spec": "robots/h/hand.yaml"},
        object={"shape": "box", "size": [0.03, 0.04, 0.05], "position": [0, 0, 0.05], "quat_xyzw": [0, 0, 0, 1]},
        friction={"mu": 0.9, "gamma": 0.003, "edges": 5},
        inputs={},
        parameters={"seed": 0},
        summary={"gait_steps": 1, "bottleneck_metric": np.float64(s0.metric)},
        joints=("ja", "jb"),
        states=(s0, s1),
        steps=(step,),
        alternatives=(Alternative(("b:lift",), -0.5, 1, 0.1),),
    )


def test_yaml_and_json_carry_the_documented_keys(tmp_path):
    """Both formats hold schema_version, states with patches/closure/removable/q, and steps."""
    for suffix in (".yaml", ".json"):
        path = write_plan(tiny_plan(), tmp_path / f"plan{suffix}")
        data = read_plan(path)
        assert data["schema_version"] == 3 and SCHEMA_VERSION == 4  # no repose step: written as schema 3
        s0 = data["states"][0]
        assert set(s0["patches"]) == {"a", "b"}
        assert len(s0["patches"]["a"]["points"]) == 2 and len(s0["patches"]["a"]["normals"][0]) == 3
        fc, metric = _closure({"a": (PTS, NRM), "b": (-PTS, -NRM)})
        assert s0["closure"] == {"is_force_closure": fc, "metric": pytest.approx(metric, rel=1e-9)}
        assert s0["removable"] == ["b"] and s0["q"] == {"ja": 0.1, "jb": 0.2}
        assert "b" not in data["states"][1]["patches"]
        assert data["steps"][0]["path"][0] == [0.2] and data["steps"][0]["path"][-1] == [0.0]
        assert data["alternatives"][0]["order"] == ["b:lift"]


def test_export_is_byte_identical_and_plain():
    """Same plan gives the same text; numpy scalars never leak into the file."""
    a, b = dumps_plan(tiny_plan()), dumps_plan(tiny_plan())
    assert a == b
    assert "numpy" not in a and "!!" not in a
    assert dumps_plan(tiny_plan(), "json") == dumps_plan(tiny_plan(), "json")
    json.loads(dumps_plan(tiny_plan(), "json"))


def test_unknown_suffix_is_refused_and_nothing_written(tmp_path):
    """A .txt plan path is an error naming the valid suffixes; no file appears."""
    with pytest.raises(SpecError, match=r"\.yaml"):
        write_plan(tiny_plan(), tmp_path / "plan.txt")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    "mutate, key",
    [
        (lambda d: d.pop("states"), "states"),
        (lambda d: d.update(schema_version=99), "schema_version"),
        (lambda d: d["states"][0]["q"].pop("ja"), "states[0].q"),
        (lambda d: d["steps"][0].update(action="jump"), "steps[0].action"),
        (lambda d: d["steps"][0].update(to_state=7), "steps[0].to_state"),
        (lambda d: d["states"][1]["patches"]["a"]["normals"].pop(), "states[1].patches.a"),
    ],
)
def test_read_plan_names_file_and_key(tmp_path, mutate, key):
    """A broken plan file gives a SpecError naming the file and the key path."""
    data = yaml.safe_load(dumps_plan(tiny_plan()))
    mutate(data)
    path = tmp_path / "broken.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(SpecError) as err:
        read_plan(path)
    assert str(path) in str(err.value) and key in str(err.value)


def test_malformed_yaml_is_a_spec_error(tmp_path):
    """Unparseable YAML is reported as such, with the file name."""
    path = tmp_path / "bad.yaml"
    path.write_text("states: [unclosed\n")
    with pytest.raises(SpecError, match="malformed YAML"):
        read_plan(path)


def test_grip_force_is_exported_per_state_and_null_without_gravity(tmp_path):
    """states[i].grip_force_n / grip_force_by_gravity_n and the alternatives' grip bottleneck
    are written (rounded like every float) when given and null otherwise; both formats."""
    plan = tiny_plan()
    s0, s1 = plan.states
    gripped = Plan(**{**plan.__dict__, "states": (
        PlanState(s0.fingers, s0.patches, True, s0.metric, s0.removable, s0.q, grip_force_n=0.123456789012345,
                  grip_force_by_gravity_n={"palm_down": 0.123456789012345, "palm_up": np.float64(0.1)}),
        s1,
    ), "alternatives": (Alternative(("b:lift",), -0.5, 1, 0.1, bottleneck_grip_force_n=0.7),)})
    for suffix in (".yaml", ".json"):
        data = read_plan(write_plan(gripped, tmp_path / f"g{suffix}"))
        assert data["states"][0]["grip_force_n"] == 0.123456789
        assert data["states"][0]["grip_force_by_gravity_n"] == {"palm_down": 0.123456789, "palm_up": 0.1}
        assert data["states"][1]["grip_force_n"] is None and data["states"][1]["grip_force_by_gravity_n"] is None
        assert data["alternatives"][0]["bottleneck_grip_force_n"] == 0.7
    plain = yaml.safe_load(dumps_plan(tiny_plan()))
    assert plain["states"][0]["grip_force_n"] is None and plain["alternatives"][0]["bottleneck_grip_force_n"] is None
    assert dumps_plan(gripped) == dumps_plan(gripped)


def test_plans_without_grip_keys_still_read_and_bad_grip_is_refused(tmp_path):
    """schema_version 1 files (no integrity record) written before grip_force_n existed read
    as null with a PlannerWarning; a negative or non-numeric grip force is a SpecError naming the key."""
    data = yaml.safe_load(dumps_plan(tiny_plan()))
    data["schema_version"] = 1
    del data["integrity"]
    for state in data["states"]:
        del state["grip_force_n"], state["grip_force_by_gravity_n"]
    old = tmp_path / "old.yaml"
    old.write_text(yaml.safe_dump(data))
    with pytest.warns(PlannerWarning, match="no integrity record"):
        assert read_plan(old).states[0].grip_force_n is None
    for bad in (-0.1, "strong", True):
        data["states"][1]["grip_force_n"] = bad
        path = tmp_path / "bad.yaml"
        path.write_text(yaml.safe_dump(data))
        with pytest.raises(SpecError, match=r"states\[1\]\.grip_force_n"):
            read_plan(path)
