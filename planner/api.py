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


def _known(kind: str, given, valid: set) -> None:
    """Every keyword in ``given`` is one of ``valid``, else `UnknownNameError` naming ``kind``
    and the valid ones (a misspelt keyword was a TypeError deep inside, or ignored)."""
    from planner.errors import UnknownNameError

    for k in given:
        if k not in valid:
            raise UnknownNameError(kind, k, valid)


def plan(initial, final, *, execution: bool = False, output: PathLike | None = None, verbose: bool = False,
         **options: Any):
    """Plan a finger-gaiting sequence between two grasps (``regrasp plan``).

    Args:
        initial, final: grasp files (paths), `planner.grasp.GraspSpec` or `RealizedGrasp`.
        execution: `PlanOptions.for_execution` (one contact per touching link, six gravity
            directions, the grip model, verified in a physics engine: ``engine="pybullet"``,
            ``"mujoco"`` or ``"both"``; default pybullet when installed, else MuJoCo) instead
            of the thesis's defaults.
        output: also write the plan there (``.yaml``/``.json``), atomically; it may not be a
            file the planner reads (the grasp files, their hand's files, the object's mesh).
        verbose: let OMPL log to the console.
        **options: any `planner.options.PlanOptions` field (e.g. ``time_limit_s=5``,
            ``motion=False``, ``verify=False``); ``gravity`` may be a name (``"palm_up"``,
            `planner.gravity.named_gravity`).

    Checks, cheapest first and before any planning: option names, the output's suffix, the
    two files (read, same hand, object, pose and friction), the output against every input
    file, the options' values, then the grasps are realized with every finger placed. Without a
    gravity (force closure only) a `PlannerWarning` says when an end grasp does not hold its
    own weight in some hand orientation (`planner.realization.weight_warning`).

    Returns:
        `planner.regrasp.PlanResult` (``.plan``, ``.sequence``, ``.alternatives``, ...).
    """
    from planner.fileio import as_path, check_outputs
    from planner.grasp import GraspSpec, grasp_files, input_record, load_grasp, load_hand
    from planner.options import PlanOptions
    from planner.plan_data import plan_format, write_plan
    from planner.realization import RealizedGrasp, realize
    from planner.regrasp import check_same_setup, plan_regrasp

    _known("plan option", options, {f.name for f in fields(PlanOptions)})
    if output is not None:
        plan_format(as_path(output, "output", "a plan file path (.yaml/.json)"))  # a bad suffix before any work
    grasps = [initial, final]
    for name, g in zip(("initial", "final"), grasps):
        if not isinstance(g, (GraspSpec, RealizedGrasp)):
            as_path(g, name, "a grasp file path, a GraspSpec or a RealizedGrasp")
    specs = [g.spec if isinstance(g, RealizedGrasp) else g if isinstance(g, GraspSpec) else load_grasp(g)
             for g in grasps]
    check_same_setup(*specs, pose=options.get("repose") is False)
    hand = grasps[0].hand if isinstance(grasps[0], RealizedGrasp) else load_hand(specs[0].hand_ref)
    paths = [g for g in grasps if isinstance(g, (str, os.PathLike))]  # the same hand and object in both
    check_outputs([(output, "-o")], paths + grasp_files(specs[0], hand))
    if isinstance(options.get("gravity"), str):  # a named orientation (planner.gravity.named_gravity)
        from planner.gravity import named_gravity

        options["gravity"] = named_gravity(options["gravity"], hand)
    opts = (PlanOptions.for_execution if execution else PlanOptions)(**options)
    # (no realization warnings are shown here: no reachable point is searched for them)
    a, b = (g if isinstance(g, RealizedGrasp) else realize(s, hand, suggest=False).require_placed()
            for g, s in zip(grasps, specs))
    if opts.gravity is None and opts.gravity_set is None:  # force closure only: say when an end grasp drops its object
        import warnings

        from planner.errors import PlannerWarning
        from planner.realization import weight_warning

        words = weight_warning({"initial": a, "final": b}, opts.contact_model)
        if words is not None:
            warnings.warn(words, PlannerWarning, stacklevel=2)
    inputs = {k: input_record(g) for k, g in (("initial", initial), ("final", final)) if isinstance(g, (str, os.PathLike))}
    result = plan_regrasp(a, b, opts, inputs, verbose=verbose)
    if output is not None:
        write_plan(result.plan, output)
    return result


