"""One object model (`planner.objects.SIZE_LENGTHS`): grasp files, plan files and `make_object`
accept the same shapes and the same numbers of size entries."""

import sys
from pathlib import Path

import pytest
import yaml

from planner.errors import InputError, SpecError, UnknownNameError
from planner.grasp import parse_grasp
from planner.objects import SHAPES, SIZE_LENGTHS, make_object
from planner.plan import plan_from_data

ROOT = Path(__file__).resolve().parents[1]
MESH = ROOT / "grasps/meshes/rounded_box.obj"
GRASP = ROOT / "grasps/icub/box_ir2m.yaml"
COUNTS = (1, 2, 3, 4)


def _object(shape: str, n: int) -> dict:
    o = {"shape": shape, "size": [0.02] * n, "position": [0.03, 0.0, 0.025], "quat_xyzw": [0, 0, 0, 1], "mass_kg": 0.04}
    if shape == "mesh":
        o["mesh"], o["size"] = str(MESH), [1.0] * n
    return o


def _size_refused(read) -> bool:
    """True when `read` refuses object.size; other complaints (e.g. a contact off the new surface) are not ours."""
    try:
        read()
    except SpecError as err:
        return err.key == "object.size"
    except InputError as err:
        return "size must be" in str(err)
    return False


def test_shapes_are_the_table_and_unknown_ones_are_refused_by_every_reader():
    """The shape list is the table's keys; a 'cone' is refused by all three readers naming the shapes."""
    assert SHAPES == tuple(SIZE_LENGTHS) == ("box", "cylinder", "sphere", "mesh")
    with pytest.raises(UnknownNameError, match="box, cylinder, mesh, sphere|box, cylinder, sphere, mesh"):
        make_object("cone", [0.1])
    data = yaml.safe_load(GRASP.read_text())
    data["object"] = {**_object("box", 3), "shape": "cone"}
    with pytest.raises(SpecError, match="shapes are box, cylinder, sphere, mesh"):
        parse_grasp(data, GRASP)
    sys.path.insert(0, str(Path(__file__).parent))
    from test_plan import tiny_plan

    plan = tiny_plan().to_dict()
    plan["object"] = {**_object("box", 3), "shape": "cone"}
    with pytest.raises(SpecError, match="shapes are box, cylinder, sphere, mesh"):
        plan_from_data(plan)


@pytest.mark.parametrize("shape", SHAPES)
def test_every_reader_accepts_exactly_the_tables_size_counts(shape):
    """For 1-4 size entries, the grasp reader, the plan reader and make_object refuse
    object.size exactly when the count is not in SIZE_LENGTHS (a mesh: 1 or 3, never 2)."""
    sys.path.insert(0, str(Path(__file__).parent))
    from test_plan import tiny_plan

    for n in COUNTS:
        expected = n not in SIZE_LENGTHS[shape]
        o = _object(shape, n)
        grasp = yaml.safe_load(GRASP.read_text())
        grasp["object"] = o
        plan = tiny_plan().to_dict()
        plan["object"] = o
        refused = {
            "grasp": _size_refused(lambda: parse_grasp(grasp, GRASP)),
            "plan": _size_refused(lambda: plan_from_data(plan)),
            "make_object": _size_refused(lambda: make_object(shape, o["size"], mesh_path=o.get("mesh"))),
        }
        assert refused == dict.fromkeys(refused, expected), (shape, n)
