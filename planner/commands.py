"""The commands of `regrasp` (`planner.cli`): one ``cmd_<name>(args) -> exit code`` each.

`planner.cli` parses and validates the arguments, then calls one of these; its ``main``
turns a `PlannerError` into one line and an exit code. The modules a command needs beyond
the light ones imported here are imported inside it, each marked with why: scipy,
networkx, the kinematics and collision back ends (pinocchio, coal), OMPL and pybullet load
only for the command that uses them, so ``regrasp --help`` and argument errors stay fast
and ``regrasp check`` loads neither pybullet nor OMPL. ``regrasp demo`` runs other commands
through ``main`` and lives in `planner.cli`.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import sys
import time
from pathlib import Path

import yaml

from planner import handtool
from planner.errors import NoSequenceError, PlannerError
from planner.fileio import check_outputs, write_atomic

#: `verify` says what it is checking first when a plan has more path waypoints than this (about
#: 1 ms each: a plan of 2,701 states took 69.5 s with nothing printed).
LARGE_PLAN_WAYPOINTS = 10_000


def _gravity_line(name: str, g, hand_name: str) -> str:
    """The line saying what a named ``--gravity`` resolved to."""
    label = "gravity" if name == "gravity" else f"gravity {name}"  # "gravity": 3 numbers
    return f"{label}: [{' '.join(f'{v:+.3f}' for v in g)}] m/s^2 in the palm frame of {hand_name}"


def cmd_plan(args: argparse.Namespace) -> int:
    """Plan (`planner.api.plan`, which checks and writes) and print the steps and summary."""
    from planner.api import plan as plan_api  # deferred: scipy, networkx, pinocchio, coal; OMPL when planning

    # the options of the verification in a physics engine, which --execution alone runs: given
    # without it (or with --no-verify), they were ignored and the plan silently not verified
    unused = [option for option, given in (("--verify-attempts", args.verify_attempts is not None),
                                           ("--engine", args.engine is not None)) if given]
    if not args.execution and (unused or args.no_verify):
        raise PlannerError(f"{', '.join(unused + ['--no-verify'] * args.no_verify)}: only with --execution (the plan is "
                           "verified in a physics engine in execution mode alone); add --execution or leave it out")
    if args.no_verify and unused:
        raise PlannerError(f"{', '.join(unused)} and --no-verify exclude each other: --no-verify replays nothing")
    t0 = time.perf_counter()
    gname = args.gravity if isinstance(args.gravity, str) else None  # a name: the grasps' hand resolves it
    chosen = dict(contact_model=args.contact_model, rank=args.rank, gravity_set=args.gravity_set,
                  gravity=gname or (tuple(args.gravity) if args.gravity is not None else None))
    if not args.execution:  # the thesis's defaults; --execution brings its own (PlanOptions.for_execution)
        # ('' is not the default: --contact-model '' planned with patch, --rank '' with metric)
        chosen.update(contact_model="patch" if args.contact_model is None else args.contact_model,
                      rank="metric" if args.rank is None else args.rank)
    result = plan_api(
        args.initial, args.final, execution=args.execution, output=args.output, verbose=args.verbose,
        strategy=args.strategy,
        alternatives=args.alternatives,
        intermediate=args.intermediate,
        seed=args.seed,
        motion=not args.no_motion,
        motion_planner=args.motion_planner,
        motion_checks=args.motion_checks,
        max_lifted=args.max_lifted,
        max_finger_force_n=args.max_finger_force,
        time_limit_s=args.time_limit,
        max_rounds=args.max_rounds,
        **({"verify": False} if args.no_verify else {}),
        **({"repose": False} if args.no_repose else {}),
        **({"verify_attempts": args.verify_attempts} if args.verify_attempts is not None else {}),
        **({"engine": args.engine} if args.engine is not None else {}),
        **chosen,
    )
    plan = result.plan  # written by plan_api before anything is printed: a closed pipe (| head) cannot lose it
    if gname is not None:
        print(_gravity_line(gname, plan.parameters["gravity"], plan.hand["name"]))
    gripped = plan.states[0].grip_force_n is not None
    print(f"{'step':>4}  {'finger':<8} {'action':<5} {'state':>5}  {'metric':>10}  " + ("grip N  " if gripped else "") + "removable")
    for i, step in enumerate(plan.steps):
        st = plan.states[step.to_state]
        grip = f"{st.grip_force_n:>6.3f}  " if gripped else ""
        # a lifted or free finger is trivially removable: the column lists the touching ones
        removable = [f for f in st.removable if f in st.patches]
        print(f"{i:>4}  {step.finger:<8} {step.action:<5} {step.to_state:>5}  {st.metric:>10.4g}  {grip}{','.join(removable) or '-'}")
    s = plan.summary
    for rank, alt in enumerate(result.alternatives, start=2):
        grip = f", grip {alt.bottleneck_grip:.3f} N" if alt.bottleneck_grip is not None else ""
        print(f"alternative {rank}: bottleneck {alt.bottleneck:.4g}{grip}, {alt.gait_steps} gait steps: "
              f"{' '.join(alt.order(result.graph.graph['problem']))}")
    print(
        f"{s['strategy']}: {s['gait_steps']} gait steps ({len(plan.steps)} motions), bottleneck metric "
        f"{s['bottleneck_metric']:.4g}"
        + (f", largest grip {s['bottleneck_grip_force_n']:.3f} N" if s["bottleneck_grip_force_n"] is not None else "")
        + f" (ranked by {s['rank']}), graph {s['graph_nodes']} states / {s['graph_edges']} edges "
        f"({s['blocked_states']} blocked), {time.perf_counter() - t0:.2f} s"
        + (f", written to {args.output}" if args.output else "")
    )
    moved = s.get("reposing")
    if moved:
        print(f"reposing: the hand moves the object in {moved['moves']} step(s), {moved['object_path_mm']:g} mm / "
              f"{moved['object_path_deg']:g} deg along its path, the gaits at "
              f"[{', '.join(f'{v:.4f}' for v in moved['pose'][:3])}] (palm frame)")
    check = s.get("verification")
    if check is not None:
        shown = {"gravity": gname} if gname is not None else {}  # a named --gravity by its name
        names = ", ".join(shown.get(d, d) for d in check["directions"])
        from planner.sim.engine import default_engine  # the engine plan's verification replayed in

        engines = {"both": "pybullet and mujoco"}.get(check.get("engine"), check.get("engine") or default_engine())
        print(f"verified in {engines}: held in {len(check['directions'])} gravity directions ({names}), "
              f"{check['attempts']} sequence(s) replayed in {result.verify_s:.1f} s"
              + (f" ({len(check['rejected'])} rejected: " + "; ".join(f"{shown.get(r['direction'], r['direction'])} "
                                                                    f"at step {r['step']}"
                                                                    for r in check['rejected']) + ")"
                 if check["rejected"] else "") + "; --no-verify skips it")
    return 0


def cmd_check(args: argparse.Namespace) -> int:
    """Realize one grasp, print the report (text or JSON), draw it (``--png``); exit 0 force
    closure and as written (no `RealizedGrasp.problems`), 1 not, 2 bad input. With
    ``--execution`` also 1 unless ``plan --execution`` accepts it as an end grasp: its static
    test (`planner.realization.execution_verdict`: the execution contact model, the hold
    factor in the six directions it plans for), then the grasp held in a physics engine as the
    plan's end grasps are (`_simulator_hold`; ``--no-verify`` skips it, ``--engine``); with
    ``--gravity`` (3 numbers, "gravity"; or a name) the same under that gravity alone, as
    ``plan --execution --gravity``."""
    from planner.grasp import grasp_files, load_grasp  # deferred: objects, the hand: pinocchio, coal (~0.1 s)
    from planner.grasp_report import check_text, contact_markers  # deferred: scipy (~0.2 s)
    from planner.realization import execution_verdict, realize  # deferred: closure, contacts: scipy (~0.05 s more)

    strict = args.execution or args.gravity is not None
    if not strict and (args.no_verify or args.engine is not None):
        raise PlannerError(f"{'--no-verify' if args.no_verify else '--engine'}: only with --execution or --gravity "
                           "(the grasp is held in a physics engine for execution mode alone); add one or leave it out")
    if args.no_verify and args.engine is not None:
        raise PlannerError("--engine and --no-verify exclude each other: --no-verify replays nothing")
    if strict and not args.no_verify:  # (an engine not installed: refused whatever the static test says, as plan does)
        from planner.sim.verify import engines_of

        engines_of(args.engine)
    spec = load_grasp(args.grasp)
    # the picture may not be a file the check reads (the grasp, its hand's files, the mesh)
    check_outputs([(args.png, "--png")], grasp_files(spec, path=args.grasp))
    grasp = realize(spec)
    gline = gdata = None
    if args.gravity is not None:
        from planner.gravity import named_gravity

        name = args.gravity if isinstance(args.gravity, str) else "gravity"
        g = named_gravity(name, grasp.hand) if isinstance(args.gravity, str) else tuple(float(v) for v in args.gravity)
        verdict = execution_verdict(grasp, g, name)
        gline, gdata = _gravity_line(name, g, grasp.hand.name), {"name": name, "vector": list(g)}
    else:
        g, name, verdict = None, None, execution_verdict(grasp)
    sim = None
    if strict and not args.no_verify and grasp.ok and verdict.ok:
        sim = _simulator_hold(grasp, g, name, args.engine)
    passes = grasp.ok and (verdict.ok and (sim is None or sim["held"]) or not strict)
    if args.png:
        from planner.sim.render import render_png  # deferred: pybullet, only with --png

        render_png(grasp.hand, grasp.q, grasp.obj, args.png, markers=contact_markers(grasp))
    if args.json:
        data = grasp.summary(list(verdict.hold), verdict)
        data["execution"]["required"] = strict
        data["execution"]["simulator"] = sim
        data["passes"] = passes
        if gdata is not None:
            data["gravity"] = gdata
        print(json.dumps(data, indent=1))
    else:
        from planner.gravity import gravity_label_of

        label = gravity_label_of(args.gravity, args.gravity if isinstance(args.gravity, str) else None)
        text = check_text(grasp, verdict, strict, sim, "" if label is None else f" --gravity {label}")
        if gline is not None:  # before the verdict, the report's last line
            head, _, last = text.rpartition("\n")
            text = f"{head}\n{gline}\n{last}"
        print(text)
        if args.png:
            print(f"picture written to {args.png} (contacts: dots with their inward normals; green ok, orange "
                  "warning, red problem)")
    return 0 if passes else 1


def _simulator_hold(grasp, gravity, name: str | None, engine: str | None) -> dict:
    """The grasp held in a physics engine as ``plan --execution``'s verification replays an
    initial grasp (`planner.regrasp.end_grasp_replay`), as plain data (``check --json``'s
    ``execution.simulator``): the engine, whether it held, the directions replayed (in order;
    ``gravity`` as ``name``, the --gravity given) and the failing one's verdict, the replays'
    wall time."""
    from planner.regrasp import end_grasp_replay  # deferred: the physics engine

    try:
        v = end_grasp_replay(grasp, gravity, engine=engine)
    except NoSequenceError as err:  # the one-state plan refused before any replay (its static test passed)
        from planner.sim.engine import default_engine

        return {"engine": engine or default_engine(), "held": False, "directions": [], "failure": {"direction": None, "verdict": str(err)},
                "wall_s": 0.0}
    failure = v.first_failure()
    shown = {"gravity": name} if name else {}
    return {"engine": v.engine_names, "held": v.passed, "directions": [shown.get(d[0], d[0]) for d in v.directions],
            "failure": None if failure is None else {"direction": shown.get(failure[0], failure[0]),
                                                     "verdict": failure[2]},
            "wall_s": round(v.wall_time_s, 2)}


def cmd_synth(args: argparse.Namespace) -> int:
    """Synthesize force-closure grasps; exit 0 when -n were written, 1 fewer, 2 bad input."""
    from planner.synthesis import run_synth  # deferred: scipy, coal (~0.25 s)

    if args.no_verify and args.engine is not None:
        raise PlannerError("--engine and --no-verify exclude each other: --no-verify replays nothing")
    gravity = args.gravity
    if isinstance(gravity, str):  # a name: the hand resolves it (planner.gravity.named_gravity)
        from pathlib import Path

        from planner.grasp import load_hand, resolve_hand_ref
        from planner.gravity import named_gravity

        try:
            hand = load_hand(resolve_hand_ref(args.hand, Path.cwd()))
        except (RuntimeError, OSError) as err:  # a symlink loop, an unreadable folder
            raise PlannerError(f"synth: hand {args.hand}: cannot be resolved: {err}") from None
        gravity = named_gravity(args.gravity, hand)
        if not args.quiet:
            print(f"synth: {_gravity_line(args.gravity, gravity, hand.name)}", file=sys.stderr, flush=True)
    return run_synth(args.hand, args.object, args.fingers, args.n, args.output, gravity=gravity, seed=args.seed,
                     max_finger_force_n=args.max_finger_force, mu=args.mu, gamma=args.gamma,
                     max_attempts=args.max_attempts, quiet=args.quiet, palm=args.palm,
                     workers=getattr(args, "workers", 1),
                     gravity_name=args.gravity if isinstance(args.gravity, str) else None,
                     verify=not args.no_verify, engine=args.engine)



def cmd_verify(args: argparse.Namespace) -> int:
    """Check a plan against physics and its inputs (`planner.audit`): exit 0 sound, 1 not."""
    from planner.audit import audit_plan  # deferred: scipy (~0.2 s)
    from planner.plan import read_plan  # deferred: scipy (~0.2 s)

    plan = read_plan(args.plan, strict=args.strict)
    waypoints = sum(len(s.path) for s in plan.steps)
    if waypoints > LARGE_PLAN_WAYPOINTS:  # about 1 ms each: why nothing is printed for a while (a progress line)
        logging.getLogger("planner").info("checking %d states, %d steps, %d path waypoints (about %d s or more)",
                                          len(plan.states), len(plan.steps), waypoints, waypoints // 1000 + 1)
    rep = audit_plan(plan)
    for line in rep.problems:
        print(f"FAIL {line}")
    print(rep.summary())
    return 0 if rep.ok else 1


def cmd_hand(args: argparse.Namespace) -> int:
    """``hand init URDF -o hand.yaml``: a hand.yaml with every guess explained; ``hand check
    HAND``: what a planner or simulator cannot use in it (exit 1 on an error)."""
    if args.hand_command == "init":
        out = os.path.abspath(args.output)
        # --root: the hand's own URDF (the sub-tree) is written beside the hand.yaml, same stem
        cut = os.path.splitext(out)[0] + ".urdf" if args.root is not None else None
        # the sub-tree is written before the hand is inferred from it: a refusal after that
        # leaves no hand.urdf behind (or the one that was there)
        cut_before = Path(cut).read_bytes() if cut is not None and os.path.isfile(cut) else None
        try:
            spec, rep = handtool.init_hand(args.urdf, args.package_dir or (), root=args.root, cut_path=cut,
                                           output=args.output)
            urdf = os.path.abspath(spec["urdf"])
            spec["urdf"] = os.path.relpath(urdf, os.path.dirname(out))  # a hand.yaml moves with its URDF
            if spec.get("package_dirs"):
                spec["package_dirs"] = [os.path.relpath(os.path.abspath(d), os.path.dirname(out))
                                        for d in spec["package_dirs"]]
            header = "# written by regrasp hand init: every guess below is explained on its output; check and edit\n"
            write_atomic(args.output, header + yaml.safe_dump(spec, sort_keys=False, default_flow_style=None))
        except BaseException:
            if cut is not None and os.path.isfile(cut):
                if cut_before is None:
                    os.remove(cut)
                elif Path(cut).read_bytes() != cut_before:
                    write_atomic(cut, cut_before)
            raise
        for f in rep.findings:
            print(f.line())
        print(f"wrote {args.output}: {len(spec['fingers'])} fingers ({', '.join(spec['fingers'])}); "
              f"next: regrasp hand check {args.output}")
        return 1 if rep.errors else 0
    rep = handtool.check_hand(args.hand)
    for f in rep.findings:
        print(f.line())
    n_warn = sum(f.level == "warning" for f in rep.findings)
    print(f"{args.hand}: {len(rep.errors)} error(s), {n_warn} warning(s)")
    return 1 if rep.errors else 0


def cmd_view(args: argparse.Namespace) -> int:
    """Write the interactive 3D page (one self-contained HTML file) of a plan or a grasp."""
    from planner.view import view_command  # deferred: scipy (~0.2 s)

    return view_command(args.source, args.output, report=args.report, gif=args.gif)


def _print_states(report) -> None:
    print(f"{'state':>5}  {'plan fingers':<24} {'plan FC':>7} {'plan metric':>11}  {'sim fingers':<24} "
          f"{'sim FC':>6} {'sim metric':>10}  {'drift mm':>8} {'drift deg':>9}  contacts off the plan's")
    for s in report.states:
        if not s.reached:
            print(f"{s.index:>5}  {','.join(s.planned_fingers) or '-':<24} {str(s.planned_force_closure):>7} "
                  f"{s.planned_metric:>11.4g}  {'(not reached)':<24}")
            continue
        print(f"{s.index:>5}  {','.join(s.planned_fingers) or '-':<24} {str(s.planned_force_closure):>7} "
              f"{s.planned_metric:>11.4g}  {','.join(s.sim_fingers) or '-':<24} {str(s.sim_force_closure):>6} "
              f"{s.sim_metric:>10.4g}  {s.drift_mm:>8.2f} {s.drift_deg:>9.2f}  "
              + (", ".join(f"{f} {d:.1f} mm" for f, d in sorted(s.contact_offset_mm.items()) if d >= 1.0) or "-"))


def _compare_verification(plan, result, engine: str = "pybullet") -> None:
    """Say whether this replay (in ``engine``) gives what the planner's verification recorded
    for that engine: the verdicts and the drifts (the replay is deterministic: a record this
    replay did not write differs). A plan verified before engines were named was pybullet's."""
    recorded = (plan.summary or {}).get("verification")
    if not isinstance(recorded, dict) or not isinstance(recorded.get("directions"), dict):
        return
    by_engine = recorded.get("engines") if isinstance(recorded.get("engines"), dict) else {}
    verified_in = recorded.get("engine", "pybullet")
    mine = by_engine.get(engine) if by_engine else (recorded["directions"] if verified_in == engine else None)
    if not isinstance(mine, dict):
        print(f"the plan's verification ran in {verified_in}; this replay in {engine}: not compared")
        return
    now = {name: r for name, _, r in result.directions}
    common = [n for n in mine if n in now]

    def differs(name) -> bool:
        rec = mine[name]
        rec = rec if isinstance(rec, dict) else {}
        r = now[name]
        if bool(rec.get("passed")) != r.passed:
            return True
        return any(not isinstance(rec.get(k), (int, float)) or abs(rec[k] - v) > 2e-3
                   for k, v in (("max_drift_mm", r.max_drift_mm), ("max_drift_deg", r.max_drift_deg)) if math.isfinite(v))

    differ = [n for n in common if differs(n)]
    if differ:
        print(f"warning: this replay in {engine} differs from the plan's recorded verification in {', '.join(differ)} "
              f"(verdict or drift): the record was not written by a replay of this plan")
    elif common:
        print(f"same verdicts and drifts in {engine} as the plan's verification in {len(common)} direction(s)")