def replay(plan, *, gravity_set: int | None = None, report: PathLike | None = None, engine: str | None = None,
           **kwargs: Any):
    """Execute a plan in a physics engine (``regrasp replay``), after the physics checks of `verify`.

    Args:
        plan: a plan file, a `planner.plan_data.Plan` or plan data.
        gravity_set: replay under 1, 2, 6 or 7 gravity directions (`planner.gravity`), in
            parallel processes (``workers=N``); None: one replay, palm down unless
            ``gravity=(gx, gy, gz)`` or a name (``"palm_up"``) is given.
        report: also write the replay's report (JSON) there, atomically.
        engine: "pybullet", "mujoco", "both" (each engine in turn; the films of each are
            ``FILE_<engine>.gif``) or None (`planner.sim.engine.default_engine`).
        **kwargs: `planner.sim.replay.replay_plan` keywords (``gif``, ``mp4``,
            ``drift_mm_max``, ...; with ``gravity_set``, ``film``: the directions filmed, a list
            or "palm_down,palm_up", and ``workers``); any other name is an `UnknownNameError`.

    Every file written (the report, the films, one per filmed direction of a gravity set:
    ``FILE_<direction>.gif``) is checked before anything is simulated: none may be a file
    the replay reads (the plan, its recorded grasps, its hand's files, the object's mesh)
    and no two may be the same.

    Returns:
        `ReplayReport` (one replay) or `GravitySetReport` (``gravity_set``); with ``engine="both"``
        a `planner.sim.verify.EnginesReport` of one of those per engine.
    """
    import inspect
    import json

    from planner.audit import require_sound
    from planner.fileio import check_format, check_outputs, write_atomic
    from planner.gravity import gravity_directions, named_gravity
    from planner.plan import plan_files, plan_from_data, read_plan
    from planner.plan_data import Plan
    from planner.sim.inputs import plan_hand
    from planner.sim.replay import replay_plan
    from planner.sim.verify import engine_path, engines_of, film_paths, in_engines, replay_gravity_set

    # (a misspelt keyword was a TypeError from replay_plan, after the plan was read and checked)
    _known("replay option", kwargs,
           {*inspect.signature(replay_plan).parameters, *inspect.signature(replay_gravity_set).parameters} - {"plan", "n"})
    if isinstance(kwargs.get("film"), str):  # "palm_down,palm_up", as --film
        kwargs["film"] = [d.strip() for d in kwargs["film"].split(",") if d.strip()]
    if not isinstance(plan, Plan):
        plan = plan_from_data(dict(plan)) if hasattr(plan, "keys") else read_plan(plan, strict=kwargs.get("strict", False))
    hand = kwargs.pop("hand", None) or plan_hand(plan)
    inputs = plan_files(plan, hand)
    # the names as given, then the names derived from them, may not be inputs; then a picture's
    # name as given must say its format (said of the name the user wrote); all before the
    # physics check (a large plan's takes a minute)
    given = [(report, "--report"), *((kwargs.get(k), "--" + k) for k in ("gif", "mp4"))]
    check_outputs(given, inputs, formats=False)
    if isinstance(kwargs.get("gravity"), str):  # a named orientation (planner.gravity.named_gravity)
        kwargs["gravity"] = named_gravity(kwargs["gravity"], hand)
    engines = engines_of(engine)  # (an engine not installed: one line, before any work)
    films = {e: {key: (engine_path(kwargs[key], e) if len(engines) > 1 else kwargs[key])
                 for key in ("gif", "mp4") if kwargs.get(key) is not None} for e in engines}
    outputs = [(report, "--report")]
    for e in engines:
        for key, path in films[e].items():
            if gravity_set is None:
                outputs.append((path, "--" + key))
            else:
                names = [n for n, _ in gravity_directions(hand.palm_normal, gravity_set)]
                outputs += [(p, "--" + key) for p in film_paths(path, names, kwargs.get("film"))]
    check_outputs(outputs, inputs, formats=False)
    for path, option in given:
        if path is not None:
            check_format(path, option)
    require_sound(plan, hand)
    results = []
    for e in engines:
        kw = {**kwargs, **films[e], "engine": e}
        if gravity_set is not None:
            results.append((e, replay_gravity_set(plan, gravity_set, hand=hand, **kw)))
        else:
            results.append((e, replay_plan(plan, hand=hand, **kw)))
    result = results[0][1] if len(results) == 1 else in_engines(results)
    if report is not None:
        write_atomic(report, json.dumps(result.to_dict(), indent=1) + "\n")
    return result


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
    `planner.audit.AuditReport` (``ok``, ``problems``). ``plan``: a plan file, a
    `planner.plan_data.Plan` or plan data (as `replay`)."""
    from planner.audit import audit_plan
    from planner.plan import plan_from_data

    return audit_plan(plan_from_data(dict(plan)) if hasattr(plan, "keys") else plan)


def synth(hand, object_block: dict, fingers, n: int = 1, *, fixed: bool = False, **kwargs: Any):
    """Synthesize force-closure grasps (``regrasp synth``): `planner.synthesis.synthesize`.

    Args:
        hand: a bundled hand's name or a hand.yaml path.
        object_block: the grasp file's ``object`` mapping (shape, size[, position, quat_xyzw, mass_kg]).
        fingers: finger names (a list or "thumb,index,middle").
        n: grasps wanted.
        fixed: keep the object's pose (else it is sampled too).
        kwargs: `planner.synthesis.synthesize`'s; ``verify`` defaults to True here, as ``regrasp
            synth``: the grasps execution mode's static test accepts are held in a physics engine.
    """
    import inspect

    from planner.errors import InputError
    from planner.fileio import describe
    from planner.grasp import resolve_hand_ref
    from planner.synthesis import synthesize

    _known("synth option", kwargs, set(inspect.signature(synthesize).parameters) - {"hand_ref", "obj", "fingers", "n", "fixed"})
    if not hasattr(object_block, "keys"):
        raise InputError(f"object_block: expected a grasp file's object mapping (shape, size[, position, quat_xyzw, "
                         f"mass_kg]), got {describe(object_block)}")
    if isinstance(fingers, str):
        names = [f.strip() for f in fingers.split(",")]
    elif isinstance(fingers, (list, tuple)) and all(isinstance(f, str) for f in fingers):
        names = list(fingers)
    else:
        raise InputError(f"fingers: expected finger names (a list or 'thumb,index,middle'), got {describe(fingers)}")
    kwargs.setdefault("verify", True)  # as regrasp synth: the accepted grasps held in a physics engine
    return synthesize(resolve_hand_ref(str(hand), Path.cwd()), dict(object_block), names, n, fixed=fixed, **kwargs)
