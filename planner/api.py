"""The one-call API: each command of ``regrasp`` as one function taking paths or loaded objects.

    import planner
    result = planner.plan("initial.yaml", "final.yaml", execution=True, output="plan.yaml")
    report = planner.replay("plan.yaml", gravity_set=6)
    grasp = planner.check("initial.yaml")
    audit = planner.verify("plan.yaml")

Every function raises a `planner.errors.PlannerError` (one line) on bad input, as the CLI
reports it.
"""

from __future__ import annotations

import os
from dataclasses import fields
from pathlib import Path
from typing import Any

# The facade's imports are inside its functions on purpose: each function imports what its
# command runs when it runs, so `import planner` (which re-exports these functions) stays light.

PathLike = str | os.PathLike


def plan(initial, final, *, execution: bool = False, output: PathLike | None = None, **options: Any):
    """Plan a finger-gaiting sequence between two grasps (``regrasp plan``).

    Args:
        initial, final: grasp files (paths), `planner.grasp.GraspSpec` or `RealizedGrasp`.
        execution: `PlanOptions.for_execution` (one contact per touching link, six gravity
            directions, the grip model, verified in pybullet) instead of the thesis's defaults.
        output: also write the plan there (``.yaml``/``.json``), atomically.
        **options: any `planner.options.PlanOptions` field (e.g. ``time_limit_s=5``,
            ``motion=False``, ``verify=False``); ``gravity`` may be a name (``"palm_up"``,
            `planner.gravity.named_gravity`).

    Returns:
        `planner.regrasp.PlanResult` (``.plan``, ``.sequence``, ``.alternatives``, ...).
    """
    from planner.errors import UnknownNameError
    from planner.options import PlanOptions
    from planner.plan_data import plan_format, write_plan
    from planner.realization import realized_grasp
    from planner.regrasp import check_same_setup, plan_regrasp

    valid = {f.name for f in fields(PlanOptions)}
    for k in options:
        if k not in valid:
            raise UnknownNameError("plan option", k, valid)
    if output is not None:
        plan_format(output)  # a bad suffix before any work
    a, rec_a = realized_grasp(initial)
    b, rec_b = realized_grasp(final)
    check_same_setup(a.spec, b.spec)
    if isinstance(options.get("gravity"), str):  # a named orientation (planner.gravity.named_gravity)
        from planner.gravity import named_gravity

        options["gravity"] = named_gravity(options["gravity"], a.hand)
    opts = (PlanOptions.for_execution if execution else PlanOptions)(**options)
    inputs = {k: v for k, v in (("initial", rec_a), ("final", rec_b)) if v is not None}
    result = plan_regrasp(a, b, opts, inputs)
    if output is not None:
        write_plan(result.plan, output)
    return result


def replay(plan, *, gravity_set: int | None = None, **kwargs: Any):
    """Execute a plan in pybullet (``regrasp replay``), after the physics checks of `verify`.

    Args:
        plan: a plan file, a `planner.plan_data.Plan` or plan data.
        gravity_set: replay under 1, 2, 6 or 7 gravity directions (`planner.gravity`), in
            parallel processes (``workers=N``); None: one replay, palm down unless
            ``gravity=(gx, gy, gz)`` is given.
        **kwargs: `planner.sim.replay.replay_plan` keywords (``gif``, ``drift_mm_max``, ...).

    Returns:
        `ReplayReport` (one replay) or `GravitySetReport` (``gravity_set``).
    """
    from planner.audit import require_sound
    from planner.plan import plan_from_data, read_plan
    from planner.plan_data import Plan
    from planner.sim.replay import replay_plan
    from planner.sim.verify import replay_gravity_set

    if not isinstance(plan, Plan):
        plan = plan_from_data(dict(plan)) if hasattr(plan, "keys") else read_plan(plan, strict=kwargs.get("strict", False))
    require_sound(plan)
    if gravity_set is not None:
        return replay_gravity_set(plan, gravity_set, **kwargs)
    return replay_plan(plan, **kwargs)


def check(grasp):
    """Realize one grasp (``regrasp check``): `RealizedGrasp` with its contacts, closure,
    ``problems`` (why it is not what the file asks) and ``warnings``. ``grasp``: a grasp
    file, a `GraspSpec` or a `RealizedGrasp` (returned as it is)."""
    from planner.grasp import GraspSpec, load_grasp
    from planner.realization import RealizedGrasp, realize

    if isinstance(grasp, RealizedGrasp):
        return grasp
    return realize(grasp if isinstance(grasp, GraspSpec) else load_grasp(grasp))


def verify(plan):
    """Check a plan against physics and its inputs without simulation (``regrasp verify``):
    `planner.audit.AuditReport` (``ok``, ``problems``)."""
    from planner.audit import audit_plan

    return audit_plan(plan)


def synth(hand, object_block: dict, fingers, n: int = 1, *, fixed: bool = False, **kwargs: Any):
    """Synthesize force-closure grasps (``regrasp synth``): `planner.synthesis.synthesize`.

    Args:
        hand: a bundled hand's name or a hand.yaml path.
        object_block: the grasp file's ``object`` mapping (shape, size[, position, quat_xyzw, mass_kg]).
        fingers: finger names (a list or "thumb,index,middle").
        n: grasps wanted.
        fixed: keep the object's pose (else it is sampled too).
    """
    from planner.grasp import resolve_hand_ref
    from planner.synthesis import synthesize

    names = [f.strip() for f in fingers.split(",")] if isinstance(fingers, str) else list(fingers)
    return synthesize(resolve_hand_ref(str(hand), Path.cwd()), dict(object_block), names, n, fixed=fixed, **kwargs)
