"""Test-wide markers for the engines a Python has.

pybullet publishes wheels up to Python 3.11 only; on 3.12 and 3.13 the package runs with MuJoCo
(`planner.sim.engine.default_engine`). A test of something only pybullet does (pictures, its
loader, its engine class) carries ``@pytest.mark.needs_pybullet("what")`` and is skipped, with
that reason, where pybullet is not installed; a replay or verification test without the marker
runs in the default engine, so on 3.13 it exercises MuJoCo. The replay tests MuJoCo does not
pass yet are listed in `MUJOCO_GAPS` (test id prefix -> what fails, measured on Python 3.13):
skipped, with that reason, where the default engine is MuJoCo; remove a line when it passes.
"""

import importlib.util

import pytest

HAVE_PYBULLET = importlib.util.find_spec("pybullet") is not None

_SIM = "tests/test_sim.py::"
_PAIRS = _SIM + "test_other_bundled_pairs_hold_in_execution_mode["
#: Replay tests MuJoCo fails (plans verified in MuJoCo, or replayed there): id prefix -> why.
MUJOCO_GAPS = {
    _SIM + "test_safe_lift_of_index_passes":
        "the box held by thumb, index, middle turns 9.8 deg (limit 5) when the index lifts",
    _SIM + "test_library_plan_holds_and_agrees_at_every_state[box_":
        "no box PE -> IR2M sequence holds palm up in MuJoCo (6 verification attempts: lift index, "
        "little, ring turn the box 5-22 deg)",
    **{_PAIRS + f"{d}-mesh]": "no rounded-box mesh sequence holds palm up in MuJoCo (6 verification attempts)"
       for d in ("palm_down", "palm_up", "off")},
    **{_PAIRS + f"{d}-allegro_box]": "no Allegro box sequence holds side_+y in MuJoCo (4 sequences: the box "
                                     "turns 28-52 deg when the index lifts or moves)"
       for d in ("palm_down", "palm_up", "off")},
}


def pytest_configure(config):
    config.addinivalue_line("markers", "needs_pybullet(why): skipped where pybullet is not installed (Python >= 3.12)")


def pytest_collection_modifyitems(config, items):
    if HAVE_PYBULLET:  # the default engine (planner.sim.engine.default_engine) is pybullet
        return
    for item in items:
        mark = item.get_closest_marker("needs_pybullet")
        if mark is not None:
            why = mark.args[0] if mark.args else "a pybullet-only check"
            item.add_marker(pytest.mark.skip(reason=f"needs pybullet (not installed; no wheel for Python >= 3.12): {why}"))
        gap = next((why for prefix, why in MUJOCO_GAPS.items() if item.nodeid.startswith(prefix)), None)
        if gap is not None:
            item.add_marker(pytest.mark.skip(reason=f"the default engine is MuJoCo, which does not pass it yet: {gap}"))