def _print_gravity_set(result) -> None:
    print(f"{'gravity':<10} {'g (palm frame)':<22} {'verdict':<5} {'drift mm':>8} {'drift deg':>9} {'closure':>8}  why")
    for name, g, r in result.directions:
        agree, reached = r.closure_agreement
        why = r.reasons[0] if r.reasons and not r.passed else ""
        print(f"{name:<10} {'[' + ' '.join(f'{v:+.2f}' for v in g) + ']':<22} {'PASS' if r.passed else 'FAIL':<5} "
              f"{r.max_drift_mm:>8.2f} {r.max_drift_deg:>9.2f} {f'{agree}/{reached}':>8}  {why}")


def _print_couplings(runs) -> None:
    """One line on the coupled joints of the replays ``runs`` ((name, ReplayReport) pairs):
    each coupling's largest ``|q_f - (m q_d + o)|`` over them against its tolerance
    (`planner.sim.report.CouplingError`); nothing for a hand without couplings."""
    worst: dict = {}
    for name, r in runs:
        for c in getattr(r, "coupling_errors", ()):
            if c.joint not in worst or c.max_error > worst[c.joint][1].max_error:
                worst[c.joint] = (name, c)
    if not worst:
        return
    parts = [f"{j} {c.max_error:.2g} ({c.max_error / c.tolerance:.0%} of {c.tolerance:.3g}"
             + (f", {name}" if name else "") + (", state 0)" if c.step < 0 else f", step {c.step})")
             for j, (name, c) in worst.items()]
    broken = sum(not c.within for _, c in worst.values())
    print(f"coupled joints, largest error (rad or m; of the tolerance): {'; '.join(parts)}"
          + (f": {broken} broken" if broken else ": all within"))


