"""Test-wide markers for the engines a Python has.

pybullet publishes wheels up to Python 3.11 only; on 3.12 and 3.13 the package runs with MuJoCo
(`planner.sim.engine.default_engine`). A test of something only pybullet does (pictures, its
loader, its engine class) carries ``@pytest.mark.needs_pybullet("what")`` and is skipped, with
that reason, where pybullet is not installed; a replay or verification test without the marker
runs in the default engine, so on 3.13 it exercises MuJoCo. A replay test that MuJoCo does not
pass yet carries ``@pytest.mark.mujoco_fails("what is missing")``: skipped, with that reason,
where the default engine is MuJoCo.
"""

import importlib.util

import pytest

HAVE_PYBULLET = importlib.util.find_spec("pybullet") is not None


def pytest_configure(config):
    config.addinivalue_line("markers", "needs_pybullet(why): skipped where pybullet is not installed (Python >= 3.12)")
    config.addinivalue_line("markers", "mujoco_fails(why): a replay MuJoCo does not pass yet; skipped where it is the "
                                       "default engine")


def pytest_collection_modifyitems(config, items):
    if HAVE_PYBULLET:
        return
    for item in items:
        mark = item.get_closest_marker("needs_pybullet")
        if mark is not None:
            why = mark.args[0] if mark.args else "a pybullet-only check"
            item.add_marker(pytest.mark.skip(reason=f"needs pybullet (not installed; no wheel for Python >= 3.12): {why}"))
        mark = item.get_closest_marker("mujoco_fails")
        if mark is not None:
            item.add_marker(pytest.mark.skip(reason=f"the default engine is MuJoCo, which does not pass it yet: {mark.args[0]}"))
