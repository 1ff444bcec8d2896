"""Command line: `regrasp` and `python -m planner`.

A `PlannerError` becomes one line on stderr and exit code 2 (bad input) or the
command's own failure code; any other exception is a bug and shows its traceback.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
import tempfile

from planner.errors import NoSequenceError, PlannerError, one_line
from planner.gravity import GRAVITY_SET_SIZES

DEMO_INITIAL = "icub/cylinder_parallel_extension.yaml"  # bundled grasps (planner.resources)
DEMO_FINAL = "icub/cylinder_ir2m.yaml"
DEMO_OUT = "regrasp-demo"


def _cmd_plan(args: argparse.Namespace) -> int:
    import time

    from planner.grasp import load_grasp, realize
    from planner.plan import plan_format, write_plan
    from planner.grasp import input_record
    from planner.options import PlanOptions
    from planner.regrasp import check_same_setup, plan_regrasp

    if args.output:
        plan_format(args.output)  # refuse a bad suffix before any work
    t0 = time.perf_counter()
    chosen = dict(contact_model=args.contact_model, rank=args.rank,
                  gravity=tuple(args.gravity) if args.gravity is not None else None, gravity_set=args.gravity_set)
    if not args.execution:  # the thesis's defaults; --execution brings its own (PlanOptions.for_execution)
        chosen.update(contact_model=args.contact_model or "patch", rank=args.rank or "metric")
    options = (PlanOptions.for_execution if args.execution else PlanOptions)(
        strategy=args.strategy,
        alternatives=args.alternatives,
        intermediate=args.intermediate,
        seed=args.seed,
        motion=not args.no_motion,
        motion_planner=args.motion_planner,
        motion_timeout_s=args.motion_timeout,
        max_lifted=args.max_lifted,
        max_finger_force_n=args.max_finger_force,
        time_limit_s=args.time_limit,
        max_rounds=args.max_rounds,
        **({"verify": False} if args.no_verify else {}),
        **chosen,
    )
    specs = [load_grasp(args.initial), load_grasp(args.final)]
    check_same_setup(*specs)
    initial, final = (realize(s).require_placed() for s in specs)
    inputs = {k: input_record(p) for k, p in (("initial", args.initial), ("final", args.final))}
    result = plan_regrasp(initial, final, options, inputs, verbose=args.verbose)
    plan = result.plan
    if args.output:  # written before anything is printed: a closed pipe (| head) cannot lose it
        write_plan(plan, args.output)
    gripped = plan.states[0].grip_force_n is not None
    print(f"{'step':>4}  {'finger':<8} {'action':<5} {'state':>5}  {'metric':>10}  " + ("grip N  " if gripped else "") + "removable")
    for i, step in enumerate(plan.steps):
        st = plan.states[step.to_state]
        grip = f"{st.grip_force_n:>6.3f}  " if gripped else ""
        print(f"{i:>4}  {step.finger:<8} {step.action:<5} {step.to_state:>5}  {st.metric:>10.4g}  {grip}{','.join(st.removable) or '-'}")
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
    check = s.get("verification")
    if check is not None:
        names = ", ".join(check["directions"])
        print(f"verified in pybullet: held in {len(check['directions'])} gravity directions ({names}), "
              f"{check['attempts']} sequence(s) replayed in {result.verify_s:.1f} s"
              + (f" ({len(check['rejected'])} rejected: " + "; ".join(f"{r['direction']} at step {r['step']}"
                                                                    for r in check['rejected']) + ")"
                 if check["rejected"] else "") + "; --no-verify skips it")
    return 0


def _cmd_check(args: argparse.Namespace) -> int:
    """Realize one grasp, print the report (text or JSON), draw it (``--png``); exit 0 force
    closure and as written (no `RealizedGrasp.problems`), 1 not, 2 bad input."""
    import json

    from planner.grasp_report import check_text, contact_markers
    from planner.grasp import load_grasp, realize

    grasp = realize(load_grasp(args.grasp))
    if args.png:
        from planner.sim.render import render_png

        render_png(grasp.hand, grasp.q, grasp.obj, args.png, markers=contact_markers(grasp))
    if args.json:
        print(json.dumps(grasp.summary(), indent=1))
    else:
        print(check_text(grasp))
        if args.png:
            print(f"picture written to {args.png} (contacts: dots with their inward normals; green ok, orange "
                  "warning, red problem)")
    return 0 if grasp.ok else 1


def _cmd_synth(args: argparse.Namespace) -> int:
    """Synthesize force-closure grasps; exit 0 when -n were written, 1 fewer, 2 bad input."""
    from planner.synth import run_synth

    return run_synth(args.hand, args.object, args.fingers, args.n, args.output, gravity=args.gravity, seed=args.seed,
                     max_finger_force_n=args.max_finger_force, mu=args.mu, gamma=args.gamma,
                     max_attempts=args.max_attempts, quiet=args.quiet)


def _cmd_demo(args: argparse.Namespace) -> int:
    """Plan the bundled cylinder example (parallel extension -> IR2M) for execution and
    replay it under the six gravity directions it was planned for, and gravity off."""
    from pathlib import Path

    from planner.resources import bundled_grasp

    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise PlannerError(f"--out {out}: exists and is not a directory; name a directory for the demo's outputs")
    out.mkdir(parents=True, exist_ok=True)
    plan_path = out / "cylinder_plan.yaml"
    # execution mode: one mean contact per finger (the simulator's rigid fingertips), every
    # state holds the weight in six hand orientations with 3/4 of the friction, least grip
    # ranked first (the box pair needs more friction palm up: execution mode refuses it)
    code = main(["plan", str(bundled_grasp(DEMO_INITIAL)), str(bundled_grasp(DEMO_FINAL)), "-o", str(plan_path),
                 "--execution"])
    if code != 0:
        return code
    # the demo's exit code is the replay's (1 when any direction fails); the GIF is palm down
    print(f"\nreplaying {plan_path} in pybullet under 7 gravity directions (palm down filmed)")
    verdict = main(["replay", str(plan_path), "--gravity-set", "7", "--gif", str(out / "cylinder_replay.gif"),
                    "--film", "palm_down",
                    "--report", str(out / "cylinder_report.json")])
    # the interactive 3D page of the plan, with the replay's contacts and drift (regrasp view)
    main(["view", str(plan_path), "-o", str(out / "cylinder_plan.html"), "--report", str(out / "cylinder_report.json")])
    print(f"demo outputs in {out}/: cylinder_plan.yaml, cylinder_plan.html, cylinder_replay_palm_down.gif, "
          f"cylinder_report.json (replay {'passed' if verdict == 0 else 'did not pass'})")
    return verdict


def _cmd_verify(args: argparse.Namespace) -> int:
    """Check a plan against physics and its inputs (`planner.audit`): exit 0 sound, 1 not."""
    from planner.audit import audit_plan
    from planner.plan import read_plan

    rep = audit_plan(read_plan(args.plan, strict=args.strict))
    for line in rep.problems:
        print(f"FAIL {line}")
    print(rep.summary())
    return 0 if rep.ok else 1


def _cmd_hand(args: argparse.Namespace) -> int:
    """``hand init URDF -o hand.yaml``: a hand.yaml with every guess explained; ``hand check
    HAND``: what a planner or simulator cannot use in it (exit 1 on an error)."""
    from planner import handtool

    if args.hand_command == "init":
        import yaml

        from planner.fileio import write_atomic

        spec, rep = handtool.init_hand(args.urdf, args.package_dir or ())
        out = os.path.abspath(args.output)
        urdf = os.path.abspath(args.urdf)
        spec["urdf"] = os.path.relpath(urdf, os.path.dirname(out))  # a hand.yaml moves with its URDF
        if spec.get("package_dirs"):
            spec["package_dirs"] = [os.path.relpath(os.path.abspath(d), os.path.dirname(out)) for d in spec["package_dirs"]]
        header = "# written by regrasp hand init: every guess below is explained on its output; check and edit\n"
        write_atomic(args.output, header + yaml.safe_dump(spec, sort_keys=False, default_flow_style=None))
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


def _cmd_view(args: argparse.Namespace) -> int:
    """Write the interactive 3D page (one self-contained HTML file) of a plan or a grasp."""
    from planner.view import view_command

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


def _compare_verification(plan, result) -> None:
    """Say whether this replay gives the verdicts the planner's verification recorded."""
    recorded = (plan.summary or {}).get("verification")
    if not isinstance(recorded, dict) or not isinstance(recorded.get("directions"), dict):
        return
    now = {name: r.passed for name, _, r in result.directions}
    common = [n for n in recorded["directions"] if n in now]
    differ = [n for n in common if bool(recorded["directions"][n].get("passed")) != now[n]]
    if differ:
        print(f"warning: verdicts differ from the plan's verification in {', '.join(differ)}")
    elif common:
        print(f"same verdicts as the plan's verification in {len(common)} direction(s)")


