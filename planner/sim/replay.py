"""Execute a regrasp plan in a physics engine with gravity on and check that the object stays put.

The replay talks to the engine only through `planner.sim.engine.PhysicsEngine` (pybullet:
`planner.sim.engine_pybullet`, which says how the plan's friction is set there); the grasp
controller (`planner.sim.controller`) is engine-free.

The palm is fixed and the world frame IS the palm frame, so every pose, point and the
gravity vector of this module are palm-frame quantities. Default gravity is +z of the
palm, ``(0, 0, +9.81)``: the palm faces DOWN and gravity pulls the object away from the
grasping face. The object then rests on nothing but the fingers' contacts, which is the
case the force-closure guarantee is about: lift a non-removable finger and the object
falls. (With gravity along -z the object would fall into the palm and a bad gait could
still look fine.) Pass any other vector to test another hand orientation.

Sequence (thesis section VII / IX):
  1. hand joints reset to ``states[0].q``; the object is held at its planned pose by a
     fixed constraint while the touching fingers squeeze;
  2. the constraint is released with gravity on and the grasp settles;
  3. every step drives its finger along ``step.path`` (position control, bounded joint
     torque) while the touching fingers keep squeezing. Before a lift, the other fingers
     take the lifted state's forces for ``UNLOAD_S`` while the lifting finger only holds
     its posture (it is unloaded, then lifted); during a land, the other fingers keep the
     forces that balance the object without the landing finger, which switches from the
     free-motion torque to its squeeze torque within ``LANDING_ZONE_M`` of the object;
     at the end of the path every finger takes the new state's targets. A reposing step
     (``action: repose``, plan schema 4) lifts nothing: every touching finger keeps holding
     while all their joints follow ``step.path`` together (offset by the grip each is
     latched at), and the force balance, solved at the simulator's contacts, follows the
     object, the palm carrying none of it while the object moves relative to it (its share
     handed over to the fingers before, and back after the object rests on it); at its end
     they latch where they touch;
  4. drift is measured from the PLANNED pose: the current state's (`planner.plan_data
     .PlanState.object_pose`, else the plan's ``object`` pose), and during a reposing step
     the pose along its ``object_path`` at the fraction of the waypoint the joints are at;
  5. at every state, the engine's contact points (one raw sample per simulation
     step) go through the temporal filter (`planner.sim.contact_filter`), are expressed
     in the object frame with normals INTO the object, grouped by finger, and the force
     closure and metric are recomputed with `planner.closure.grasp_closure`, under the
     plan's contact model (``parameters.contact_model``: every point, or one mean contact
     per finger).

Squeeze (grasp force optimization). At every state the contact of each touching finger
(its link nearest the object at the planned pose) gets a force ``f_i`` chosen so the object
is in equilibrium under gravity: ``min sum |f_i - F n_i|_1`` subject to the net wrench
balancing ``m g``, every ``f_i`` inside half the friction cone (then 3/4, then the whole
cone if needed; at each step point forces first, then with the soft-finger torsion that
the simulator's torsional friction provides: `planner.grip.CONE_MARGINS`), no
component above ``MAX_FORCE_RATIO * F`` and a normal force of at least ``MIN_NORMAL_RATIO * F``
(``F = finger_force_n``; `planner.sim.controller.balance_forces`). Plain normal squeezing is kept only when no balanced forces exist
at those contacts. The finger then presses with joint torques ``tau = J_f^T f_i``
(``J_f``: linear Jacobian of the contact point over the finger's joints): its position
target lies ``squeeze_m`` beyond the contact along ``tau`` and each joint's torque is
capped at ``|tau_j|`` (at least a small holding torque), so the motors saturate against
the object and press with ``tau``.

Friction. Every finger-object contact gets exactly the plan's ``mu`` (Coulomb) and ``gamma``
(torsional, metres) of the soft-finger model (thesis eq. 1); how an engine combines the two
bodies' friction to give it is the engine module's business (`planner.sim.engine.World`).

This module is one concept, kept whole: the replay loop and its verdict share the per-state
measurements, and split apart either half would only read the other's state.
"""

from __future__ import annotations

import math
import multiprocessing
import os
import shutil
import time
from collections.abc import Mapping

import numpy as np
from scipy.spatial.transform import Rotation

from planner.closure import apply_contact_model, grasp_closure
from planner.errors import InputError, SimulationError
from planner.model import PALM
from planner.plan_data import object_still, pose_between
from planner.sim.contact_filter import ContactFilter
from planner.sim.controller import BACK_OFF_ITERATIONS, TOUCH_TOL_M, Controller
from planner.sim.engine import PhysicsEngine, default_engine, engine_for
from planner.sim.inputs import HandInfo, load_hand_info, object_mass, replay_world, typed_plan
from planner.sim.report import CouplingError, ReplayReport, StateReport

#: A finger (or the palm) carries the object when it presses with a mean normal force of at
#: least this share of the larger of the object's weight and the controller's squeeze: every
#: holding finger is commanded at least half the squeeze (`planner.sim.controller
#: .MIN_NORMAL_RATIO`), so a tenth of it is a touch that takes part of the load, not a graze.
CARRY_SHARE = 0.1
#: The replay records the hand's joints and the object's pose this often (simulated s) for
#: `view --report` to play what the simulator did (a drop is seen as a drop).
TRAJECTORY_DT_S = 1.0 / 30.0


# --------------------------------------------------------------------------- helpers


def _T(pos, quat_xyzw) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(quat_xyzw).as_matrix()
    T[:3, 3] = pos
    return T


def lift_path(start: np.ndarray, path: np.ndarray) -> np.ndarray:
    """The waypoints a lifting finger follows: its planned retreat, started from where the
    finger touches now rather than from the planned contact (the object may have moved a
    little, and the planned contact configuration is then inside it: the way there would
    push the object), the offset fading out along the retreat so that it ends where the
    plan's does. (m + 1, n) for a planned (m, n) path."""
    start, path = np.asarray(start, float), np.asarray(path, float)
    if not len(path):
        return start[None, :]
    fade = np.linspace(1.0, 0.0, len(path))[:, None]
    return np.vstack([start[None, :], path + fade * (start - path[0])])


