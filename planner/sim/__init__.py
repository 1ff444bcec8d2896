"""Physics replay of regrasp plans: the only package that imports pybullet.

`replay_plan` executes a plan with gravity on and re-measures contacts and force
closure from the simulator, through the physics seam `planner.sim.engine.PhysicsEngine`
(pybullet behind it: `planner.sim.engine_pybullet`); `ContactFilter` is the thesis's temporal
contact filter and `ReplayReport` / `StateReport` what a replay reports (pure numpy,
importable without pybullet, as are `planner.sim.engine` and `planner.sim.controller`).
"""

from planner.sim.contact_filter import ContactFilter, FilteredContact
from planner.sim.report import ReplayReport, StateReport

__all__ = ["ContactFilter", "FilteredContact", "ReplayReport", "StateReport", "replay_plan"]


def __getattr__(name):
    # pybullet is loaded only when the replay itself is used
    if name == "replay_plan":
        from planner.sim import replay

        return getattr(replay, name)
    raise AttributeError(f"module 'planner.sim' has no attribute {name!r}")