def _cmd_replay(args: argparse.Namespace) -> int:
    """Replay a plan in pybullet; exit 0 pass, 1 fail (dropped, drifted or closure disagrees), 2 bad input."""
    import json

    from planner.sim.replay import replay_plan
    from planner.sim.verify import replay_gravity_set

    kw = dict(gui=args.gui, gif=args.gif, gif_every=args.gif_every, mp4=args.mp4,
              drift_mm_max=args.drift_mm, drift_deg_max=args.drift_deg, strict=args.strict)
    if args.film and args.gravity_set is None:
        raise PlannerError("--film names directions of --gravity-set: give --gravity-set N too")
    if args.gravity_set is not None and args.gravity is not None:
        raise PlannerError("--gravity and --gravity-set exclude each other: give one")
    if args.workers is not None and args.workers < 1:
        raise PlannerError(f"--workers must be >= 1, got {args.workers}")
    from planner.audit import require_sound
    from planner.plan import read_plan

    plan = read_plan(args.plan, strict=args.strict)  # read (and its inputs checked) once
    require_sound(plan)  # intact is not right: a resealed, physically wrong plan is refused here
    import logging

    log = logging.getLogger("planner")
    log.info("plan verified against physics (%d states, %d steps); simulating", len(plan.states), len(plan.steps))
    if args.gravity_set is not None:
        film = [d.strip() for d in args.film.split(",") if d.strip()] if args.film else None
        workers = 1 if args.gui else args.workers
        result = replay_gravity_set(plan, args.gravity_set, film=film, workers=workers, **kw)
        print(f"{'gravity':<10} {'g (palm frame)':<22} {'verdict':<5} {'drift mm':>8} {'drift deg':>9} {'closure':>8}  why")
        for name, g, r in result.directions:
            agree, reached = r.closure_agreement
            why = r.reasons[0] if r.reasons and not r.passed else ""
            print(f"{name:<10} {'[' + ' '.join(f'{v:+.2f}' for v in g) + ']':<22} {'PASS' if r.passed else 'FAIL':<5} "
                  f"{r.max_drift_mm:>8.2f} {r.max_drift_deg:>9.2f} {f'{agree}/{reached}':>8}  {why}")
        data, passed, verdict = result.to_dict(), result.passed, result.verdict
        _compare_verification(plan, result)
    else:
        report = replay_plan(plan, **kw, **({"gravity": tuple(args.gravity)} if args.gravity else {}))
        _print_states(report)
        agree, reached = report.closure_agreement
        print(f"force closure agrees at {agree}/{reached} states; simulated {report.sim_time_s:.2f} s "
              f"in {report.wall_time_s:.2f} s" + (f"; GIF {report.gif} ({report.gif_frames} frames)" if report.gif else ""))
        data, passed, verdict = report.to_dict(), report.passed, report.verdict
    if args.report:
        from planner.fileio import write_atomic

        write_atomic(args.report, json.dumps(data, indent=1) + "\n")
    print(verdict)
    return 0 if passed else 1


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="regrasp", description=__doc__.splitlines()[0])
    from planner import __version__

    parser.add_argument("--version", action="version", version=f"regrasp {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="plan and replay the bundled cylinder example")
    demo.add_argument("--out", default=DEMO_OUT, metavar="DIR",
                      help=f"directory for the plan, GIFs and report (default: ./{DEMO_OUT}/)")
    demo.set_defaults(func=_cmd_demo)

    check = sub.add_parser("check", help="realize one grasp file and report its contacts and force closure")
    check.add_argument("grasp", help="grasp YAML")
    check.add_argument("--json", action="store_true", help="machine-readable output")
    check.add_argument("--png", metavar="FILE", help="render the hand holding the object (headless)")
    check.set_defaults(func=_cmd_check)

    plan = sub.add_parser("plan", help="plan a finger-gaiting sequence between two grasps")
    plan.add_argument("initial", help="grasp YAML the hand holds now")
    plan.add_argument("final", help="grasp YAML the hand needs")
    plan.add_argument("-o", "--output", help="write the plan here (.yaml/.yml or .json)")
    plan.add_argument("--alternatives", type=int, default=4, metavar="K", help="ranked sequences to report (default 4)")
    plan.add_argument("--intermediate", type=int, default=0, metavar="N",
                      help="a fixed number of intermediate contacts per finger (default 0: added in rounds when needed, "
                           "see --max-rounds)")
    plan.add_argument("--max-rounds", type=int, default=4, metavar="N",
                      help="when no sequence exists, intermediate contacts are added for the fingers that block "
                           "progress, round after round, at most N rounds (default 4; 0: none); the result does not "
                           "depend on the machine's load")
    plan.add_argument("--time-limit", type=float, default=60.0, metavar="S",
                      help="a cap on the search time, s (default 60; finger paths not counted; reaching it is "
                           "reported: the result then depends on the machine's speed); 0: no rounds")
    plan.add_argument("--strategy", default="graph", help="graph (ranked search, default) or greedy (thesis Algorithm 2)")
    plan.add_argument("--seed", type=int, default=0, help="seed for sampling and motion planning (default 0)")
    plan.add_argument("--contact-model", default=None, metavar="MODEL",
                      help="closure from every patch point (patch, default: the thesis) or from one mean contact "
                           "per finger (mean: what the simulator's rigid fingertips give; --execution's)")
    plan.add_argument("--max-lifted", type=int, default=None, metavar="N", help="at most N fingers lifted at once")
    plan.add_argument("--gravity", type=float, nargs=3, metavar=("GX", "GY", "GZ"), default=None,
                      help="also require every state to hold twice the object's weight under this gravity (palm "
                           "frame, m/s^2, e.g. 0 0 9.81 palm down) within the hand's joint torque limits")
    plan.add_argument("--gravity-set", type=int, default=None, metavar="N",
                      help="like --gravity for several hand orientations at once: 1 palm down, 2 and palm up, "
                           "6 and the four sideways directions, 7 and gravity off (from the hand's palm_normal)")
    plan.add_argument("--max-finger-force", type=float, default=None, metavar="N",
                      help="optional extra cap on every finger's normal force against gravity, N (default none: "
                           "the hand's joint torque limits bound the grip)")
    plan.add_argument("--rank", default=None, metavar="metric|grip",
                      help="rank sequences by their worst closure metric (metric, default: the thesis) or by the "
                           "largest grip force they need (grip; needs --gravity or --gravity-set)")
    plan.add_argument("--execution", action="store_true",
                      help="plan for execution: --contact-model mean, --gravity-set 6 (unless --gravity or "
                           "--gravity-set is given) and --rank grip, and verify the plan in pybullet")
    plan.add_argument("--no-verify", action="store_true",
                      help="with --execution: return the best sequence without replaying it in pybullet first")
    plan.add_argument("--no-motion", action="store_true", help="skip OMPL finger paths (straight joint segments)")
    plan.add_argument("--motion-planner", default="rrtconnect", help="OMPL planner name (default rrtconnect)")
    plan.add_argument("--motion-timeout", type=float, default=2.0, metavar="S", help="time budget per finger path, s")
    plan.add_argument("-v", "--verbose", action="store_true",
                      help="show the motion planner's and the C++ libraries' console output and every warning")
    plan.set_defaults(func=_cmd_plan)
    synth = sub.add_parser("synth", help="generate force-closure grasp files for a hand and an object")
    synth.add_argument("hand", help="hand name under robots/ (icub_right, allegro_right) or a hand.yaml")
    synth.add_argument("object", help="object YAML: the object: block of a grasp file (shape, size[, position, "
                                      "quat_xyzw, mass_kg, mesh]); without position the object pose is sampled too")
    synth.add_argument("--fingers", default=None,
                       help="comma-separated fingers that grasp, e.g. thumb,index,middle (default: a tripod, the "
                            "thumb and the hand's next two fingers; without a thumb its first three)")
    synth.add_argument("-n", type=int, default=20, help="grasps to write (default 20)")
    synth.add_argument("-o", "--output", required=True, metavar="DIR", help="folder for the grasp files (never overwritten)")
    synth.add_argument("--gravity", type=float, nargs=3, metavar=("GX", "GY", "GZ"), default=None,
                       help="keep grasps that hold twice the weight under this gravity (palm frame, m/s^2) within "
                            "the hand's joint torque limits")
    synth.add_argument("--max-finger-force", type=float, default=None, metavar="N",
                       help="with --gravity: an extra cap on every finger's normal force, N (default none)")
    synth.add_argument("--seed", type=int, default=0, help="seed (default 0); same seed, same files")
    synth.add_argument("--mu", type=float, default=None, help="friction coefficient (default: the object file's, else 0.9)")
    synth.add_argument("--gamma", type=float, default=None, help="torsional friction, m (default: the object file's, else 0.004)")
    synth.add_argument("--max-attempts", type=int, default=None, metavar="K", help="candidates sampled at most (default 60 n)")
    synth.add_argument("-q", "--quiet", action="store_true", help="no progress lines on stderr")
    synth.set_defaults(func=_cmd_synth)
    replay = sub.add_parser("replay", help="execute a plan in pybullet with gravity on and check the object stays put")
    replay.add_argument("plan", help="plan file (.yaml/.yml or .json)")
    replay.add_argument("--gif", metavar="FILE", help="write an animated GIF (headless TinyRenderer)")
    replay.add_argument("--gif-every", type=int, default=8, metavar="N", help="one GIF frame every N physics steps (default 8)")
    replay.add_argument("--mp4", metavar="FILE", help="write an MP4 (needs ffmpeg on PATH)")
    replay.add_argument("--gui", action="store_true", help="open the pybullet GUI (needs a display)")
    replay.add_argument("--report", metavar="FILE", help="write the replay report as JSON")
    replay.add_argument("--strict", action="store_true",
                        help="refuse a plan whose recorded input files changed or are gone (default: a warning)")
    replay.add_argument("--drift-mm", type=float, default=5.0, metavar="X", help="largest allowed object drift, mm (default 5)")
    replay.add_argument("--drift-deg", type=float, default=5.0, metavar="Y", help="largest allowed object rotation, deg (default 5)")
    replay.add_argument("--gravity", type=float, nargs=3, metavar=("GX", "GY", "GZ"),
                        help="gravity in the palm frame, m/s^2 (default: palm facing down, along the hand's palm_normal)")
    replay.add_argument("--gravity-set", type=int, choices=GRAVITY_SET_SIZES, metavar="N",
                        help="replay under N gravity directions of the palm frame with a verdict per direction: "
                             "1 palm down, 2 and palm up, 6 and the four sideways directions, 7 and gravity off")
    replay.add_argument("--workers", type=int, default=None, metavar="N",
                        help="with --gravity-set: replay the directions in N processes (default: the cores "
                             "available; the verdicts are those of a serial run)")
    replay.add_argument("--film", metavar="NAMES",
                        help="with --gravity-set and --gif/--mp4: film only these directions (comma-separated, "
                             "e.g. palm_down; default all, one file per direction)")
    replay.set_defaults(func=_cmd_replay)
    verify = sub.add_parser("verify", help="check a plan against physics and its inputs, without simulation: "
                                           "contacts on the surface and at the joints' kinematics, paths free, "
                                           "the chain from the initial to the final grasp")
    verify.add_argument("plan", help="plan file (.yaml/.yml or .json)")
    verify.add_argument("--strict", action="store_true",
                        help="refuse a plan whose recorded input files changed or are gone (default: a warning)")
    verify.set_defaults(func=_cmd_verify)
    hand = sub.add_parser("hand", help="your own hand: write a hand.yaml from a URDF (init), check one (check)")
    hsub = hand.add_subparsers(dest="hand_command", required=True)
    hinit = hsub.add_parser("init", help="infer fingers, tips, pads, closing joints and the palm normal from a URDF")
    hinit.add_argument("urdf", help="the hand's URDF")
    hinit.add_argument("-o", "--output", required=True, metavar="FILE", help="the hand.yaml to write")
    hinit.add_argument("--package-dir", action="append", metavar="DIR",
                       help="a folder holding the ROS packages of package:// mesh paths (repeatable)")
    hcheck = hsub.add_parser("check", help="report what a planner or simulator cannot use in a hand, one line each")
    hcheck.add_argument("hand", help="a bundled hand's name or a hand.yaml")
    hand.set_defaults(func=_cmd_hand)
    view = sub.add_parser("view", help="write an interactive 3D page (one offline HTML file) of a plan or a grasp")
    view.add_argument("source", help="plan file (.yaml/.yml/.json) or grasp YAML")
    view.add_argument("-o", "--output", required=True, metavar="FILE", help="the page to write (.html)")
    view.add_argument("--report", metavar="FILE", help="replay report (regrasp replay --report) shown next to the plan")
    view.add_argument("--gif", metavar="FILE", help="also a 640x480 GIF: captions, contacts, the moving finger coloured")
    view.set_defaults(func=_cmd_view)
    commands = [c for n, c in sub.choices.items() if n not in ("synth", "hand")] + [hinit, hcheck]
    for cmd in commands + [synth]:  # -q/--quiet and -v/--verbose on every command
        if cmd is not synth:
            cmd.add_argument("-q", "--quiet", action="store_true", help="no progress lines on stderr")
        if cmd is not plan:
            cmd.add_argument("-v", "--verbose", action="store_true",
                             help="show the C++ libraries' console output (urdfdom, OMPL, pybullet) and every warning")
    return parser


#: Ranges of the numeric options (README "Hardening / plan integrity"), (low, high, low is
#: exclusive): the planner's are `planner.options.PLAN_OPTION_LIMITS` (checked by
#: `PlanOptions` too; `option_limits` gives them their option names), these are replay's.
OPTION_LIMITS = {
    "gif_every": (1, 10000, False),
    "drift_mm": (0.0, 1000.0, True),
    "drift_deg": (0.0, 180.0, True),
}
#: Files each command reads and writes (argument names): an output may not be an input.
_INPUTS = {"plan": ("initial", "final"), "check": ("grasp",), "replay": ("plan",), "view": ("source", "report"),
           "verify": ("plan",), "hand": ("urdf", "hand")}
_OUTPUTS = {"hand": ("output",), "plan": ("output",), "check": ("png",), "replay": ("report", "gif", "mp4"), "view": ("output", "gif")}
#: Exit code of an interrupted command (128 + SIGINT) and of a closed stdout (128 + SIGPIPE).
EXIT_INTERRUPTED = 130
EXIT_BROKEN_PIPE = 141


class _Parser(argparse.ArgumentParser):
    """argparse with its errors as one line (no usage block) and exit code 2."""

    def error(self, message: str):
        message = one_line(str(message).strip())  # a user's option may hold a line break or an escape
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _option_name(dest: str) -> str:
    return "--" + dest.replace("_", "-")


def option_limits() -> dict:
    """Every numeric option's range by argparse dest: the planner's (`PlanOptions`'s
    table under its option names) and `OPTION_LIMITS`."""
    from planner.options import PLAN_OPTION_FLAGS, PLAN_OPTION_LIMITS

    return {**{PLAN_OPTION_FLAGS.get(k, k): v for k, v in PLAN_OPTION_LIMITS.items()}, **OPTION_LIMITS}


def _validate(args: argparse.Namespace) -> None:
    """Numeric ranges (`option_limits`) and output paths, before any work."""
    from planner.fileio import check_output
    from planner.options import in_range, option_range

    for dest, (low, high, open_low) in option_limits().items():
        value = getattr(args, dest, None)
        for v in value if isinstance(value, list) else [value]:
            if isinstance(v, str):
                continue
            if v is None:
                continue
            if not in_range(v, low, high, open_low):
                raise PlannerError(f"{_option_name(dest)}: {v!r} is out of range; valid: {option_range(low, high, open_low)}")
    inputs = [getattr(args, k, None) for k in _INPUTS.get(args.command, ())]
    outputs = [(getattr(args, k, None), "-o" if k == "output" else "--" + k) for k in _OUTPUTS.get(args.command, ())]
    named = [o for o, _ in outputs if o is not None]
    for out, option in outputs:
        if out is not None:
            check_output(out, inputs + [o for o in named if o is not out], option)
    if args.command == "replay" and getattr(args, "gravity_set", None) is not None:
        # a gravity set films into one file per direction (FILE_<direction>.gif): each of those
        # names may not be an input either (a plan called q_palm_down.yaml and --gif q.yaml)
        from pathlib import Path

        every = ("palm_down", "palm_up", "off") + tuple(f"side_{s}{a}" for a in "xyz" for s in "+-")
        for key in ("gif", "mp4"):
            out = getattr(args, key, None)
            if out is not None:
                p = Path(out)
                for name in every:
                    check_output(p.with_name(f"{p.stem}_{name}{p.suffix}"), inputs, f"--{key}")
        if getattr(args, key, None) is not None:
            from planner.fileio import check_grasp_file

            check_grasp_file(getattr(args, key))


_DEPTH = 0  # nesting of main() (demo calls it): only the outermost one redirects stderr


def main(argv: list[str] | None = None) -> int:
    """Run one command; a `PlannerError` is one line on stderr and exit 2 (1 for "no plan"),
    Ctrl-C exit 130, a closed stdout a quiet exit 141. Without --verbose, what C++ libraries
    print on stderr (urdfdom, eigen, OMPL) and Python warnings are dropped, except
    `planner.errors.PlannerWarning`s, printed as one ``warning:`` line each."""
    global _DEPTH
    parser = build_parser()
    args = parser.parse_args(argv)
    verbose = bool(getattr(args, "verbose", False))
    prefix = f"regrasp {args.command}"
    _DEPTH += 1
    try:
        try:
            term = sys.stderr.fileno()
        except (AttributeError, OSError, ValueError):  # stderr replaced (e.g. captured in tests)
            term = None
        quiet = bool(getattr(args, "quiet", False))
        with _progress(prefix, term, quiet), _warnings_as_lines(prefix, verbose), \
                _quiet_stderr(verbose or _DEPTH > 1) as noise:
            try:
                _validate(args)
                code = int(args.func(args))
                sys.stdout.flush()
                return code
            except (PlannerError, KeyboardInterrupt, BrokenPipeError):
                raise
            except BaseException:
                noise.keep = True  # a bug: show what the libraries printed before its traceback
                raise
    except NoSequenceError as err:
        _say(f"{prefix}: {err}")
        return 1
    except PlannerError as err:
        _say(f"{prefix}: error: {err}")
        return 2
    except KeyboardInterrupt:
        _say(f"{prefix}: interrupted")
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        # like other Unix tools: stop quietly; stdout goes nowhere so the exit flush cannot fail
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
        return EXIT_BROKEN_PIPE
    finally:
        _DEPTH -= 1


def _say(line: str) -> None:
    """One line on stderr, whatever the message holds (newlines in names included; other
    control characters, e.g. a terminal escape in a file name, shown escaped)."""
    print(one_line(" ".join(line.split("\n")).replace("\r", " ")), file=sys.stderr)


class _Noise:
    keep = False  # a bug's traceback keeps what the libraries printed before it


@contextlib.contextmanager
def _progress(prefix: str, fd: int | None, quiet: bool):
    """The ``planner`` logger's INFO records (a long plan's rounds, paths, replays) as lines
    on the terminal while a command runs: only when stderr is a terminal, never with -q."""
    import logging

    on = not quiet and fd is not None and os.isatty(fd)
    if not on:
        yield
        return
    stream = os.fdopen(os.dup(fd), "w", buffering=1)
    handler = logging.StreamHandler(stream)
    handler.setFormatter(logging.Formatter(f"{prefix}: %(message)s"))
    log = logging.getLogger("planner")
    old_level, old_prop = log.level, log.propagate
    log.addHandler(handler)
    log.setLevel(logging.INFO)
    log.propagate = False
    try:
        yield
    finally:
        log.removeHandler(handler)
        log.setLevel(old_level)
        log.propagate = old_prop
        stream.close()


@contextlib.contextmanager
def _quiet_stderr(off: bool):
    """Send file descriptor 2 (C++ libraries, Python warnings) to a temporary file while
    a command runs; dropped afterwards unless the command ends in a bug."""
    noise = _Noise()
    if off:
        yield noise
        return
    try:
        fd = sys.stderr.fileno()
    except (AttributeError, OSError, ValueError):  # stderr replaced (e.g. captured in tests)
        fd = 2
    sys.stderr.flush()
    saved = os.dup(fd)
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), fd)
        try:
            yield noise
        finally:
            sys.stderr.flush()
            os.dup2(saved, fd)
            os.close(saved)
            if noise.keep:
                tmp.seek(0)
                sys.stderr.write(tmp.read().decode(errors="replace"))


@contextlib.contextmanager
def _warnings_as_lines(prefix: str, verbose: bool):
    """PlannerWarnings become one ``warning:`` line each; other warnings (numpy
    RuntimeWarnings...) only show with --verbose."""
    import warnings

    from planner.errors import PlannerWarning

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            yield
        finally:
            for w in caught:
                if issubclass(w.category, PlannerWarning):
                    _say(f"{prefix}: warning: {w.message}")
                elif verbose:
                    _say(f"{prefix}: {w.category.__name__}: {w.message}")