def pose_drift(pos_ref, quat_ref, pos, quat) -> tuple[float, float]:
    """(translation mm, rotation deg) of a pose relative to a reference, positions in m and
    unit quaternions (x, y, z, w): the angle of the relative rotation is 2 acos |q_ref . q|.
    Plain floats: the replay measures it every physics step."""
    dot = abs(sum(a * b for a, b in zip(quat, quat_ref)))
    return 1000.0 * math.dist(pos, pos_ref), math.degrees(2.0 * math.acos(min(1.0, dot)))


# --------------------------------------------------------------------------- replay


class StopLine:
    """The replays of one plan in several directions, in an order (a verification's: the
    directions that rejected a sequence before first, then the others as listed), shared by
    them (in one process or in forked workers: `planner.sim.verify.verify_plan`). The first
    of them in that order to fail decides: a replay failing marks its place (`fail`), the
    replays after it stop at their next measured state, unfailed (`stopped`,
    `ReplayReport.stopped_after`), the ones before it run to their end. Which replay decides
    depends on the order only, never on which of them ran first or faster. ``at(i)`` is the
    same line seen from place ``i``; a new line is place 0."""

    NONE = 2 ** 31 - 1

    def __init__(self, place: int = 0, value=None) -> None:
        if value is None:
            methods = multiprocessing.get_all_start_methods()
            value = multiprocessing.get_context("fork" if "fork" in methods else None).Value("i", self.NONE)
        self.place, self._value = int(place), value

    def at(self, place: int) -> "StopLine":
        """This line seen by the replay at ``place`` in the order."""
        return StopLine(place, self._value)

    def first(self) -> int:
        """The place of the first replay in the order that failed so far (`NONE`: none)."""
        return int(self._value.value)

    def fail(self) -> None:
        """The replay at this place failed: the ones after it stop."""
        with self._value.get_lock():
            self._value.value = min(int(self._value.value), self.place)

    def stopped(self) -> bool:
        """Whether a replay before this place failed (this one's verdict cannot decide)."""
        return self.first() < self.place


def replay_plan(
    plan: Mapping | str | os.PathLike,
    *,
    client: int | None = None,
    gui: bool = False,
    hand=None,
    dt: float = 1.0 / 240.0,
    gravity: tuple[float, float, float] | None = None,
    acquire_s: float = 0.3,
    ramp_s: float = 0.5,
    settle_s: float = 0.25,
    handover_s: float = 0.15,
    dwell_s: float = 0.25,
    joint_speed_rad_s: float = 1.5,
    finger_force_n: float | None = None,
    solver_iterations: int = 150,
    drift_mm_max: float = 5.0,
    drift_deg_max: float = 5.0,
    drop_mm: float = 30.0,
    filter_k: int = 12,
    density_kg_m3: float = 500.0,
    gif: str | os.PathLike | None = None,
    gif_every: int = 8,
    mp4: str | os.PathLike | None = None,
    width: int = 640,
    height: int = 480,
    strict: bool = False,
    engine: str | None = None,
    stop_at_failure: "bool | StopLine" = False,
    snapshots: tuple[str, int] | None = None,
) -> ReplayReport:
    """Replay a plan in a physics engine with gravity on; re-measure contacts, closure and drift.

    Args:
        plan: plan data (the schema of docs/INTERFACES.md) or a plan file (.yaml/.json)
            (or a plan this module has already read).
        client: (pybullet) an existing client id; the replay adds its bodies there and removes
            them at the end. None: a private DIRECT (or GUI) client, disconnected at the end.
        gui: open the engine's window (needs a display) and run in real time.
        hand: a `planner.hand.Hand` to use instead of loading the plan's ``hand``.
        dt: physics time step, s.
        gravity: gravity vector in the palm (= world) frame, m/s^2. None: palm down, 9.81
            along the hand's ``palm_normal`` (the object hangs from the fingers);
            `planner.gravity` names the other directions.
        acquire_s: time the fingers take their planned contacts with gravity off while the
            object is held at its planned pose, s.
        ramp_s: time over which gravity rises from 0 after the object is released, s.
        settle_s: time after the ramp before state 0 is measured, s.
        handover_s: time over which a finger's load fades out before it lifts, and in after
            it lands, s.
        dwell_s: time spent at every state after its step, before measuring it, s.
        joint_speed_rad_s: largest joint speed along a step's path, rad/s.
        finger_force_n: the squeeze force per holding finger, N; None derives it from the
            object's weight and friction (`planner.sim.controller.squeeze_force_n`).
        solver_iterations: contact solver iterations per step (pybullet's numSolverIterations).
        drift_mm_max, drift_deg_max: pass thresholds on the object's drift.
        drop_mm: displacement beyond which the object counts as dropped; the replay stops.
        filter_k: contact filter: a contact is removed after this many missing samples.
        density_kg_m3: density used when the plan gives no ``object.mass_kg``.
        gif: write an animated GIF here (TinyRenderer, headless; drawn like `regrasp view
            --gif`: contact-seeing camera, the simulator's contacts, the moving finger
            coloured, a caption per frame), playing at the simulation's speed.
        gif_every: render one frame every this many physics steps (a GIF alone: frames at
            least 20 ms of simulated time apart, the shortest delay GIF viewers show).
        mp4: write an MP4 here (needs ``ffmpeg`` on PATH), every rendered frame.
        width, height: frame size in pixels.
        strict: a plan file whose recorded inputs changed or are gone is refused
            (`planner.plan.read_plan`'s ``strict``) instead of a warning.
        engine: the physics engine (`planner.sim.engine.engine_for`): "pybullet" or "mujoco";
            None: `planner.sim.engine.default_engine` (pybullet when installed, else MuJoCo).
        stop_at_failure: stop after the first state measured once the replay has failed (the
            drift left its limits, or the state is not held as planned): the verdict's failed
            step and whether it failed at the state are those of the whole replay (the
            simulation is the same up to there); the later states are reported not reached.
            For a caller that needs the verdict only (the planner's verification). A
            `StopLine` shared by the replays of one plan in other directions also stops this
            one, unfailed, at its next measured state once a replay before it in their order
            has failed (``stopped_after``: its verdict cannot decide).
        snapshots: the open `planner.sim.snapshots.scope` (`planner.sim.snapshots.current`)
            of a verification: with ``stop_at_failure``, in a worker process, without a
            picture or window, the replay resumes from the latest snapshot an earlier replay
            left of this plan's beginning and leaves its own (the same report as from the
            start).

    Returns:
        ReplayReport with a pass/fail verdict (drift and closure agreement), per-state
        closure and drift, and where and why it failed.

    Raises:
        SpecError: the plan lacks a key or has a bad value (names the file and key).
        InputError: a parameter is out of range, or no engine of that name.
        SimulationError: the engine could not set up the scene, or ffmpeg is missing for mp4.
    """
    rd = typed_plan(plan, strict)
    joints, states, steps, obj, friction = list(rd.joints), rd.states, rd.steps, rd.object, rd.friction
    positive = [("dt", dt), ("drift_mm_max", drift_mm_max), ("drift_deg_max", drift_deg_max),
                ("drop_mm", drop_mm), ("joint_speed_rad_s", joint_speed_rad_s)]
    if finger_force_n is not None:
        positive.append(("finger_force_n", finger_force_n))
    for name, v in positive:
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise InputError(f"{name} must be a positive number, got {v!r}")
    info = load_hand_info(rd, joints, hand)
    g_vec = 9.81 * np.asarray(info.palm_normal, float) if gravity is None else np.asarray(gravity, dtype=float)
    if g_vec.shape != (3,) or not np.all(np.isfinite(g_vec)):
        raise InputError(f"gravity must be 3 finite numbers (palm frame, m/s^2), got {gravity!r}")
    if int(gif_every) < 1:
        raise InputError(f"gif_every must be >= 1, got {gif_every!r}")
    ffmpeg = None
    if mp4 is not None:
        ffmpeg = shutil.which("ffmpeg")
        if ffmpeg is None:
            raise SimulationError("--mp4 needs ffmpeg on PATH and none was found; use --gif instead")
    contact_model = rd.parameters.get("contact_model", "patch")  # checked by plan_from_data
    params = dict(dt=dt, contact_model=contact_model, gravity=g_vec.tolist(), acquire_s=acquire_s, ramp_s=ramp_s,
                  settle_s=settle_s, handover_s=handover_s, dwell_s=dwell_s, joint_speed_rad_s=joint_speed_rad_s,
                  finger_force_n=finger_force_n, solver_iterations=int(solver_iterations), drop_mm=drop_mm,
                  drift_mm_max=float(drift_mm_max), drift_deg_max=float(drift_deg_max), filter_k=int(filter_k),
                  mu=friction.mu, gamma=friction.gamma, edges=friction.edges, touch_tol_m=TOUCH_TOL_M,
                  stop_at_failure=bool(stop_at_failure))
    line = stop_at_failure if isinstance(stop_at_failure, StopLine) else None
    snap = None
    if snapshots is not None and stop_at_failure and client is None and not gui and gif is None and mp4 is None:
        from planner.sim import snapshots as _snapshots  # (only a verification's replays)

        setting = (params, engine or default_engine(), float(density_kg_m3), str(info.urdf_path), list(joints))
        snap = _snapshots.Snapshots(tuple(snapshots), _snapshots.Chain(rd, setting))
        if os.getpid() != snap.owner:
            resumed = snap.resume(rd, line)
            if resumed is not None:
                return resumed
    try:
        return _replay_engine(rd, info, joints, states, steps, obj, friction, params, line, snap, gui, client, engine,
                              density_kg_m3, dt, solver_iterations, gif, gif_every, mp4, width, height, ffmpeg)
    except BaseException as err:
        if snap is not None:
            snap.finish(error=err)  # a copy resumed from a snapshot reports it and exits
        raise