def _engine_verdict(report) -> str:
    """A single replay's verdict naming its engine: "PASS in mujoco: max drift ..."."""
    head, sep, rest = report.verdict.partition(": ")
    return f"{head} in {report.engine}{sep}{rest}"


def cmd_replay(args: argparse.Namespace) -> int:
    """Replay a plan in a physics engine (`planner.api.replay`, printed; ``--engine both``: in
    each); exit 0 pass, 1 fail (dropped, drifted or closure disagrees; in any engine), 2 bad input."""
    from planner.api import replay  # deferred: the physics engine

    kw = dict(gui=args.gui, gif=args.gif, gif_every=args.gif_every, mp4=args.mp4,
              drift_mm_max=args.drift_mm, drift_deg_max=args.drift_deg, strict=args.strict)
    if args.film is not None and args.gravity_set is None:
        raise PlannerError("--film names directions of --gravity-set: give --gravity-set N too")
    if args.gravity_set is not None and args.gravity is not None:
        raise PlannerError("--gravity and --gravity-set exclude each other: give one")
    if args.workers is not None and args.gravity_set is None:  # (one replay runs in this process: it was ignored)
        raise PlannerError("--workers runs the directions of --gravity-set in parallel: give --gravity-set N too")
    if args.workers is not None and args.workers < 1:
        raise PlannerError(f"--workers must be >= 1, got {args.workers}")
    from planner.plan import read_plan  # deferred: scipy (~0.2 s)

    plan = read_plan(args.plan, strict=args.strict)  # read (and its inputs checked) once
    engine = {"engine": args.engine} if args.engine is not None else {}
    if args.gravity_set is not None:
        film = [d.strip() for d in args.film.split(",") if d.strip()] if args.film is not None else None
        result = replay(plan, gravity_set=args.gravity_set, report=args.report, film=film,
                        workers=1 if args.gui else args.workers, **engine, **kw)
        results = getattr(result, "engines", None) or ((result.directions[0][2].engine, result),)
        for name, res in results:
            if len(results) > 1:
                print(f"{name}:")
            _print_gravity_set(res)
            _print_couplings([(d, r) for d, _, r in res.directions])
            _compare_verification(plan, res, name)
            if len(results) > 1:
                print(f"{name}: {res.verdict}")
        passed, verdict = result.passed, result.verdict
    else:
        gravity = tuple(args.gravity) if args.gravity and not isinstance(args.gravity, str) else args.gravity
        result = replay(plan, report=args.report, **engine, **kw, **({"gravity": gravity} if gravity is not None else {}))
        results = getattr(result, "engines", None) or ((result.engine, result),)
        for name, report in results:
            if len(results) > 1:
                print(f"{name}:")
            if isinstance(args.gravity, str):
                print(_gravity_line(args.gravity, report.parameters["gravity"], plan.hand["name"]))
            _print_states(report)
            _print_couplings([("", report)])
            agree, reached = report.closure_agreement
            print(f"force closure agrees at {agree}/{reached} states; simulated {report.sim_time_s:.2f} s "
                  f"in {report.wall_time_s:.2f} s in {name}"
                  + (f"; GIF {report.gif} ({report.gif_frames} frames)" if report.gif else ""))
            if len(results) > 1:
                print(_engine_verdict(report))
        passed = result.passed
        verdict = result.verdict if len(results) > 1 else _engine_verdict(result)
    print(verdict)
    return 0 if passed else 1

