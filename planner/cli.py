"""Command line: `regrasp` and `python -m planner`.

A `PlannerError` becomes one line on stderr and exit code 2 (bad input) or the
command's own failure code; any other exception is a bug and shows its traceback.
"""

from __future__ import annotations

import argparse
import sys

from planner.errors import NoSequenceError, PlannerError
from planner.gravity import GRAVITY_SET_SIZES

DEMO_INITIAL = "grasps/icub/cylinder_parallel_extension.yaml"
DEMO_FINAL = "grasps/icub/cylinder_ir2m.yaml"


def _cmd_plan(args: argparse.Namespace) -> int:
    import time

    from planner.grasp import load_grasp, realize
    from planner.plan import plan_format, write_plan
    from planner.regrasp import PlanOptions, check_same_setup, plan_regrasp, sha256_file

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
        **chosen,
    )
    specs = [load_grasp(args.initial), load_grasp(args.final)]
    check_same_setup(*specs)
    initial, final = (realize(s).require_placed() for s in specs)
    inputs = {k: {"path": str(p), "sha256": sha256_file(p)} for k, p in (("initial", args.initial), ("final", args.final))}
    result = plan_regrasp(initial, final, options, inputs, verbose=args.verbose)
    plan = result.plan
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
    if args.output:
        write_plan(plan, args.output)
    print(
        f"{s['strategy']}: {s['gait_steps']} gait steps ({len(plan.steps)} motions), bottleneck metric "
        f"{s['bottleneck_metric']:.4g}"
        + (f", largest grip {s['bottleneck_grip_force_n']:.3f} N" if s["bottleneck_grip_force_n"] is not None else "")
        + f" (ranked by {s['rank']}), graph {s['graph_nodes']} states / {s['graph_edges']} edges "
        f"({s['blocked_states']} blocked), {time.perf_counter() - t0:.2f} s"
        + (f", written to {args.output}" if args.output else "")
    )
    return 0


def _cmd_check(args: argparse.Namespace) -> int:
    """Realize one grasp and report it; exit 0 force closure and as written, 1 not, 2 bad input."""
    from planner.grasp import check_grasp

    return check_grasp(args.grasp, as_json=args.json, png=args.png)


def _cmd_demo(args: argparse.Namespace) -> int:
    """Plan the bundled cylinder example (parallel extension -> IR2M) for execution and
    replay it under the six gravity directions it was planned for, and gravity off."""
    from pathlib import Path

    root = Path(__file__).resolve().parent.parent
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    plan_path = out / "cylinder_plan.yaml"
    # execution mode: one mean contact per finger (the simulator's rigid fingertips), every
    # state holds the weight in six hand orientations with 3/4 of the friction, least grip
    # ranked first (the box pair needs more friction palm up: execution mode refuses it)
    code = main(["plan", str(root / DEMO_INITIAL), str(root / DEMO_FINAL), "-o", str(plan_path), "--execution"])
    if code != 0:
        return code
    # the demo's exit code is the replay's (1 when any direction fails); the GIF is palm down
    print(f"\nreplaying {plan_path} in pybullet under 7 gravity directions (palm down filmed)")
    verdict = main(["replay", str(plan_path), "--gravity-set", "7", "--gif", str(out / "cylinder_replay.gif"),
                    "--report", str(out / "cylinder_report.json")])
    print(f"demo outputs in {out}/: cylinder_plan.yaml, cylinder_replay_<direction>.gif, cylinder_report.json "
          f"(replay {'passed' if verdict == 0 else 'did not pass'})")
    return verdict


def _print_states(report) -> None:
    print(f"{'state':>5}  {'plan fingers':<24} {'plan FC':>7} {'plan metric':>11}  {'sim fingers':<24} "
          f"{'sim FC':>6} {'sim metric':>10}  {'drift mm':>8} {'drift deg':>9}")
    for s in report.states:
        if not s.reached:
            print(f"{s.index:>5}  {','.join(s.planned_fingers) or '-':<24} {str(s.planned_force_closure):>7} "
                  f"{s.planned_metric:>11.4g}  {'(not reached)':<24}")
            continue
        print(f"{s.index:>5}  {','.join(s.planned_fingers) or '-':<24} {str(s.planned_force_closure):>7} "
              f"{s.planned_metric:>11.4g}  {','.join(s.sim_fingers) or '-':<24} {str(s.sim_force_closure):>6} "
              f"{s.sim_metric:>10.4g}  {s.drift_mm:>8.2f} {s.drift_deg:>9.2f}")