def _replay_engine(rd, info, joints, states, steps, obj, friction, params, line, snap, gui, client, engine,
                   density_kg_m3, dt, solver_iterations, gif, gif_every, mp4, width, height, ffmpeg) -> ReplayReport:
    """`replay_plan` once its inputs are checked: build the engine, run, give the verdict."""
    drift_mm_max, drift_deg_max, drop_mm = params["drift_mm_max"], params["drift_deg_max"], params["drop_mm"]
    own = client is None
    mass_kg, radius_m = object_mass(obj, density_kg_m3)
    # the hand's visual meshes only matter to a picture or a window (half the URDF load)
    visual = gui or not own or gif is not None or mp4 is not None
    world = replay_world(info, obj, mass_kg, friction, dt, solver_iterations, visual)
    t0 = time.perf_counter()
    eng = engine_for(engine or default_engine(), world, client=client, gui=gui)
    try:
        sim = _Sim(eng, rd, info, joints, obj, friction, params, mass_kg, radius_m)
        sim.stop_line = line
        sim.snapshots = snap
        params["object_mass_kg"] = sim.mass
        recorder = None
        if gif is not None or mp4 is not None:
            from planner.sim.film import ReplayRecorder  # the renderer and PIL: loaded only for a film

            recorder = ReplayRecorder(sim, rd, info, width, height, keep_rgb=mp4 is not None)
        result = sim.run(states, steps, recorder=recorder, every=int(gif_every), realtime=gui and own)
        trajectory = sim.trajectory
        couplings = sim.coupling_errors()
        params["squeeze_force_n"] = sim.ctl.force_n if params["finger_force_n"] is None else float(params["finger_force_n"])
    finally:
        eng.close()
    wall = time.perf_counter() - t0 - (snap.paused_s if snap is not None else 0.0)

    gif_frames = 0
    if recorder is not None:
        if gif is not None:
            gif_frames = recorder.write_gif(gif)
        if mp4 is not None:
            from planner.sim.film import write_mp4  # PIL: loaded only for a film

            write_mp4(recorder.frames, str(mp4), 1.0 / (dt * int(gif_every)), ffmpeg)

    reports, dropped, max_mm, max_deg, fin_mm, fin_deg, n_steps, failure, fail_step = result
    stopped_after = sim.stopped_after
    reached = [r for r in reports if r.reached]
    agree = sum(1 for r in reached if r.sim_force_closure == r.planned_force_closure)
    disagree = [r for r in reached if r.sim_force_closure != r.planned_force_closure]
    other = [r for r in reached if not r.holds_as_planned]
    within = math.isfinite(max_mm) and math.isfinite(max_deg) and max_mm <= drift_mm_max and max_deg <= drift_deg_max
    broken = [c for c in couplings if not c.within]  # the engine let a coupled joint go
    if broken:  # a coupling broken before the stop line stopped it: its own failure
        stopped_after = None
    passed = (not dropped) and within and not disagree and not other and len(reached) == len(reports) and not broken
    limits = f"limits {drift_mm_max:g} mm / {drift_deg_max:g} deg"
    if dropped:
        # (the cause that follows is where it first left the drift limits: the millimetres it names
        # are those, not the drop's)
        verdict = f"FAIL: object dropped (moved more than {drop_mm:g} mm), first out of the {limits}"
    elif not within:
        # (the largest drift; the cause that follows is where it first left the limits, smaller)
        verdict = f"FAIL: drift {max_mm:.1f} mm / {max_deg:.1f} deg exceeds the {limits}" \
            + (", first out of them" if failure is not None else "")
    elif disagree:
        verdict = (f"FAIL: the simulator's force closure disagrees with the plan at "
                   f"{len(disagree)}/{len(reached)} states (max drift {max_mm:.1f} mm / {max_deg:.1f} deg)")
    elif other:
        verdict = (f"FAIL: the simulator holds the object with other links than the plan's at {len(other)}/"
                   f"{len(reached)} states (max drift {max_mm:.1f} mm / {max_deg:.1f} deg)")
    elif broken:
        verdict = (f"FAIL: the simulated hand breaks {len(broken)}/{len(couplings)} coupled joints beyond their "
                   f"tolerance (max drift {max_mm:.1f} mm / {max_deg:.1f} deg)")
    elif stopped_after is not None:
        verdict = (f"STOPPED after step {stopped_after}, unfailed: a replay before it in the verification's order failed "
                   f"(max drift {max_mm:.1f} mm / {max_deg:.1f} deg)")
    else:
        verdict = f"PASS: max drift {max_mm:.1f} mm / {max_deg:.1f} deg ({limits}); closure agrees at {agree}/{len(reached)} states"
    reasons = []
    if failure is not None:
        reasons.append(failure)
    for c in broken:
        at = "state 0" if c.step < 0 else f"step {c.step}"
        reasons.append(f"coupling {c.joint} = f({c.follows}) broken by {c.max_error:.4g} (tolerance {c.tolerance:.4g}) "
                       f"during {at} at t = {c.time_s:.3f} s")
    for r in disagree:
        plan_fc = "force closure" if r.planned_force_closure else "not force closure"
        sim_fc = "force closure" if r.sim_force_closure else "not force closure"
        missing = r.not_touching
        reasons.append(f"state {r.index}: plan {plan_fc}, simulator {sim_fc} (touching: "
                       f"{', '.join(r.sim_fingers) or 'nothing'}" + (f"; lost: {', '.join(missing)}" if missing else "") + ")")
    for r in other:
        if r in disagree:
            continue
        extra, idle = r.unplanned_carriers, r.not_touching
        words = ([f"carried by {', '.join(extra)} too"] if extra else []) + ([f"{', '.join(idle)} not touching"] if idle else [])
        reasons.append(f"state {r.index}: the plan holds with {', '.join(r.planned_fingers)}; in the simulator "
                       + "; ".join(words) + f" (forces: {', '.join(f'{f} {v:.2f} N' for f, v in sorted(r.carried_n.items()))})")
    failed_step, at_state = None, False
    if not passed and stopped_after is None:
        bad_states = [r.index for r in disagree + other] + [r.index for r in reports if not r.reached]
        first_bad = min(bad_states) if bad_states else None
        candidates = [k for k in (fail_step, None if first_bad is None else first_bad - 1) if k is not None]
        candidates += [c.step for c in broken]
        failed_step = min(candidates) if candidates else -1
        at_state = fail_step is None or (first_bad is not None and first_bad - 1 < fail_step)
    if reasons and not passed:
        verdict += ": " + "; ".join(reasons[:3]) + (f" (+{len(reasons) - 3} more)" if len(reasons) > 3 else "")
    report = ReplayReport(
        passed=passed, verdict=verdict, dropped=dropped,
        max_drift_mm=max_mm, max_drift_deg=max_deg, final_drift_mm=fin_mm, final_drift_deg=fin_deg,
        drift_mm_max=float(drift_mm_max), drift_deg_max=float(drift_deg_max),
        closure_agreement=(agree, len(reached)), states=tuple(reports),
        sim_time_s=n_steps * dt, wall_time_s=wall, sim_steps=n_steps,
        gif=str(gif) if gif is not None else None, gif_frames=gif_frames,
        mp4=str(mp4) if mp4 is not None else None, parameters=params, reasons=tuple(reasons),
        failed_step=failed_step, failed_at_state=at_state, trajectory=trajectory, engine=eng.name,
        coupling_errors=tuple(couplings), stopped_after=stopped_after,
    )
    if sim.stop_line is not None and not passed and stopped_after is None:
        # the line marked once the verdict is known too (a failure found once the run is
        # over, a broken coupling or a drop, stops the later replays); ``sim``'s line: in a
        # copy resumed from a snapshot `_Sim.swap_plan` put the requester's there
        sim.stop_line.fail()
    if snap is not None:
        snap.finish(report)  # a copy resumed from a snapshot hands it to its requester and exits
    return report


