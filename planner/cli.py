"""Command line: `regrasp` and `python -m planner`.

A `PlannerError` becomes one line on stderr and exit code 2 (bad input) or the
command's own failure code; any other exception is a bug and shows its traceback.
Here: the parser, the checks of the arguments before any work, and ``main``; the
commands themselves are `planner.commands` (and ``demo``, below, which runs them).
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import signal
import sys
import tempfile
import threading
import warnings
from pathlib import Path

import planner
from planner import commands
from planner.errors import NoSequenceError, PlannerError, PlannerWarning, one_line
from planner.fileio import check_outputs
from planner.gravity import GRAVITY_NAMES, GRAVITY_SET_SIZES, gravity_name_error
from planner.options import MOTION_CHECKS
from planner.resources import bundled_grasp

DEMO_INITIAL = "icub/cylinder_parallel_extension.yaml"  # bundled grasps (planner.resources)
DEMO_FINAL = "icub/cylinder_ir2m.yaml"
DEMO_OUT = "regrasp-demo"
#: --engine of plan and replay (`planner.options.VERIFY_ENGINES`, written out: --help loads nothing).
ENGINE_CHOICES = ("pybullet", "mujoco", "both")
_ENGINE_DEFAULT = "pybullet when installed, else mujoco"


def _cmd_demo(args: argparse.Namespace) -> int:
    """Plan the bundled cylinder example (parallel extension -> IR2M) for execution and
    replay it under the six gravity directions it was planned for, and gravity off.
    Here, not in `planner.commands`: it runs the other commands through `main`."""
    if not args.out:  # Path("") is the current folder: an empty variable wrote the demo there
        raise PlannerError(f"--out: an empty name; name a directory for the demo's outputs (default ./{DEMO_OUT}/)")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise PlannerError(f"--out {out}: exists and is not a directory; name a directory for the demo's outputs")
    if out.is_symlink() and not out.exists():
        raise PlannerError(f"--out {out}: a symbolic link to nothing (broken, or a loop); name a directory")
    if not out.exists() and not out.absolute().parent.is_dir():  # a typo is not a new folder (as every -o)
        raise PlannerError(f"--out {out}: folder {out.absolute().parent} does not exist; create it first")
    try:
        out.mkdir(exist_ok=True)
    except OSError as err:  # a symlink loop, a read-only folder
        raise PlannerError(f"--out {out}: cannot create the folder: {err.strerror or err}") from None
    plan_path = out / "cylinder_plan.yaml"
    # execution mode: one mean contact per finger (the simulator's rigid fingertips), every
    # state holds the weight in six hand orientations with 3/4 of the friction, least grip
    # ranked first (the box pair needs more friction palm up: execution mode refuses it)
    code = main(["plan", str(bundled_grasp(DEMO_INITIAL)), str(bundled_grasp(DEMO_FINAL)), "-o", str(plan_path),
                 "--execution"])
    if code != 0:
        return code
    # the demo's exit code is the replay's (1 when any direction fails); the GIF is palm down,
    # drawn by pybullet: without it (Python >= 3.12 has no wheel) the replay runs unfilmed
    from planner.sim.engine import default_engine, engine_installed

    film = engine_installed("pybullet")
    print(f"\nreplaying {plan_path} in {default_engine()} under 7 gravity directions"
          + (" (palm down filmed)" if film else " (not filmed: the GIF is drawn by pybullet, not installed)"))
    verdict = main(["replay", str(plan_path), "--gravity-set", "7", "--report", str(out / "cylinder_report.json")]
                   + (["--gif", str(out / "cylinder_replay.gif"), "--film", "palm_down"] if film else []))
    # the interactive 3D page of the plan, with the replay's contacts and drift (regrasp view)
    main(["view", str(plan_path), "-o", str(out / "cylinder_plan.html"), "--report", str(out / "cylinder_report.json")])
    print(f"demo outputs in {out}/: cylinder_plan.yaml, cylinder_plan.html, "
          + ("cylinder_replay_palm_down.gif, " if film else "")
          + f"cylinder_report.json (replay {'passed' if verdict == 0 else 'did not pass'})")
    return verdict


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="regrasp", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"regrasp {planner.__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="plan and replay the bundled cylinder example")
    demo.add_argument("--out", default=DEMO_OUT, metavar="DIR",
                      help=f"directory for the plan, GIFs and report (default: ./{DEMO_OUT}/)")
    demo.set_defaults(func=_cmd_demo)

    check = sub.add_parser("check", help="realize one grasp file and report its contacts and force closure")
    check.add_argument("grasp", help="grasp YAML")
    check.add_argument("--json", action="store_true", help="machine-readable output")
    check.add_argument("--png", metavar="FILE", help="render the hand holding the object (headless)")
    check.add_argument("--gravity", action=_GravityArgument, default=None,
                       help="report the load held under this gravity only (palm frame, m/s^2, or a NAME: "
                            + _GRAVITY_NAMES_HELP + ") instead of the six directions of execution mode, and "
                            "exit 1 unless plan --execution --gravity accepts the grasp under it (as --execution)")
    check.add_argument("--execution", action="store_true",
                       help="exit 1 unless plan --execution accepts the grasp as an initial or final grasp: force "
                            "closure with one contact per touching link and twice the weight held in each of the six "
                            "hand orientations within the joints' torque limits (the failing direction and joint named), "
                            "then held in a physics engine from the start, as plan --execution replays an initial grasp (--no-verify "
                            "skips it; a plan arriving at a grasp that fails here may still hold it as its final grasp)")
    check.add_argument("--no-verify", action="store_true",
                       help="with --execution or --gravity: the static test alone, no replay in a physics engine")
    check.add_argument("--engine", default=None, choices=ENGINE_CHOICES,
                       help="with --execution or --gravity: the physics engine that holds the grasp (default: "
                            + _ENGINE_DEFAULT + "); both: it must hold in pybullet and in mujoco")
    check.set_defaults(func=commands.cmd_check)

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
    plan.add_argument("--time-limit", type=float, default=None, metavar="S",
                      help="an optional cap on the search time, s (default none: the work bounds end the search, "
                           "so the result does not depend on the machine's load; finger paths not counted; reaching "
                           "a cap is reported: the result then depends on the machine's speed); 0: no rounds")
    plan.add_argument("--strategy", default="graph", help="graph (ranked search, default) or greedy (thesis Algorithm 2)")
    plan.add_argument("--seed", type=int, default=0, help="seed for sampling and motion planning (default 0)")
    plan.add_argument("--contact-model", default=None, metavar="MODEL",
                      help="closure from every patch point (patch, default: the thesis) or from one mean contact "
                           "per finger (mean: what the simulator's rigid fingertips give; --execution's)")
    plan.add_argument("--max-lifted", type=int, default=None, metavar="N", help="at most N fingers lifted at once")
    plan.add_argument("--gravity", action=_GravityArgument, default=None,
                      help="also require every state to hold twice the object's weight under this gravity (palm "
                           "frame, m/s^2, e.g. 0 0 9.81 palm down, or a NAME: " + _GRAVITY_NAMES_HELP + ") within "
                           "the hand's joint torque limits")
    plan.add_argument("--gravity-set", type=int, default=None, choices=GRAVITY_SET_SIZES, metavar="N",
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
                           "--gravity-set is given) and --rank grip, and verify the plan in a physics engine (--engine)")
    plan.add_argument("--verify-attempts", type=int, default=None, metavar="N",
                      help="with --execution: sequences replayed at most before the plan is refused (a bound on "
                           "the work, default 6): for the gaits at the grasps' shared pose, and as many again for "
                           "the plans that move the object (all their candidate poses together)")
    plan.add_argument("--no-verify", action="store_true",
                      help="with --execution: return the best sequence without replaying it in a physics engine first")
    plan.add_argument("--engine", default=None, choices=ENGINE_CHOICES,
                      help="with --execution: the physics engine that verifies the plan (default: " + _ENGINE_DEFAULT
                           + "); both: returned only if it holds in pybullet and in mujoco")
    plan.add_argument("--no-repose", action="store_true",
                      help="never move the object (no reposing moves): the grasps must share the object's pose and "
                           "only finger gaits are planned")
    plan.add_argument("--no-motion", action="store_true", help="skip OMPL finger paths (straight joint segments)")
    plan.add_argument("--motion-planner", default="rrtconnect", help="OMPL planner name (default rrtconnect)")
    plan.add_argument("--motion-checks", type=int, default=MOTION_CHECKS, metavar="N",
                      help="work bound per finger path: OMPL's collision checks (not a time, so the plan does not "
                           "depend on the machine's load)")
    plan.add_argument("-v", "--verbose", action="store_true",
                      help="show the motion planner's and the C++ libraries' console output and every warning")
    plan.set_defaults(func=commands.cmd_plan)
    synth = sub.add_parser("synth", help="generate force-closure grasp files for a hand and an object")
    synth.add_argument("hand", help="hand name under robots/ (icub_right, allegro_right) or a hand.yaml")
    synth.add_argument("object", help="object YAML: the object: block of a grasp file (shape, size[, position, "
                                      "quat_xyzw, mass_kg, mesh]); without position the object pose is sampled too")
    synth.add_argument("--fingers", default=None,
                       help="comma-separated fingers that grasp, e.g. thumb,index,middle (default: a tripod, the "
                            "thumb and the hand's next two fingers; without a thumb its first three; with --palm all)")
    synth.add_argument("-n", type=int, default=20, help="grasps to write (default 20)")
    synth.add_argument("-o", "--output", required=True, metavar="DIR", help="folder for the grasp files (never overwritten)")
    synth.add_argument("--gravity", action=_GravityArgument, default=None,
                       help="keep grasps that hold twice the weight under this gravity (palm frame, m/s^2, or a "
                            "NAME: " + _GRAVITY_NAMES_HELP + ") within the hand's joint torque limits")
    synth.add_argument("--max-finger-force", type=float, default=None, metavar="N",
                       help="with --gravity: an extra cap on every finger's normal force, N (default none)")
    synth.add_argument("--seed", type=int, default=0, help="seed (default 0); same seed, same files")
    synth.add_argument("--mu", type=float, default=None, help="friction coefficient (default: the object file's, else 0.9)")
    synth.add_argument("--gamma", type=float, default=None, help="torsional friction, m (default: the object file's, else 0.004)")
    synth.add_argument("--max-attempts", type=int, default=None, metavar="K", help="candidates sampled at most (default 60 n)")
    synth.add_argument("--palm", action="store_true",
                       help="whole-hand grasps: the object against the palm, which holds too (files say palm: hold); "
                            "with every finger by default (power grasps); a fixed position must touch the palm")
    synth.add_argument("--workers", type=int, default=1, metavar="K",
                       help="processes running attempts (default 1); the files do not depend on it")
    synth.add_argument("--no-verify", action="store_true",
                       help="do not hold the grasps execution mode's static test accepts in a physics engine (as "
                            "plan --execution replays an initial grasp; those that drop are ranked after the others, "
                            "a plan arriving at one may still end in it)")
    synth.add_argument("--engine", default=None, choices=ENGINE_CHOICES,
                       help="the physics engine that holds the grasps (default: " + _ENGINE_DEFAULT + ")")
    synth.add_argument("-q", "--quiet", action="store_true", help="no progress line on stderr")
    synth.set_defaults(func=commands.cmd_synth)
    replay = sub.add_parser("replay", help="execute a plan in a physics engine with gravity on and check the object "
                                           "stays put")
    replay.add_argument("plan", help="plan file (.yaml/.yml or .json)")
    replay.add_argument("--engine", default=None, choices=ENGINE_CHOICES,
                        help="physics engine (default: " + _ENGINE_DEFAULT + "); both: replay in each, pass only if "
                             "both pass (films: FILE_<engine>.gif)")
    replay.add_argument("--gif", metavar="FILE", help="write an animated GIF (headless TinyRenderer)")
    replay.add_argument("--gif-every", type=int, default=8, metavar="N", help="one GIF frame every N physics steps (default 8)")
    replay.add_argument("--mp4", metavar="FILE", help="write an MP4 (needs ffmpeg on PATH)")
    replay.add_argument("--gui", action="store_true", help="open the pybullet GUI (needs a display; --engine pybullet)")
    replay.add_argument("--report", metavar="FILE", help="write the replay report as JSON")
    replay.add_argument("--strict", action="store_true",
                        help="refuse a plan whose recorded input files changed or are gone (default: a warning)")
    replay.add_argument("--drift-mm", type=float, default=5.0, metavar="X", help="largest allowed object drift, mm (default 5)")
    replay.add_argument("--drift-deg", type=float, default=5.0, metavar="Y", help="largest allowed object rotation, deg (default 5)")
    replay.add_argument("--gravity", action=_GravityArgument,
                        help="gravity in the palm frame, m/s^2, or a NAME: " + _GRAVITY_NAMES_HELP + " (default: "
                             "palm facing down, along the hand's palm_normal)")
    replay.add_argument("--gravity-set", type=int, choices=GRAVITY_SET_SIZES, metavar="N",
                        help="replay under N gravity directions of the palm frame with a verdict per direction: "
                             "1 palm down, 2 and palm up, 6 and the four sideways directions, 7 and gravity off")
    replay.add_argument("--workers", type=int, default=None, metavar="N",
                        help="with --gravity-set: replay the directions in N processes (default: the cores "
                             "available; the verdicts are those of a serial run)")
    replay.add_argument("--film", metavar="NAMES",
                        help="with --gravity-set and --gif/--mp4: film only these directions (comma-separated, "
                             "e.g. palm_down; default all, one file per direction)")
    replay.set_defaults(func=commands.cmd_replay)
    verify = sub.add_parser("verify", help="check a plan against physics and its inputs, without simulation: "
                                           "contacts on the surface and at the joints' kinematics, paths free, "
                                           "the chain from the initial to the final grasp")
    verify.add_argument("plan", help="plan file (.yaml/.yml or .json)")
    verify.add_argument("--strict", action="store_true",
                        help="refuse a plan whose recorded input files changed or are gone (default: a warning)")
    verify.set_defaults(func=commands.cmd_verify)
    hand = sub.add_parser("hand", help="your own hand: write a hand.yaml from a URDF (init), check one (check)")
    hsub = hand.add_subparsers(dest="hand_command", required=True)
    hinit = hsub.add_parser("init", help="infer fingers, tips, pads, closing joints and the palm normal from a URDF")
    hinit.add_argument("urdf", help="the hand's URDF")
    hinit.add_argument("-o", "--output", required=True, metavar="FILE", help="the hand.yaml to write")
    hinit.add_argument("--package-dir", action="append", metavar="DIR",
                       help="a folder holding the ROS packages of package:// mesh paths (repeatable)")
    hinit.add_argument("--root", metavar="LINK",
                       help="the hand is the sub-tree below this link of a robot's URDF (written beside the "
                            "hand.yaml as its URDF); a robot's URDF without it is refused with its hands listed")
    hcheck = hsub.add_parser("check", help="report what a planner or simulator cannot use in a hand, one line each")
    hcheck.add_argument("hand", help="a bundled hand's name or a hand.yaml")
    hand.set_defaults(func=commands.cmd_hand)
    view = sub.add_parser("view", help="write an interactive 3D page (one offline HTML file) of a plan or a grasp")
    view.add_argument("source", help="plan file (.yaml/.yml/.json) or grasp YAML")
    view.add_argument("-o", "--output", required=True, metavar="FILE", help="the page to write (.html)")
    view.add_argument("--report", metavar="FILE", help="replay report (regrasp replay --report) shown next to the plan")
    view.add_argument("--gif", metavar="FILE", help="also a 640x480 GIF: captions, contacts, the moving finger coloured")
    view.set_defaults(func=commands.cmd_view)
    parsers = [c for n, c in sub.choices.items() if n not in ("synth", "hand")] + [hinit, hcheck]
    for cmd in parsers + [synth]:  # -q/--quiet and -v/--verbose on every command
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
#: Exit code of an interrupted command (128 + SIGINT) and of a closed stdout (128 + SIGPIPE); a
#: terminated or hung-up one exits 128 + its signal (`Terminated.signum`: 143, 129).
EXIT_INTERRUPTED = 130
EXIT_BROKEN_PIPE = 141


class Terminated(KeyboardInterrupt):
    """SIGTERM (``kill PID``, ``timeout``) as Ctrl-C: the command unwinds as it does on Ctrl-C
    (worker and helper processes stopped, temporary files removed, no output written), then
    exits 143. A KeyboardInterrupt, so that every clean-up for Ctrl-C runs for it too."""

    signum = signal.SIGTERM
    words = "terminated"


class HungUp(Terminated):
    """SIGHUP (the terminal or the ssh session closed) as SIGTERM: exit 129. Not where the
    command started with SIGHUP ignored (``nohup``): it runs on."""

    signum = getattr(signal, "SIGHUP", signal.SIGTERM)
    words = "hung up (the terminal closed)"


@contextlib.contextmanager
def _sigterm_unwinds():
    """While the outermost command runs, SIGTERM raises `Terminated` in this process. Without
    it, the process died at once and the processes it had forked (the gait search's helper,
    the replays' workers) lived on, holding the caller's pipes open. A forked child (which
    inherits the handler) still dies of it at once, as before."""
    if threading.current_thread() is not threading.main_thread():  # (handlers are set there only)
        yield
        return
    pid = os.getpid()

    def handler(signum, _frame):
        if os.getpid() != pid:  # a forked worker: die of the signal, as without this handler
            signal.signal(signum, signal.SIG_DFL)
            os.kill(os.getpid(), signum)
            return
        if _unwinding():  # a repeat (`timeout` signals the process and its group) while the command unwinds
            return
        raise HungUp if signum == HungUp.signum else Terminated

    old = signal.signal(signal.SIGTERM, handler)
    hup = getattr(signal, "SIGHUP", None)
    old_hup = signal.getsignal(hup) if hup is not None else None
    if old_hup is not None and old_hup != signal.SIG_IGN:  # (nohup: the command outlives the terminal)
        signal.signal(hup, handler)
    else:
        old_hup = None
    # the redelivery's timer, unless the caller (a program running main()) has one of its own:
    # its alarm was swallowed by `_raise_dropped` and its timer cancelled when main() returned
    timer = hasattr(signal, "setitimer") and signal.getitimer(signal.ITIMER_REAL) == (0.0, 0.0) \
        and signal.getsignal(signal.SIGALRM) in (signal.SIG_DFL, signal.SIG_IGN)
    old_alarm = signal.signal(signal.SIGALRM, _raise_dropped) if timer else None
    old_hook = sys.unraisablehook
    sys.unraisablehook = _redeliver_interrupts(old_hook, timer)
    try:
        yield
    finally:
        sys.unraisablehook = old_hook
        if old_alarm is not None:
            signal.setitimer(signal.ITIMER_REAL, 0)
            _DROPPED.clear()
            signal.signal(signal.SIGALRM, old_alarm)
        if old_hup is not None:
            signal.signal(hup, old_hup)
        signal.signal(signal.SIGTERM, old)


#: The interrupt (`Terminated` or KeyboardInterrupt) Python dropped, raised again by `_raise_dropped`.
_DROPPED: list[type[BaseException]] = []
#: How soon a dropped interrupt is raised again (s): past the callback or finalizer that dropped it.
_REDELIVER_S = 0.005


def _unwinding() -> bool:
    """Whether the command is already unwinding for an interrupt (the clean-up of a Ctrl-C, a
    SIGTERM or a hang-up runs in an ``except``/``finally``/``__exit__``, which Python runs with
    it as the exception handled): another one raised there would cut the clean-up short (the
    replays' workers not told to stop, the pool waiting for them)."""
    return isinstance(sys.exc_info()[1], KeyboardInterrupt)


def _raise_dropped(_signum, _frame) -> None:
    """SIGALRM's handler while a command runs: raise the interrupt Python dropped (not when
    another one has been raised since: the command is unwinding for it)."""
    if _DROPPED:
        stop = _DROPPED.pop()
        if not _unwinding():
            raise stop()


def _redeliver_interrupts(fallback, timer: bool = True):
    """An unraisable-exception hook that raises a Ctrl-C or SIGTERM again when Python dropped
    the exception its handler raised: a signal's handler runs wherever the interpreter is, and
    where that is inside a fork's callback (`os.register_at_fork`: logging's lock release after
    each fork), a finalizer or a weakref callback, the exception is printed and dropped
    ("Exception ignored in ...") and the command ran on to exit 0 with its output written. It is
    raised again a few milliseconds later (a timer's signal: raised from here, it would be raised
    inside the hook, and dropped again), where the command runs. Other exceptions go to
    ``fallback``, and every one without ``timer`` (SIGALRM is not ours: the caller's timer runs)."""

    def hook(unraisable) -> None:
        exc = unraisable.exc_value
        if not isinstance(exc, KeyboardInterrupt) or not timer:
            fallback(unraisable)
            return
        _DROPPED[:] = [type(exc) if isinstance(exc, Terminated) else KeyboardInterrupt]
        signal.setitimer(signal.ITIMER_REAL, _REDELIVER_S)

    return hook


class _Parser(argparse.ArgumentParser):
    """argparse with its errors as one line (no usage block) and exit code 2; ``--gravity``
    takes 3 numbers or one name (`_GravityArgument`)."""

    def error(self, message: str):
        message = one_line(str(message).strip())  # a user's option may hold a line break or an escape
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")

    def parse_known_args(self, args=None, namespace=None):
        if args is None:
            args = sys.argv[1:]
        if isinstance(self._option_string_actions.get("--gravity"), _GravityArgument):
            args = _gravity_name_explicit(list(args))
        return super().parse_known_args(args, namespace)

    def _get_nargs_pattern(self, action):
        if isinstance(action, _GravityArgument):
            return "(A(?:AA)?)"  # 3 values when 3 follow, else 1 (a name, made explicit: --gravity=NAME)
        return super()._get_nargs_pattern(action)


#: The names of ``--gravity NAME`` in the help (`planner.gravity.GRAVITY_NAMES`).
_GRAVITY_NAMES_HELP = "palm_down, palm_up, side_+x ... side_-z, thumb_up, thumb_down, fingers_up, fingers_down, off"


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _gravity_name_explicit(args: list[str]) -> list[str]:
    """``--gravity NAME`` as ``--gravity=NAME``: one value, so the positionals after a name
    stay positionals (3 numbers take the 3 tokens after the option, as before)."""
    out = []
    i = 0
    while i < len(args):
        a = args[i]
        if a == "--":
            return out + args[i:]
        if a == "--gravity" and i + 1 < len(args) and not args[i + 1].startswith("-") and not _is_number(args[i + 1]):
            out.append(f"--gravity={args[i + 1]}")
            i += 2
            continue
        out.append(a)
        i += 1
    return out


class _GravityArgument(argparse.Action):
    """``--gravity GX GY GZ`` (a list of 3 floats, as ``type=float, nargs=3`` gave) or
    ``--gravity NAME`` (the name, a str, resolved against the hand by the command:
    `planner.gravity.named_gravity`); anything else is one line naming the choices."""

    def __init__(self, option_strings, dest, **kwargs):
        super().__init__(option_strings, dest, nargs=3, metavar=("GX", "GY", "GZ"), **kwargs)

    def __call__(self, parser, namespace, values, option_string=None):
        if len(values) == 3:
            out = []
            for v in values:
                try:
                    out.append(float(v))
                except ValueError:
                    raise argparse.ArgumentError(self, f"invalid float value: {v!r}") from None
            setattr(namespace, self.dest, out)
        elif len(values) == 1 and values[0] in GRAVITY_NAMES:
            setattr(namespace, self.dest, values[0])
        else:
            parser.error(gravity_name_error())


def _option_name(dest: str) -> str:
    return "--" + dest.replace("_", "-")


def option_limits() -> dict:
    """Every numeric option's range by argparse dest: the planner's (`PlanOptions`'s
    table under its option names) and `OPTION_LIMITS`."""
    from planner.options import PLAN_OPTION_FLAGS, PLAN_OPTION_LIMITS  # deferred: scipy, networkx (~0.25 s)

    return {**{PLAN_OPTION_FLAGS.get(k, k): v for k, v in PLAN_OPTION_LIMITS.items()}, **OPTION_LIMITS}


def _validate(args: argparse.Namespace) -> None:
    """Numeric ranges (`option_limits`) and output paths, before any work."""
    from planner.options import in_range, option_range  # deferred: scipy, networkx (~0.25 s)

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
    check_outputs(outputs, inputs, formats=False)
    # the files a command derives from these (a film per gravity direction) and the files its
    # inputs name (a plan's grasps, hand, URDF, meshes) are checked once the inputs are read
    # (`planner.fileio.check_outputs`, with the pictures' and films' suffixes: an input named
    # like a picture is said to be an input), before any work


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
                _quiet_stderr(verbose or _DEPTH > 1) as noise, \
                (_sigterm_unwinds() if _DEPTH == 1 else contextlib.nullcontext()):
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
    except KeyboardInterrupt as stop:
        if _DEPTH > 1:  # a step of the demo: the demo stops (it went on to its next step)
            raise
        if isinstance(stop, Terminated):
            with contextlib.suppress(OSError):  # (a closed terminal: the line goes nowhere)
                _say(f"{prefix}: {stop.words}")
            return 128 + stop.signum
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


#: Longest line a message prints, a backstop: values from files are shortened where they are
#: quoted (`planner.fileio.repr_short`, `describe`, `shown`); a refusal's explanation in words
#: runs to about 2 000 characters and is never cut.
MAX_LINE_CHARS = 20_000


def _say(line: str) -> None:
    """One line on stderr, whatever the message holds (newlines in names included; other
    control characters, e.g. a terminal escape in a file name, shown escaped), at most
    `MAX_LINE_CHARS` long (the middle of a longer one left out, and said so)."""
    text = one_line(" ".join(line.split("\n")).replace("\r", " "))
    if len(text) > MAX_LINE_CHARS:
        cut = len(text) - MAX_LINE_CHARS + 40
        head = (MAX_LINE_CHARS - 40) * 2 // 3
        text = f"{text[:head]} [... {cut} characters ...] {text[head + cut:]}"
    print(text, file=sys.stderr)


class _Noise:
    keep = False  # a bug's traceback keeps what the libraries printed before it


@contextlib.contextmanager
def _progress(prefix: str, fd: int | None, quiet: bool):
    """The ``planner`` logger's INFO records (a long plan's rounds, paths, replays) as lines
    on the terminal while a command runs: only when stderr is a terminal, never with -q."""
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