def _cmd_replay(args: argparse.Namespace) -> int:
    """Replay a plan in pybullet; exit 0 pass, 1 fail (dropped, drifted or closure disagrees), 2 bad input."""
    import json
    from pathlib import Path

    from planner.sim.replay import replay_gravity_set, replay_plan

    kw = dict(gui=args.gui, gif=args.gif, gif_every=args.gif_every, mp4=args.mp4,
              drift_mm_max=args.drift_mm, drift_deg_max=args.drift_deg)
    if args.gravity_set is not None:
        if args.gravity is not None:
            raise PlannerError("--gravity and --gravity-set exclude each other: give one")
        result = replay_gravity_set(args.plan, args.gravity_set, **kw)
        print(f"{'gravity':<10} {'g (palm frame)':<22} {'verdict':<5} {'drift mm':>8} {'drift deg':>9} {'closure':>8}  why")
        for name, g, r in result.directions:
            agree, reached = r.closure_agreement
            why = r.reasons[0] if r.reasons and not r.passed else ""
            print(f"{name:<10} {'[' + ' '.join(f'{v:+.2f}' for v in g) + ']':<22} {'PASS' if r.passed else 'FAIL':<5} "
                  f"{r.max_drift_mm:>8.2f} {r.max_drift_deg:>9.2f} {f'{agree}/{reached}':>8}  {why}")
        data, passed, verdict = result.to_dict(), result.passed, result.verdict
    else:
        report = replay_plan(args.plan, **kw, **({"gravity": tuple(args.gravity)} if args.gravity else {}))
        _print_states(report)
        agree, reached = report.closure_agreement
        print(f"force closure agrees at {agree}/{reached} states; simulated {report.sim_time_s:.2f} s "
              f"in {report.wall_time_s:.2f} s" + (f"; GIF {report.gif} ({report.gif_frames} frames)" if report.gif else ""))
        data, passed, verdict = report.to_dict(), report.passed, report.verdict
    if args.report:
        Path(args.report).parent.mkdir(parents=True, exist_ok=True)
        Path(args.report).write_text(json.dumps(data, indent=1) + "\n")
    print(verdict)
    return 0 if passed else 1


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="regrasp", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="plan (and replay) the bundled box example")
    demo.add_argument("--out", default="out", help="output folder (default: out)")
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
    plan.add_argument("--intermediate", type=int, default=0, metavar="N", help="extra contacts sampled per finger (default 0)")
    plan.add_argument("--strategy", default="graph", help="graph (ranked search, default) or greedy (thesis Algorithm 2)")
    plan.add_argument("--seed", type=int, default=0, help="seed for sampling and motion planning (default 0)")
    plan.add_argument("--contact-model", default=None, metavar="MODEL",
                      help="closure from every patch point (patch, default: the thesis) or from one mean contact "
                           "per finger (mean: what the simulator's rigid fingertips give; --execution's)")
    plan.add_argument("--max-lifted", type=int, default=None, metavar="N", help="at most N fingers lifted at once")
    plan.add_argument("--gravity", type=float, nargs=3, metavar=("GX", "GY", "GZ"), default=None,
                      help="also require every state to hold the object's weight under this gravity (palm frame, "
                           "m/s^2, e.g. 0 0 9.81 palm down) with each finger pressing at most --max-finger-force")
    plan.add_argument("--gravity-set", type=int, default=None, metavar="N",
                      help="like --gravity for several hand orientations at once: 1 palm down, 2 and palm up, "
                           "6 and the four sideways directions, 7 and gravity off (from the hand's palm_normal)")
    plan.add_argument("--max-finger-force", type=float, default=1.0, metavar="N",
                      help="per-finger normal force budget against gravity, N (default 1, the replay's squeeze)")
    plan.add_argument("--rank", default=None, metavar="metric|grip",
                      help="rank sequences by their worst closure metric (metric, default: the thesis) or by the "
                           "largest grip force they need (grip; needs --gravity or --gravity-set)")
    plan.add_argument("--execution", action="store_true",
                      help="plan for execution: --contact-model mean, --gravity-set 6 (unless --gravity or "
                           "--gravity-set is given) and --rank grip")
    plan.add_argument("--no-motion", action="store_true", help="skip OMPL finger paths (straight joint segments)")
    plan.add_argument("--motion-planner", default="rrtconnect", help="OMPL planner name (default rrtconnect)")
    plan.add_argument("--motion-timeout", type=float, default=2.0, metavar="S", help="time budget per finger path, s")
    plan.add_argument("--verbose", action="store_true", help="show the motion planner's console output")
    plan.set_defaults(func=_cmd_plan)
    replay = sub.add_parser("replay", help="execute a plan in pybullet with gravity on and check the object stays put")
    replay.add_argument("plan", help="plan file (.yaml/.yml or .json)")
    replay.add_argument("--gif", metavar="FILE", help="write an animated GIF (headless TinyRenderer)")
    replay.add_argument("--gif-every", type=int, default=8, metavar="N", help="one GIF frame every N physics steps (default 8)")
    replay.add_argument("--mp4", metavar="FILE", help="write an MP4 (needs ffmpeg on PATH)")
    replay.add_argument("--gui", action="store_true", help="open the pybullet GUI (needs a display)")
    replay.add_argument("--report", metavar="FILE", help="write the replay report as JSON")
    replay.add_argument("--drift-mm", type=float, default=5.0, metavar="X", help="largest allowed object drift, mm (default 5)")
    replay.add_argument("--drift-deg", type=float, default=5.0, metavar="Y", help="largest allowed object rotation, deg (default 5)")
    replay.add_argument("--gravity", type=float, nargs=3, metavar=("GX", "GY", "GZ"),
                        help="gravity in the palm frame, m/s^2 (default: palm facing down, along the hand's palm_normal)")
    replay.add_argument("--gravity-set", type=int, choices=GRAVITY_SET_SIZES, metavar="N",
                        help="replay under N gravity directions of the palm frame with a verdict per direction: "
                             "1 palm down, 2 and palm up, 6 and the four sideways directions, 7 and gravity off")
    replay.set_defaults(func=_cmd_replay)
    return parser


def _has_command(name: str) -> bool:
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return name in sub.choices


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except NoSequenceError as err:
        print(f"regrasp {args.command}: {err}", file=sys.stderr)
        return 1
    except PlannerError as err:
        print(f"regrasp {args.command}: error: {err}", file=sys.stderr)
        return 2