class _Sim:
    """One replay in a built engine (hand, object, controller, measurements).

    Args:
        engine: the built world (`planner.sim.engine.PhysicsEngine`).
        rd: the typed plan; info: its hand; joints: the plan's joints; obj: its object.
        friction: the plan's friction; params: the replay's parameters (`replay_plan`).
        mass_kg, radius_m: the object's mass and smallest half-extent (`planner.sim.inputs.object_mass`).
    """

    def __init__(self, engine: PhysicsEngine, rd, info: HandInfo, joints, obj, friction, params, mass_kg: float,
                 radius_m: float):
        self.engine, self.rd, self.params, self.friction = engine, rd, params, friction
        self.dt = params["dt"]
        self.mass = float(mass_kg)
        # the planned pose drift is measured from: the current state's (`set_reference`); the
        # plan's object pose (state 0's) until a reposing step moves it
        self.T_ref = _T(obj.position, obj.quat_xyzw)
        self._p_ref = tuple(float(v) for v in self.T_ref[:3, 3])
        self._quat_ref = tuple(float(v) for v in Rotation.from_matrix(self.T_ref[:3, :3]).as_quat())
        self._ref0 = (self.T_ref, self._p_ref, self._quat_ref)
        topo = engine.topology
        unknown = [j for j in joints if j not in topo.joints]
        if unknown:
            raise rd.error("joints", f"joints {unknown} are not movable joints of {info.urdf_path}")
        self.joints = joints
        self.fingers = info.fingers
        # URDF link -> the finger it moves with, or the palm
        self.link_finger = topo.link_owner({j: f for f, js in info.fingers.items() for j in js}, "palm")
        g_max = float(np.linalg.norm(params["gravity"]))
        self.ctl = Controller(engine, info.hand, topo, self.link_finger, engine.link_masses(), self.mass, friction,
                              g_max, force_n=params["finger_force_n"], dt_s=self.dt, object_radius_m=radius_m)
        for link, floor in self.ctl.armature_floor.items():
            engine.raise_link_inertia(link, floor)
        # coupled joints (engine order: follower, driver) and their largest error so far, with when
        ix = {j: k for k, j in enumerate(topo.joints)}
        self.couplings = [(c, ix[c.joint], ix[c.follows]) for c in info.hand.couplings
                          if c.joint in ix and c.follows in ix]
        self.coupling_max = [0.0] * len(self.couplings)
        self.coupling_at = [(-1, 0.0)] * len(self.couplings)
        self.filter = ContactFilter(params["filter_k"])
        self.steps_done = 0
        self.max_mm = self.max_deg = 0.0
        self.phase = "acquiring the initial grasp"
        self.sampling = False
        self.traj_every = max(1, int(round(TRAJECTORY_DT_S / self.dt)))
        self.trajectory: dict = {"joints": list(info.hand.joint_names), "t": [], "q": [], "object_position": [],
                                 "object_quat_xyzw": []}
        self.failure: str | None = None
        self.palm_holds = False  # the palm holds at the current state (set by `run`)
        self.reposing = False  # a reposing step's fingers are moving the object
        self.fail_step: int | None = None  # plan step (-1: state 0) at which the drift first left the limits
        self.step_k = -1
        self.stop_line: StopLine | None = None  # shared with the replays in other directions
        self.snapshots = None  # `planner.sim.snapshots.Snapshots` of a replay that leaves them
        self.stopped_after: int | None = None  # the step after which the stop line stopped it
        self.carried: dict[str, float] = {}  # finger or "palm" -> summed normal force over the sampling window
        self.samples = 0
        self.last_patches: Mapping[str, tuple[np.ndarray, np.ndarray]] = {}

    def set_reference(self, pose=None) -> None:
        """The planned object pose drift is measured from: ``pose`` (x, y, z, qx, qy, qz, qw,
        palm frame: a state's `planner.plan_data.PlanState.object_pose`, or a reposing step's
        pose between two waypoints), None: the plan's object pose (state 0's)."""
        if pose is None:
            self.T_ref, self._p_ref, self._quat_ref = self._ref0
            return
        pose = np.asarray(pose, dtype=float)
        quat = pose[3:7] / np.linalg.norm(pose[3:7])
        self._p_ref = tuple(float(v) for v in pose[:3])
        self._quat_ref = tuple(float(v) for v in quat)
        self.T_ref = _T(pose[:3], quat)

    def start_place(self, pos, quat) -> list:
        """The object's start position: the planned one moved out of the palm's links where
        they overlap it in the engine's geometry (`planner.sim.controller.Controller
        .palm_clearance`, iterated; the palm cannot back off, and an overlap is a spring that
        throws the object at its release). Drift is still measured from the planned pose."""
        pos = [float(v) for v in pos]
        for _ in range(BACK_OFF_ITERATIONS):
            d = self.ctl.palm_clearance()
            if d is None:
                break
            pos = [a + float(b) for a, b in zip(pos, d)]
            self.engine.set_object_pose(pos, quat)
        return pos

    def start_clear(self, fingers) -> dict[str, float]:
        """Back the holding fingers' links out of the object where the planned posture overlaps
        it in the engine's geometry (`planner.sim.controller.Controller.back_off`, iterated
        from the engine's closest points; pybullet's hulls overlap a planned contact by up to
        1 mm), so the acquisition closes them under their commanded torques instead of
        starting them inside the object: a finger whose contact point moves mostly along the
        face (a one-actuator finger: ``v.n < mu |v_t|``) is friction-locked and cannot be pushed
        out; the engine then presses it with its penetration's force, many times the command.
        Returns joint -> how far it was backed off (rad), the joints moved."""
        moved: dict[str, float] = {}
        q0 = self.ctl.q()
        start = {j: float(q0[self.ctl.col[j]]) for j in self.ctl.hand.joint_names}
        for _ in range(BACK_OFF_ITERATIONS):
            q_new = self.ctl.back_off(tuple(fingers))
            if q_new is None:
                break
            self.engine.reset_joints(q_new)
            moved.update(q_new)
        return {j: v - start[j] for j, v in moved.items()}

    def friction_locked(self, fingers) -> list[str]:
        """The fingers among ``fingers`` whose start overlap `start_clear` removes: those with
        coupled joints (fewer actuators than joints). Such a finger's contact point moves along
        one direction per actuator, mostly along the face (``v.n < mu |v_t|`` on the Psyonic),
        so it cannot be pushed out of an overlap and presses with the overlap's force, many
        times its command. A finger with a motor per joint is pushed out by the contact and
        its force follows the controller: it starts from the planned posture, as every replay
        of the bundled hands was measured (backing those off too lost the iCub mesh box's
        palm-down plan at its little finger's lift, which holds from the planned posture)."""
        hand = self.ctl.hand
        return [f for f in fingers if f in hand.fingers and hand.fingers[f].coupled]

    def _q(self, state) -> dict[str, float]:
        """Joint name -> value of a plan state."""
        return dict(zip(self.joints, state.q))

    def set_gravity(self, g) -> None:
        """Gravity (palm frame, m/s^2) in the engine and for the controller."""
        self.ctl.set_gravity(g)
        self.engine.set_gravity(self.ctl.gravity)

    def obj_pose(self, pose=None) -> np.ndarray:
        """The object's pose (4, 4); ``pose``: its `planner.sim.engine.ObjectPose` when already read."""
        return (pose or self.engine.object_pose()).T

    def _tick(self):
        self.engine.set_joint_torques(self.ctl.step())
        self.engine.step()
        self.steps_done += 1
        if self.couplings:
            self._measure_couplings()
        pose = self.engine.object_pose()
        pos, quat = pose.position_m, pose.quat_xyzw
        if self.sampling:  # the temporal filter only needs the samples before a measurement
            self.filter.update(self.contact_sample(pose.T, carry=True))
        mm, deg = pose_drift(self._p_ref, self._quat_ref, pos, quat)
        if self.steps_done % self.traj_every == 0 or mm > self.params["drop_mm"]:
            tr = self.trajectory
            tr["t"].append(round(self.steps_done * self.dt, 6))
            tr["q"].append([round(float(v), 6) for v in self.ctl.q()])
            tr["object_position"].append([round(float(v), 6) for v in pos])
            tr["object_quat_xyzw"].append([round(float(v), 6) for v in quat])
        if self.released:
            self.max_mm, self.max_deg = max(self.max_mm, mm), max(self.max_deg, deg)
            if self.failure is None and not (mm <= self.params["drift_mm_max"] and deg <= self.params["drift_deg_max"]):
                self.failure = self._explain(pose.T, mm, deg)
                self.fail_step = self.step_k
        self.last = (mm, deg)
        if self.recorder is not None and self.steps_done % self.every == 0:
            self.recorder.grab()
        if self.realtime:
            time.sleep(self.dt)
        return mm

    def _measure_couplings(self) -> None:
        """Keep every coupling's largest ``|q_f - (m q_d + o)|`` and the plan step and time of it."""
        q = self.engine.joint_states().position
        for i, (c, f, d) in enumerate(self.couplings):
            e = abs(float(q[f]) - (c.multiplier * float(q[d]) + c.offset))
            if e > self.coupling_max[i]:
                self.coupling_max[i] = e
                self.coupling_at[i] = (self.step_k, self.steps_done * self.dt)

    def coupling_errors(self) -> list[CouplingError]:
        """Each coupling's largest error over the replay, with its tolerance
        (`planner.hand.Hand.coupling_tolerances`)."""
        if not self.couplings:
            return []
        tol = dict(zip((c.joint for c in self.ctl.hand.couplings), self.ctl.hand.coupling_tolerances()))
        return [CouplingError(c.joint, c.follows, round(e, 9), float(tol[c.joint]), k, round(t, 6))
                for (c, _, _), e, (k, t) in zip(self.couplings, self.coupling_max, self.coupling_at)]

    def contact_sample(self, T: np.ndarray, carry: bool = False) -> list:
        """This step's contacts as (link, p_obj (1, 3), n_obj (1, 3)), normals INTO the object;
        ``carry``: also add their normal forces to the measurement window's (`carried`), once
        per physics step (a picture or an explanation reads the contacts too)."""
        R_t = T[:3, :3].T
        sample = []
        if carry:
            self.samples += 1
        for cp in self.engine.contacts():
            if cp.distance_m > TOUCH_TOL_M:
                continue
            if carry:
                who = self.link_finger.get(cp.link, "palm")
                self.carried[who] = self.carried.get(who, 0.0) + float(cp.normal_force_n)
            p_obj = R_t @ (np.asarray(cp.point_m) - T[:3, 3])  # point on the object
            n_obj = R_t @ np.asarray(cp.normal)  # into the object
            sample.append((cp.link, p_obj[None, :], n_obj[None, :]))
        return sample

    def _dwell_and_measure(self, seconds: float, index: int, state) -> StateReport | None:
        """Run ``seconds``, feeding the temporal filter during the last ``2 filter_k`` steps
        (a contact it keeps must have been seen within its last ``filter_k`` samples, so
        earlier samples cannot change what it reports), then measure the state; None when
        the object dropped."""
        window = 2 * self.params["filter_k"]
        n = max(window, int(round(seconds / self.dt)))
        if n > window and not self._run_for((n - window) * self.dt):
            return None
        self.filter.reset()
        self.carried, self.samples = {}, 0
        self.sampling = True
        try:
            ok = self._run_for(window * self.dt)
        finally:
            self.sampling = False
        return self._measure(index, state) if ok else None

    def _explain(self, T: np.ndarray, mm: float, deg: float) -> str:
        """Where and why the object first left the limits: the phase, lost contacts, slip
        and the rotation axis (palm frame)."""
        what = []
        touching = {self.link_finger.get(cp.link, "palm") for cp in self.engine.contacts()
                    if cp.distance_m <= TOUCH_TOL_M}
        lost = [f for f in self.ctl.holding if f not in touching]
        if lost:
            what.append(f"contact lost: {', '.join(lost)}")
        if not self.ctl.balanced:
            what.append("no forces at the touching links balance the load inside the friction cones")
        stray = sorted(f for f in touching if f not in self.ctl.holding and not (f == PALM and self.palm_holds))
        if stray:
            what.append(f"touched by {', '.join(stray)} (not holding)")
        now: dict[str, list] = {}
        for link, pt, _ in self.contact_sample(T):
            now.setdefault(self.link_finger.get(link, "palm"), []).append(pt[0])
        for f, (pts, _) in sorted(self.last_patches.items()):
            if f in now and len(pts):
                slip_mm = 1000.0 * float(np.linalg.norm(np.mean(now[f], axis=0) - np.mean(pts, axis=0)))
                if slip_mm > 1.0:
                    what.append(f"slip at {f} {slip_mm:.1f} mm")
        rot = Rotation.from_matrix(T[:3, :3] @ self.T_ref[:3, :3].T).as_rotvec()
        if deg > self.params["drift_deg_max"] and np.linalg.norm(rot) > 0:
            axis = rot / np.linalg.norm(rot)
            what.append(f"rotation {deg:.1f} deg about palm axis [{axis[0]:+.2f} {axis[1]:+.2f} {axis[2]:+.2f}]")
        if mm > self.params["drift_mm_max"]:
            d = T[:3, 3] - self.T_ref[:3, 3]
            g = np.asarray(self.params["gravity"], float)
            along = float(d @ g / np.linalg.norm(g) * 1000.0) if np.linalg.norm(g) > 0 else 0.0
            what.append(f"moved {mm:.1f} mm ({along:+.1f} mm along gravity)")
        return f"{self.phase}: " + (", ".join(what) or f"drift {mm:.1f} mm / {deg:.1f} deg")

    def _run_for(self, seconds: float, each=None) -> bool:
        """Step for a duration (``each(fraction)`` before every step); False when the object dropped."""
        n = max(1, int(round(seconds / self.dt)))
        for k in range(n):
            if each is not None:
                each((k + 1) / n)
            if self._tick() > self.params["drop_mm"]:
                return False
        return True

    def _measure(self, index: int, state) -> StateReport:
        patches = self.filter.patches(lambda link: self.link_finger.get(link, "palm"))
        self.last_patches = patches
        n_pts = sum(len(v[0]) for v in patches.values())
        if patches:
            c = grasp_closure(apply_contact_model(patches, self.params["contact_model"]), self.friction)
            fc, metric = bool(c.is_force_closure), float(c.metric)
        else:
            fc, metric = False, float("nan")
        mm, deg = self.last
        carried = {f: v / max(1, self.samples) for f, v in self.carried.items()}
        g = float(np.linalg.norm(self.ctl.gravity))
        threshold = CARRY_SHARE * max(self.mass * g, self.ctl.force_n)
        carriers = tuple(sorted(f for f, v in carried.items() if v >= threshold))
        offsets = {f: round(1000.0 * float(np.linalg.norm(np.mean(patches[f][0], axis=0) - np.mean(pts, axis=0))), 3)
                   for f, (pts, _) in state.patches.items() if f in patches and len(patches[f][0]) and len(pts)}
        return StateReport(index, True, self.steps_done * self.dt, tuple(state.patches), tuple(sorted(patches)),
                           state.is_force_closure, state.metric, fc, metric, n_pts, mm, deg, patches,
                           {f: round(v, 6) for f, v in sorted(carried.items())}, carriers, offsets)

    def _repose(self, st, frm, to) -> bool:
        """A reposing step: every touching finger keeps holding (no handover) while the
        posture targets of all their joints follow ``st.path`` together, offset by where each
        joint is latched now (its squeeze: the targets keep the grip they hold with), and the
        planned pose drift is measured from moves along ``st.object_path`` at the same
        fraction of each segment; at the end the fingers latch where they touch and the
        to-state's palm contact holds. A finger touching in the from-state only is released
        (its load handed over before, then it keeps still while the object is carried away),
        one touching in the to-state only is carried onto (it takes its load after). False
        when the object dropped."""
        ctl, prm = self.ctl, self.params
        q_ref = dict(ctl.q_ref)
        # a finger touching at one end only: released (the object carried away from it: its load
        # handed over first) or carried onto (it takes its load at the end); it keeps still
        released = [f for f in frm.touching if f not in to.touching]
        onto = [f for f in to.touching if f not in frm.touching]
        holding = [f for f in frm.touching if f in to.touching]
        if released:
            ctl.command(q_ref, frm.touching)
            if not self._run_for(prm["handover_s"], lambda x: [ctl.fade(f, 1.0 - x) for f in released]):
                return False
        ctl.command(q_ref, holding)
        start = np.array([q_ref[j] for j in st.joints])
        planned = np.asarray(st.path, dtype=float)
        path = planned + (start - planned[0])
        poses = np.asarray(st.object_path, dtype=float)
        # the object moves relative to the palm along segments first..last: the fingers carry
        # all of it there, as planned (the palm holds only where the object rests on it,
        # `planner.repose`): the palm's load is handed over to them before they lift the object
        # off it, and back after they put it on. Waypoints before or after, with the object
        # still (fingers re-posturing on it, `planner.pose_search`), keep the palm's share as
        # it is (a palm holding at that end holds there: the planner judged them with it)
        moving = [k for k in range(len(poses) - 1) if not object_still(poses[k], poses[k + 1])]
        first, last = (moving[0], moving[-1]) if moving else (len(poses), -1)
        self.palm_holds = frm.palm_holds
        # the holding fingers' motors carry the object: no faster than they follow a target
        # (`Controller.tracking_speed_rad_s`), or the fingers lag behind the path and the
        # object with them
        speed = np.minimum(prm["joint_speed_rad_s"], ctl.tracking_speed_rad_s(st.joints))
        ok, self.reposing, palm_back = True, True, not moving and frm.palm_holds
        for k, ((a, b), (pa, pb)) in enumerate(zip(zip(path[:-1], path[1:]), zip(poses[:-1], poses[1:]))):
            if k == first:
                if self.palm_holds and not self._run_for(prm["handover_s"], lambda x: ctl.fade_palm(1.0 - x)):
                    ok = False
                    break
                ctl.fade_palm(0.0)
                self.palm_holds = False
            n = max(1, int(math.ceil(float(np.max(np.abs(b - a) / speed)) / self.dt)))
            for i in range(1, n + 1):
                ctl.set_moving_target({j: float(v) for j, v in zip(st.joints, a + (b - a) * i / n)})
                self.set_reference(pose_between(pa, pb, i / n))
                if self._tick() > prm["drop_mm"]:
                    ok = False
                    break
            if not ok:
                break
            if k == last and to.palm_holds:  # (re-posturing waypoints after it: on the palm)
                self.palm_holds = palm_back = True
                self.set_reference(to.object_pose)
                if not self._run_for(prm["handover_s"], lambda x: ctl.fade_palm(x)):
                    ok = False
                    break
                ctl.fade_palm(1.0)
        self.reposing = False
        self.set_reference(to.object_pose)
        self.palm_holds = to.palm_holds
        if ok and to.palm_holds and not palm_back:
            ok = self._run_for(prm["handover_s"], lambda x: ctl.fade_palm(x))
        ctl.fade_palm(1.0)
        if ok and onto:
            ctl.command(dict(ctl.q_ref), to.touching, share={f: 0.0 for f in onto})
            ok = self._run_for(prm["handover_s"], lambda x: [ctl.fade(f, x) for f in onto])
        if ok:
            ctl.command(dict(ctl.q_ref), to.touching)
            ctl.latch(to.touching)
        return ok

    def _stop(self, r: StateReport, k: int) -> bool:
        """Whether to stop after measuring ``r``, the state plan step ``k`` reached (-1: state
        0): asked to stop at a failure (``stop_at_failure``) and one has happened (the drift
        left its limits, or the state is not held as planned: what `replay_plan`'s verdict
        refuses; the stop line learns it), or the stop line says a replay before this one in
        its order failed (`stopped_after`)."""
        if not self.params.get("stop_at_failure"):
            return False
        if self.failure is not None or not r.holds_as_planned or r.sim_force_closure != r.planned_force_closure:
            if self.stop_line is not None:
                self.stop_line.fail()
            return True
        if self.stop_line is not None and self.stop_line.stopped():
            self.stopped_after = k
            return True
        return False

    def swap_plan(self, rd, stop_line) -> None:
        """In a copy resumed from a snapshot (`planner.sim.snapshots`): go on with this plan,
        whose states and steps up to the snapshot are the ones replayed, and this stop line."""
        self.rd, self.plan_states, self.plan_steps, self.stop_line = rd, rd.states, rd.steps, stop_line

    def _steps(self):
        """(k, step) over the plan's steps, read as the loop goes (`swap_plan` may replace them)."""
        k = 0
        while k < len(self.plan_steps):
            yield k, self.plan_steps[k]
            k += 1

    def _checkpoint(self, k: int) -> None:
        if self.snapshots is not None:
            self.snapshots.checkpoint(self, k)

    def run(self, states, steps, recorder=None, every=8, realtime=False):
        self.recorder, self.every, self.realtime = recorder, every, realtime
        self.plan_states, self.plan_steps = states, steps
        self.released = False
        self.palm_holds = bool(states) and states[0].palm_holds  # the palm holds at the current state
        self.set_reference(states[0].object_pose if states else None)
        ctl, prm = self.ctl, self.params
        g_full = np.asarray(prm["gravity"], float)
        eng = self.engine
        eng.reset_joints(self._q(states[0]))
        pos, quat = list(self._p_ref), list(self._quat_ref)
        eng.set_object_pose(pos, quat)
        # 1. acquire the planned contacts with gravity off, the object held where the plan has it
        # (out of the palm's links) from a posture that does not overlap it in the engine's
        # geometry (`start_clear`)
        pos = self.start_place(pos, quat)
        self.start_clear(self.friction_locked(states[0].touching))
        eng.hold_object(pos, quat)
        self.set_gravity(np.zeros(3))
        ctl.command(self._q(states[0]), states[0].touching)
        self._run_for(prm["acquire_s"])
        ctl.latch(states[0].touching)
        eng.release_object()
        self.released = True
        # 2. gravity comes in gradually; the forces follow the load
        self.phase = "gravity ramp at state 0"
        ok = self._run_for(prm["ramp_s"], lambda s: self.set_gravity(s * g_full))
        self.phase = "settling at state 0"
        reports: dict[int, StateReport] = {}
        if ok:
            r0 = self._dwell_and_measure(prm["settle_s"], 0, states[0])
            ok = r0 is not None
            if ok:
                reports[0] = r0
        go = ok and not self._stop(r0, -1)
        if go:
            self._checkpoint(-1)
        for k, st in (self._steps() if go else ()):
            frm, to = self.plan_states[st.from_state], self.plan_states[st.to_state]
            self.phase = f"step {k} ({st.action} {st.finger}, state {st.from_state} -> {st.to_state})"
            self.step_k = k
            self.set_reference(frm.object_pose)
            if st.action == "repose":
                ok = self._repose(st, frm, to)
                r = self._dwell_and_measure(prm["dwell_s"], st.to_state, to) if ok else None
                if r is None:
                    ok = False
                    break
                reports[st.to_state] = r
                if self._stop(r, k):
                    break
                self._checkpoint(k)
                continue
            q_ref = dict(ctl.q_ref)
            if st.action != "land" and st.finger in ctl.holding:
                # hand the finger's load over to the others while it still touches
                ok = self._run_for(prm["handover_s"], lambda s: ctl.fade(st.finger, 1.0 - s))
                if not ok:
                    break
            holding = [f for f in frm.touching if f != st.finger]
            ctl.command(q_ref, holding, moving=st.finger)
            # the moving finger tracks its path (capped near the squeeze at its pad)
            start = np.array([q_ref[j] for j in st.joints])
            path = lift_path(start, st.path) if st.action == "lift" else np.vstack([start[None, :], st.path])
            # no faster than the finger's capped, damped motors follow (`Controller
            # .tracking_speed_rad_s`): it would lag behind the path and land short of the object
            speed = np.minimum(prm["joint_speed_rad_s"], ctl.tracking_speed_rad_s(st.joints))
            for a, b in zip(path[:-1], path[1:]):
                n = max(1, int(math.ceil(float(np.max(np.abs(b - a) / speed)) / self.dt)))
                for i in range(1, n + 1):
                    ctl.set_moving_target({j: float(v) for j, v in zip(st.joints, a + (b - a) * i / n)})
                    if self._tick() > prm["drop_mm"]:
                        ok = False
                        break
                if not ok:
                    break
            if not ok:
                break
            # at the end of the path: the new state's fingers hold; a landed finger takes its
            # load over gradually
            # (the other fingers keep the targets they were latched at)
            q_to = self._q(to)
            q_to.update({j: v for j, v in ctl.q_ref.items() if j not in st.joints})
            if st.finger in to.touching:
                ctl.command(q_to, to.touching, share={st.finger: 0.0})
                ok = self._run_for(prm["handover_s"], lambda s: ctl.fade(st.finger, s))
                ctl.latch([st.finger])
            else:
                ctl.command(q_to, to.touching)
            self.set_reference(to.object_pose)
            self.palm_holds = to.palm_holds
            r = self._dwell_and_measure(prm["dwell_s"], st.to_state, to) if ok else None
            if r is None:
                ok = False
                break
            reports[st.to_state] = r
            if self._stop(r, k):
                break
            self._checkpoint(k)
        out = []
        for i, s in enumerate(self.plan_states):
            if i in reports:
                out.append(reports[i])
            else:
                out.append(StateReport(i, False, self.steps_done * self.dt, tuple(s.patches), (), s.is_force_closure, s.metric,
                                       None, None, 0, float("nan"), float("nan")))
        mm, deg = self.last
        return out, not ok, self.max_mm, self.max_deg, mm, deg, self.steps_done, self.failure, self.fail_step
