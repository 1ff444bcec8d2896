"""Execute a regrasp plan in pybullet with gravity on and check that the object stays put.

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
     at the end of the path every finger takes the new state's targets;
  4. at every state, contacts from ``getContactPoints`` (one raw sample per simulation
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
the simulator's spinning friction provides: `planner.sim.controller.CONE_MARGINS`), no
component above ``MAX_FORCE_RATIO * F`` and a normal force of at least ``MIN_NORMAL_RATIO * F``
(``F = finger_force_n``; `planner.sim.controller.balance_forces`). Plain normal squeezing is kept only when no balanced forces exist
at those contacts. The finger then presses with joint torques ``tau = J_f^T f_i``
(``J_f``: linear Jacobian of the contact point over the finger's joints): its position
target lies ``squeeze_m`` beyond the contact along ``tau`` and each joint's torque is
capped at ``|tau_j|`` (at least a small holding torque), so the motors saturate against
the object and press with ``tau``.

Friction. Bullet multiplies the two bodies' lateral friction and combines spinning friction
as ``s_a * mu_b + s_b * mu_a``; with the hand links at lateral friction 1 and spinning 0 and
the object at ``mu`` and ``gamma``, every finger-object contact gets exactly the plan's
``mu`` (Coulomb) and ``gamma`` (torsional, metres) of the soft-finger model (thesis eq. 1).
"""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import tempfile
import time
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from planner.model import Friction
from planner.closure import apply_contact_model, grasp_closure
from planner.errors import InputError, SimulationError, UnknownNameError
from planner.objects import SHAPES, SIZE_LENGTHS, SIZE_MEANING, make_object
from planner.plan import Plan, plan_file, plan_from_data, read_plan
from planner.sim.contact_filter import ContactFilter
from planner.sim.controller import TOUCH_TOL_M, Controller
from planner.sim.scene import hand_body, object_body, p  # p: pybullet, its build banner silenced

#: A plan's joint values may exceed the hand's limits by this much (rad or m): rounding.
JOINT_LIMIT_TOL = 1e-3
#: A finger (or the palm) carries the object when it presses with a mean normal force of at
#: least this share of the larger of the object's weight and the controller's squeeze: every
#: holding finger is commanded at least half the squeeze (`planner.sim.controller
#: .MIN_NORMAL_RATIO`), so a tenth of it is a touch that takes part of the load, not a graze.
CARRY_SHARE = 0.1
#: The replay records the hand's joints and the object's pose this often (simulated s) for
#: `view --report` to play what the simulator did (a drop is seen as a drop).
TRAJECTORY_DT_S = 1.0 / 30.0


# --------------------------------------------------------------------------- reports


@dataclass(frozen=True)
class StateReport:
    """Simulated check of one plan state.

    Attributes:
        index: index into the plan's states.
        reached: False when the replay stopped (object dropped) before this state.
        time_s: simulated time at which the state was measured.
        planned_fingers: fingers with contact patches in the plan.
        sim_fingers: fingers (or "palm") touching the object in the filtered sim contacts.
        planned_force_closure, planned_metric: the plan's closure of this state.
        sim_force_closure, sim_metric: closure recomputed from the filtered sim contacts
            (None when not reached).
        sim_points: number of filtered contact points used.
        drift_mm, drift_deg: object displacement and rotation since the start of the replay.
        sim_patches: finger (or "palm") -> (p_obj (n, 3), n_in_obj (n, 3)): the filtered sim
            contacts in the object frame, normals INTO the object.
        carried_n: finger (or "palm") -> mean normal force it pressed on the object with
            over the measurement window, N (the simulator's contact forces).
        contact_offset_mm: planned finger -> distance from its planned contact (the patch
            mean) to where the simulator has it touch (its filtered points' mean), object
            frame, mm (fingers touching in both only).
        carriers: the fingers (or "palm") that carry the object: a mean normal force of at
            least ``CARRY_SHARE`` of the larger of the object's weight and the squeeze. A state
            holds as planned (`holds_as_planned`) when no other link carries it and every
            planned finger touches.
    """

    index: int
    reached: bool
    time_s: float
    planned_fingers: tuple[str, ...]
    sim_fingers: tuple[str, ...]
    planned_force_closure: bool
    planned_metric: float
    sim_force_closure: bool | None
    sim_metric: float | None
    sim_points: int
    drift_mm: float
    drift_deg: float
    sim_patches: Mapping[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    carried_n: Mapping[str, float] = field(default_factory=dict)
    carriers: tuple[str, ...] = ()
    contact_offset_mm: Mapping[str, float] = field(default_factory=dict)

    @property
    def holds_as_planned(self) -> bool:
        """The object is held by the plan's fingers: nothing else carries it (not the palm,
        not a finger the plan has lifted) and every one of them touches it."""
        return self.reached and set(self.carriers) <= set(self.planned_fingers) <= set(self.sim_fingers)


@dataclass(frozen=True)
class ReplayReport:
    """Outcome of `replay_plan`.

    Attributes:
        passed: no drop, the drift stayed within both thresholds at every step, every state
            was reached and the simulator's force closure agreed with the plan's at each.
        verdict: one line, e.g. "PASS: max drift 0.8 mm / 0.4 deg (limits 5 mm / 5 deg)".
        dropped: the object left the hand (moved more than ``drop_mm``).
        max_drift_mm, max_drift_deg: largest drift over every simulation step.
        final_drift_mm, final_drift_deg: drift at the end of the replay.
        drift_mm_max, drift_deg_max: the thresholds used.
        closure_agreement: states where sim and plan agree on force closure / states reached.
        states: one `StateReport` per plan state, in plan order.
        sim_time_s, wall_time_s, sim_steps: simulated time, wall-clock time, physics steps.
        gif, gif_frames, mp4: output files written (None when not asked).
        parameters: the physics and control parameters used.
        reasons: why it failed: where the object first left the limits (the phase: step,
            finger, action; contacts lost, slip, rotation axis), every state whose
            simulated closure disagrees with the plan's and every state carried by other
            links than the plan's fingers.
        failed_step: index of the plan step during which the replay first failed (the drift
            left the limits, or it led into a state that failed), -1 when it failed at state
            0 (acquiring, gravity ramp, settling), None when it passed.
        failed_at_state: the failure is the state that step reaches (measured there: its
            closure or the links holding the object), not the motion of the step itself.
        trajectory: what the simulator did, sampled every ``TRAJECTORY_DT_S`` of simulated
            time (`view --report` plays it): ``joints`` (names), ``t`` (s), ``q`` (rad, one row
            per sample), ``object_position`` (m) and ``object_quat_xyzw`` (palm frame).
    """

    passed: bool
    verdict: str
    dropped: bool
    max_drift_mm: float
    max_drift_deg: float
    final_drift_mm: float
    final_drift_deg: float
    drift_mm_max: float
    drift_deg_max: float
    closure_agreement: tuple[int, int]
    states: tuple[StateReport, ...]
    sim_time_s: float
    wall_time_s: float
    sim_steps: int
    gif: str | None = None
    gif_frames: int = 0
    mp4: str | None = None
    parameters: Mapping[str, Any] = field(default_factory=dict)
    reasons: tuple[str, ...] = ()
    failed_step: int | None = None
    failed_at_state: bool = False
    trajectory: Mapping[str, Any] | None = None

    def to_dict(self) -> dict:
        """Plain data for JSON (``json.dumps(report.to_dict())``)."""
        data = asdict(self)
        data["parameters"] = dict(self.parameters)
        for st, src in zip(data["states"], self.states):
            st["sim_patches"] = {f: {"points": np.asarray(pt).tolist(), "normals": np.asarray(nr).tolist()}
                                 for f, (pt, nr) in src.sim_patches.items()}
        data["closure_agreement"] = list(self.closure_agreement)
        return _no_nan(json.loads(json.dumps(data, default=_json_default)))


def _no_nan(value):
    """NaN (not measured) becomes null, so the JSON is strict."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _no_nan(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_no_nan(v) for v in value]
    return value


def _json_default(value):
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, tuple):
        return list(value)
    raise TypeError(f"not JSON serializable: {type(value).__name__}")


# --------------------------------------------------------------------------- plan input


def _read_plan(plan, strict: bool = False) -> Plan:
    """The typed plan of `planner.plan` (its one parser): a file is read and verified by
    `read_plan` (integrity, structure, closures, inputs; ``strict``: a changed or missing
    input is an error, not a warning), plan data is checked by `plan_from_data`, a `Plan`
    is used as it is."""
    if isinstance(plan, Plan):
        return plan
    if isinstance(plan, Mapping):
        return plan_from_data(dict(plan))
    return read_plan(plan, strict=strict)


@dataclass(frozen=True)
class _HandInfo:
    urdf_path: str
    fingers: dict[str, tuple[str, ...]]  # finger -> joint names
    T_palm_base: np.ndarray  # pose of the URDF root link in the palm frame
    hand: Any  # planner.hand.Hand: Jacobians for the controller
    palm_normal: tuple[float, float, float]


def _resolve(path_str: str, plan_path: str) -> Path | None:
    """A file the plan names (`planner.plan.plan_file`: relative to the plan file)."""
    found = plan_file(path_str, plan_path)
    return None if found is None else found.resolve()


def T_palm_root(hand) -> np.ndarray:
    """Pose of the URDF root link in the palm frame (identity when the root is the palm)."""
    root = getattr(getattr(hand, "model", None), "frames", None)
    if root is None or len(root) < 2 or not hasattr(hand, "link_pose"):
        return np.eye(4)
    root_name = root[1].name  # frame 0 is "universe", frame 1 the root link
    if root_name == getattr(hand, "palm_frame", root_name):
        return np.eye(4)
    return np.asarray(hand.link_pose(hand.q_open, root_name), dtype=float)


def _plan_hand(plan: Plan):
    """The plan's `planner.hand.Hand`: from its spec file when it resolves (read once, checked
    to be a hand spec without quoting the file), else by its name."""
    from planner.hand import Hand

    spec = plan.hand.get("spec")
    if spec:
        resolved = _resolve(str(spec), plan.source or "<plan>")
        if resolved is not None:
            if resolved.is_file():
                from planner.fileio import check_hand_file

                return Hand(resolved, check_hand_file(resolved, plan.source or "<plan>", "hand.spec"))
            return Hand.load(resolved)
    return Hand.load(str(plan.hand["name"]))


def _load_hand(plan: Plan, joints: list[str], hand=None) -> _HandInfo:
    """Hand URDF, finger -> joints and the pinocchio model of the plan's hand; every joint
    value of the plan must lie within the hand's limits (``JOINT_LIMIT_TOL`` beyond)."""
    if hand is None:
        hand = _plan_hand(plan)
    missing = [j for j in joints if j not in hand.joint_names]
    if missing:
        raise plan.error("joints", f"joints {missing[:5]} are not joints of hand {hand.name!r}")
    names = list(hand.joint_names)
    lo = np.array([hand.lower[names.index(j)] for j in joints]) - JOINT_LIMIT_TOL
    hi = np.array([hand.upper[names.index(j)] for j in joints]) + JOINT_LIMIT_TOL
    for i, st in enumerate(plan.states):
        bad = np.flatnonzero((np.asarray(st.q) < lo) | (np.asarray(st.q) > hi))
        if len(bad):
            j = joints[bad[0]]
            raise plan.error(f"states[{i}].q.{j}", f"{st.q[bad[0]]:.6g} is outside the joint's limits "
                                                   f"[{lo[bad[0]] + JOINT_LIMIT_TOL:.4g}, {hi[bad[0]] - JOINT_LIMIT_TOL:.4g}]")
    for i, step in enumerate(plan.steps):
        k = [joints.index(j) for j in step.joints]
        path = np.asarray(step.path)
        bad = np.argwhere((path < lo[k]) | (path > hi[k]))
        if len(bad):
            w, c = bad[0]
            raise plan.error(f"steps[{i}].path[{w}]", f"joint {step.joints[c]} at {path[w, c]:.6g} is outside its "
                                                      f"limits [{lo[k][c] + JOINT_LIMIT_TOL:.4g}, {hi[k][c] - JOINT_LIMIT_TOL:.4g}]")
    fingers = {f: tuple(fg.joints) for f, fg in hand.fingers.items()}
    return _HandInfo(str(hand.urdf_path), fingers, T_palm_root(hand), hand, tuple(hand.palm_normal))


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


def urdf_problem(urdf_path: str, joint_names) -> str | None:
    """Why pybullet cannot simulate a hand URDF with these joints (one line), or None."""
    cid = p.connect(p.DIRECT)
    try:
        body = p.loadURDF(urdf_path, useFixedBase=True, flags=p.URDF_IGNORE_VISUAL_SHAPES, physicsClientId=cid)
        names = {p.getJointInfo(body, i, physicsClientId=cid)[1].decode() for i in range(p.getNumJoints(body, physicsClientId=cid))}
        missing = [j for j in joint_names if j not in names]
        return f"joints {missing[:4]} are not in the URDF pybullet loads" if missing else None
    except p.error as err:
        return f"cannot load {urdf_path}: {err}"
    finally:
        p.disconnect(physicsClientId=cid)


#: The replay's object colour (its films).
OBJECT_RGBA = (0.85, 0.45, 0.15, 1.0)


def _create_object(cid: int, rd: Plan, obj: dict, density_kg_m3: float) -> tuple[int, float, float]:
    """The object's pybullet body (`planner.sim.scene.object_body`), its mass (kg:
    ``obj["mass_kg"]``, else volume x ``density_kg_m3``) and its smallest half-extent (m)."""
    shape = str(obj["shape"])
    size = [float(v) for v in obj["size"]]
    if shape not in SHAPES:
        raise UnknownNameError("object shape", shape, SHAPES)
    if len(size) not in SIZE_LENGTHS[shape]:
        raise rd.error("object.size", f"a {shape} size is {SIZE_MEANING[shape]}")
    resolved = None
    if shape == "mesh":
        mesh = obj.get("mesh")
        resolved = _resolve(str(mesh), rd.source or "<plan>") if mesh else None
        if resolved is None:
            raise rd.error("object.mesh", f"mesh file {mesh!r} not found")
    model = make_object(shape, size, mesh_path=resolved)
    radius = float(np.min(model.extents)) / 2
    mass = obj.get("mass_kg")  # a `Plan` always records one: the planner's
    if mass is None:
        mass = density_kg_m3 * model.volume_m3
    mass = float(mass)
    if not mass > 0:
        raise rd.error("object.mass_kg", f"expected a positive mass, got {mass}")
    body = object_body(cid, shape, size, resolved, obj["position"], obj["quat_xyzw"], mass, OBJECT_RGBA)
    return body, mass, radius


class _Recorder:
    """The replay's frames, drawn by `planner.sim.render` as `regrasp view --gif` draws a
    plan: the contact-seeing camera along the hand's ``palm_normal`` aimed at the plan's
    contacts, the simulator's contacts with their inward normals in the fingers' colours,
    the moving finger in magenta, a gravity arrow, and a caption with the phase, the state,
    the plan's metric, the drift and the gravity direction.

    It only reads the simulation (poses, contacts, the controller's commands) and changes
    colours of visual shapes; it never steps, resets or commands anything.
    """

    #: GIF viewers show a frame for at least 20 ms: a GIF alone gets no closer frames.
    GIF_MIN_S = 0.02

    def __init__(self, sim: "_Sim", rd: Plan, info: _HandInfo, width: int, height: int, keep_rgb: bool):
        from planner.gravity import gravity_directions
        from planner.sim import render

        self.sim, self.rd, self.render, self.keep_rgb = sim, rd, render, keep_rgb
        hand = info.hand
        q0 = np.array(hand.q_open, dtype=float)
        names = list(hand.joint_names)
        for j, v in zip(rd.joints, rd.states[0].q):
            q0[names.index(j)] = v
        T = sim.T_ref
        pts = np.array([T[:3, :3] @ x + T[:3, 3] for st in rd.states for P, _ in st.patches.values()
                        for x in np.asarray(P, float).reshape(-1, 3)]).reshape(-1, 3)
        extent = float(np.ptp(pts, axis=0).max()) if len(pts) > 1 else 0.03
        self.normal_len_m = 0.2 * extent
        self.scene = render.HandScene.adopt(hand, sim.hand, sim.obj, sim.cid, width=width, height=height)
        self.camera = render.contact_camera(hand, np.eye(4), pts if len(pts) else None, T[:3, 3],
                                            render.hand_reach_m(hand, q0, T[:3, 3], (extent,)))
        self.g = np.asarray(sim.params["gravity"], float)
        g = float(np.linalg.norm(self.g))
        self.g_name = "off" if g == 0 else "[" + " ".join(f"{v:+.2f}" for v in self.g / g) + "]"
        for name, v in gravity_directions(info.palm_normal, 7, g):
            if g > 0 and np.linalg.norm(v) > 0 and float(np.dot(v, self.g)) / (g * np.linalg.norm(v)) > 1 - 1e-6:
                self.g_name = name
        self.frames: list = []
        self.times: list[float] = []
        self.palette = None
        self._phase, self._moved = None, False

    def _doing(self) -> tuple[str, int, str | None]:
        """(what happens, the state it concerns, the finger to colour) from the simulation."""
        sim, ctl = self.sim, self.sim.ctl
        phase = sim.phase
        if phase != self._phase:
            self._phase, self._moved = phase, False
        if phase.startswith("acquiring"):
            return "acquire: the fingers take state 0's contacts (gravity off, object held)", 0, None
        if phase.startswith("gravity ramp"):
            g = float(np.linalg.norm(self.g))
            if g == 0:
                return "object released (gravity off)", 0, None
            share = float(np.linalg.norm(ctl.gravity)) / g
            return f"gravity ramp: {100 * share:.0f}% of {g:.2f} m/s^2, object released", 0, None
        if phase.startswith("settling"):
            return "settle at state 0", 0, None
        k = phase.split(" ", 2)[1] if phase.startswith("step ") else ""
        if not k.isdigit() or int(k) >= len(self.rd.steps):
            return phase, 0, None
        st = self.rd.steps[int(k)]
        head = f"step {int(k) + 1}/{len(self.rd.steps)}: {st.finger} {st.action} (state {st.from_state} -> {st.to_state})"
        if ctl.moving == st.finger:
            self._moved = True
            return f"{head}: moving", st.from_state, st.finger
        share = ctl.share.get(st.finger, 1.0)
        if not self._moved:
            return f"{head}: unloading", st.from_state, st.finger
        if share < 1.0:
            return f"{head}: loading", st.to_state, st.finger
        return f"{head}: dwell at state {st.to_state}", st.to_state, None

    def grab(self):
        """Draw the simulation as it is now (called every ``gif_every`` physics steps)."""
        sim = self.sim
        t = sim.steps_done * sim.dt
        if not self.keep_rgb and self.times and t - self.times[-1] < self.GIF_MIN_S - 1e-9:
            return
        doing, i, finger = self._doing()
        state = self.rd.states[i]
        mm, deg = sim.last
        over = not (mm <= sim.params["drift_mm_max"] and deg <= sim.params["drift_deg_max"])
        caption = (f"{doing}\nstate {i}: plan metric {state.metric:.4g}, "
                   f"{'force closure' if state.is_force_closure else 'NO closure'}\n"
                   f"drift {mm:.2f} mm / {deg:.2f} deg{' OVER LIMIT' if over else ''}, gravity {self.g_name}, "
                   f"t {t:.2f} s")
        T = sim._obj_pose()
        patches: dict[str, tuple[list, list]] = {}
        for link, pt, n in sim._contact_sample(T):
            P, N = patches.setdefault(sim.link_finger.get(link, "palm"), ([], []))
            P.append(pt[0])
            N.append(n[0])
        markers = self.render.patch_markers(self.scene.hand, None, patches, self.normal_len_m, T_palm_obj=T)
        img = self.scene.image(markers=markers, caption=caption, moving_finger=finger, camera=self.camera,
                               gravity=self.g, gravity_label=f"g {self.g_name}", touching=set(patches))
        if not self.keep_rgb:  # a GIF alone: palette frames, one palette for the film
            if self.palette is None:
                self.palette = self.render.gif_palette(img)
            img = self.render.gif_frame(img, self.palette)
        self.frames.append(img)
        self.times.append(t)

    def write_gif(self, path) -> int:
        """The GIF at the simulation's speed (frames at least ``GIF_MIN_S`` apart); its frame count."""
        keep, last = [], None
        for k, t in enumerate(self.times):
            if last is None or t - last >= self.GIF_MIN_S - 1e-9:
                keep.append(k)
                last = t
        frames = [self.frames[k] for k in keep]
        self.render.write_gif(frames, path, durations_ms=self.render.gif_durations_ms([self.times[k] for k in keep]))
        return len(frames)


def _write_mp4(frames: list[np.ndarray], path: str, fps: float, ffmpeg: str) -> None:
    from PIL import Image

    with tempfile.TemporaryDirectory(prefix="regrasp-mp4-") as tmp:
        for i, f in enumerate(frames):
            Image.fromarray(f).save(os.path.join(tmp, f"{i:05d}.png"))
        cmd = [ffmpeg, "-y", "-loglevel", "error", "-framerate", f"{fps:.3f}", "-i", os.path.join(tmp, "%05d.png"),
               "-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2", "-pix_fmt", "yuv420p", str(path)]
        out = subprocess.run(cmd, capture_output=True, text=True)
        if out.returncode != 0:
            raise SimulationError(f"ffmpeg failed writing {path}: {out.stderr.strip().splitlines()[-1:]}")


# --------------------------------------------------------------------------- replay


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
) -> ReplayReport:
    """Replay a plan in pybullet with gravity on; re-measure contacts, closure and drift.

    Args:
        plan: plan data (the schema of docs/INTERFACES.md) or a plan file (.yaml/.json)
            (or a plan this module has already read).
        client: an existing pybullet client id; the replay adds its bodies there and removes
            them at the end. None: a private DIRECT (or GUI) client, disconnected at the end.
        gui: open a pybullet GUI window (needs a display) and run in real time.
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
        solver_iterations: pybullet numSolverIterations.
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

    Returns:
        ReplayReport with a pass/fail verdict (drift and closure agreement), per-state
        closure and drift, and where and why it failed.

    Raises:
        SpecError: the plan lacks a key or has a bad value (names the file and key).
        SimulationError: pybullet could not set up the scene, or ffmpeg is missing for mp4.
    """
    rd = _read_plan(plan, strict)
    joints, states, steps, obj, friction = list(rd.joints), rd.states, rd.steps, dict(rd.object), Friction(**rd.friction)
    positive = [("dt", dt), ("drift_mm_max", drift_mm_max), ("drift_deg_max", drift_deg_max),
                ("drop_mm", drop_mm), ("joint_speed_rad_s", joint_speed_rad_s)]
    if finger_force_n is not None:
        positive.append(("finger_force_n", finger_force_n))
    for name, v in positive:
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise InputError(f"{name} must be a positive number, got {v!r}")
    info = _load_hand(rd, joints, hand)
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
                  mu=friction.mu, gamma=friction.gamma, edges=friction.edges, touch_tol_m=TOUCH_TOL_M)

    own = client is None
    if own:
        cid = p.connect(p.GUI if gui else p.DIRECT)
        if cid < 0:
            raise SimulationError("could not connect to pybullet" + (" GUI (is there a display?)" if gui else ""))
    else:
        cid = int(client)
    bodies: list[int] = []
    t0 = time.perf_counter()
    try:
        # the hand's visual meshes only matter to a picture or a window (half the URDF load)
        visual = gui or not own or gif is not None or mp4 is not None
        sim = _Sim(cid, rd, info, joints, obj, friction, params, density_kg_m3, bodies, visual=visual)
        params["object_mass_kg"] = sim.mass
        recorder = None
        if gif is not None or mp4 is not None:
            recorder = _Recorder(sim, rd, info, width, height, keep_rgb=mp4 is not None)
        result = sim.run(states, steps, recorder=recorder, every=int(gif_every), realtime=gui and own)
        trajectory = sim.trajectory
        params["squeeze_force_n"] = sim.ctl.force_n if finger_force_n is None else float(finger_force_n)
    finally:
        if own:
            p.disconnect(physicsClientId=cid)
        else:
            for b in bodies:
                p.removeBody(b, physicsClientId=cid)
    wall = time.perf_counter() - t0

    gif_frames = 0
    if recorder is not None:
        if gif is not None:
            gif_frames = recorder.write_gif(gif)
        if mp4 is not None:
            _write_mp4(recorder.frames, str(mp4), 1.0 / (dt * int(gif_every)), ffmpeg)

    reports, dropped, max_mm, max_deg, fin_mm, fin_deg, n_steps, failure, fail_step = result
    reached = [r for r in reports if r.reached]
    agree = sum(1 for r in reached if r.sim_force_closure == r.planned_force_closure)
    disagree = [r for r in reached if r.sim_force_closure != r.planned_force_closure]
    other = [r for r in reached if not r.holds_as_planned]
    within = math.isfinite(max_mm) and math.isfinite(max_deg) and max_mm <= drift_mm_max and max_deg <= drift_deg_max
    passed = (not dropped) and within and not disagree and not other and len(reached) == len(reports)
    limits = f"limits {drift_mm_max:g} mm / {drift_deg_max:g} deg"
    if dropped:
        verdict = f"FAIL: object dropped (moved more than {drop_mm:g} mm)"
    elif not within:
        verdict = f"FAIL: drift {max_mm:.1f} mm / {max_deg:.1f} deg exceeds the {limits}"
    elif disagree:
        verdict = (f"FAIL: the simulator's force closure disagrees with the plan at "
                   f"{len(disagree)}/{len(reached)} states (max drift {max_mm:.1f} mm / {max_deg:.1f} deg)")
    elif other:
        verdict = (f"FAIL: the simulator holds the object with other links than the plan's at {len(other)}/"
                   f"{len(reached)} states (max drift {max_mm:.1f} mm / {max_deg:.1f} deg)")
    else:
        verdict = f"PASS: max drift {max_mm:.1f} mm / {max_deg:.1f} deg ({limits}); closure agrees at {agree}/{len(reached)} states"
    reasons = []
    if failure is not None:
        reasons.append(failure)
    for r in disagree:
        plan_fc = "force closure" if r.planned_force_closure else "not force closure"
        sim_fc = "force closure" if r.sim_force_closure else "not force closure"
        missing = sorted(set(r.planned_fingers) - set(r.sim_fingers))
        reasons.append(f"state {r.index}: plan {plan_fc}, simulator {sim_fc} (touching: "
                       f"{', '.join(r.sim_fingers) or 'nothing'}" + (f"; lost: {', '.join(missing)}" if missing else "") + ")")
    for r in other:
        if r in disagree:
            continue
        extra = sorted(set(r.carriers) - set(r.planned_fingers))
        idle = sorted(set(r.planned_fingers) - set(r.sim_fingers))
        words = ([f"carried by {', '.join(extra)} too"] if extra else []) + ([f"{', '.join(idle)} not touching"] if idle else [])
        reasons.append(f"state {r.index}: the plan holds with {', '.join(r.planned_fingers)}; in the simulator "
                       + "; ".join(words) + f" (forces: {', '.join(f'{f} {v:.2f} N' for f, v in sorted(r.carried_n.items()))})")
    failed_step, at_state = None, False
    if not passed:
        bad_states = [r.index for r in disagree + other] + [r.index for r in reports if not r.reached]
        first_bad = min(bad_states) if bad_states else None
        candidates = [k for k in (fail_step, None if first_bad is None else first_bad - 1) if k is not None]
        failed_step = min(candidates) if candidates else -1
        at_state = fail_step is None or (first_bad is not None and first_bad - 1 < fail_step)
    if reasons and not passed:
        verdict += ": " + "; ".join(reasons[:3]) + (f" (+{len(reasons) - 3} more)" if len(reasons) > 3 else "")
    return ReplayReport(
        passed=passed, verdict=verdict, dropped=dropped,
        max_drift_mm=max_mm, max_drift_deg=max_deg, final_drift_mm=fin_mm, final_drift_deg=fin_deg,
        drift_mm_max=float(drift_mm_max), drift_deg_max=float(drift_deg_max),
        closure_agreement=(agree, len(reached)), states=tuple(reports),
        sim_time_s=n_steps * dt, wall_time_s=wall, sim_steps=n_steps,
        gif=str(gif) if gif is not None else None, gif_frames=gif_frames,
        mp4=str(mp4) if mp4 is not None else None, parameters=params, reasons=tuple(reasons),
        failed_step=failed_step, failed_at_state=at_state, trajectory=trajectory,
    )


@dataclass(frozen=True)
class GravitySetReport:
    """Outcome of `replay_gravity_set`: one replay per gravity direction.

    Attributes:
        passed: every direction passed.
        verdict: one line: PASS/FAIL with the directions that failed.
        directions: (name, gravity (3,), ReplayReport) per direction, in `planner.gravity` order.
    """

    passed: bool
    verdict: str
    directions: tuple[tuple[str, tuple[float, float, float], ReplayReport], ...]

    def to_dict(self) -> dict:
        """Plain data for JSON."""
        return {"passed": self.passed, "verdict": self.verdict,
                "directions": [{"name": n, "gravity": list(g), "report": r.to_dict()} for n, g, r in self.directions]}


def replay_gravity_set(plan: Mapping | str | os.PathLike, n: int = 6, *, hand=None, g_mps2: float = 9.81,
                       film: Sequence[str] | None = None, strict: bool = False, workers: int | None = None,
                       **kwargs) -> GravitySetReport:
    """Replay a plan under several gravity directions of the palm frame (`planner.gravity`).

    Args:
        plan: plan data or file, as for `replay_plan`.
        n: set size (`planner.gravity.GRAVITY_SET_SIZES`): 1 palm down, 2 palm down and up,
            6 with the four sideways directions, 7 with gravity off too.
        hand: the plan's `planner.hand.Hand` (loaded from the plan when None).
        g_mps2: gravity magnitude.
        film: the direction names filmed when ``gif`` or ``mp4`` is given (default: all).
        strict: refuse a plan file whose recorded inputs changed or are gone (`replay_plan`).
        workers: processes the directions are replayed in (`planner.sim.verify.replay_directions`;
            default: the cores available; the reports are those of a serial run).
        **kwargs: passed to `replay_plan` (not ``gravity``; a ``gif`` path gets the direction
            name inserted before its suffix).

    Returns:
        GravitySetReport; ``passed`` only when every direction passed.
    """
    from planner.gravity import gravity_directions

    if "gravity" in kwargs:
        raise InputError("replay_gravity_set takes no gravity: it replays the set's directions")
    rd = _read_plan(plan, strict)  # read and verified once for every direction
    if hand is None:
        hand = _plan_hand(rd)
    directions = gravity_directions(hand.palm_normal, n, g_mps2)
    names = [name for name, _ in directions]
    unknown = sorted(set(film or ()) - set(names))
    if unknown:
        raise InputError(f"cannot film {', '.join(unknown)}: the gravity set of {n} has {', '.join(names)}")
    from planner.sim.verify import replay_directions

    kw = dict(kwargs)
    for key in ("gif", "mp4"):
        if kw.get(key) is not None:
            path = Path(kw[key])
            kw[key] = [None if film is not None and name not in film else path.with_name(f"{path.stem}_{name}{path.suffix}")
                       for name in names]
    reports = replay_directions(rd, hand, directions, workers=workers, **kw)
    out = [(name, g, r) for (name, g), r in zip(directions, reports)]
    failed = [(name, r) for name, _, r in out if not r.passed]
    if not failed:
        worst_mm = max(r.max_drift_mm for _, _, r in out)
        worst_deg = max(r.max_drift_deg for _, _, r in out)
        verdict = f"PASS in all {len(out)} gravity directions: max drift {worst_mm:.1f} mm / {worst_deg:.1f} deg"
    else:
        verdict = (f"FAIL in {len(failed)}/{len(out)} gravity directions: "
                   + "; ".join(f"{name}: {r.verdict.removeprefix('FAIL: ')}" for name, r in failed))
    return GravitySetReport(not failed, verdict, tuple(out))


class _Sim:
    """The pybullet scene of one replay (hand, object, controller, measurements)."""

    def __init__(self, cid, rd, info: _HandInfo, joints, obj, friction, params, density_kg_m3, bodies,
                 visual: bool = True):
        self.cid, self.rd, self.params, self.friction = cid, rd, params, friction
        self.dt = params["dt"]
        p.setPhysicsEngineParameter(fixedTimeStep=self.dt, numSolverIterations=params["solver_iterations"],
                                    numSubSteps=0, deterministicOverlappingPairs=1, physicsClientId=cid)
        p.setGravity(0, 0, 0, physicsClientId=cid)
        base_pos = info.T_palm_base[:3, 3].tolist()
        base_quat = Rotation.from_matrix(info.T_palm_base[:3, :3]).as_quat().tolist()
        self.hand = hand_body(cid, info.urdf_path, base_pos=base_pos, base_quat_xyzw=base_quat,
                              inertia_from_file=True, visual=visual)
        bodies.append(self.hand)
        self.obj, self.mass, radius_m = _create_object(cid, rd, obj, density_kg_m3)
        bodies.append(self.obj)
        self.T_ref = _T(obj["position"], obj["quat_xyzw"])
        self._p_ref = tuple(float(v) for v in self.T_ref[:3, 3])
        self._quat_ref = tuple(float(v) for v in Rotation.from_matrix(self.T_ref[:3, :3]).as_quat())

        # joint and link maps
        n = p.getNumJoints(self.hand, physicsClientId=cid)
        self.jidx: dict[str, int] = {}
        parent, jname, link_name = {}, {}, {}
        for i in range(n):
            ji = p.getJointInfo(self.hand, i, physicsClientId=cid)
            jname[i] = ji[1].decode()
            link_name[i] = ji[12].decode()
            parent[i] = ji[16]
            if ji[2] in (p.JOINT_REVOLUTE, p.JOINT_PRISMATIC):
                self.jidx[jname[i]] = i
        unknown = [j for j in joints if j not in self.jidx]
        if unknown:
            raise rd.error("joints", f"joints {unknown} are not movable joints of {info.urdf_path}")
        self.joints = joints
        self.fingers = info.fingers
        finger_of_joint = {j: f for f, js in info.fingers.items() for j in js}
        self.link_finger: dict[int, str] = {-1: "palm"}
        for i in range(n):
            k, f = i, None
            while k >= 0 and f is None:
                f = finger_of_joint.get(jname[k])
                k = parent[k]
            self.link_finger[i] = f or "palm"

        # friction: see the module docstring for Bullet's combination rules. Joint damping
        # off: Bullet applies a URDF's <dynamics damping> explicitly, and the Allegro's 3-10
        # N m s/rad on links of ~1e-5 kg m^2 diverges within a few steps under torque
        # control (the controller damps the joints itself, critically for their inertia).
        for link in range(-1, n):
            p.changeDynamics(self.hand, link, lateralFriction=1.0, spinningFriction=0.0, rollingFriction=0.0,
                             restitution=0.0, linearDamping=0.0, angularDamping=0.0, physicsClientId=cid)
            if link >= 0:
                p.changeDynamics(self.hand, link, jointDamping=0.0, physicsClientId=cid)
        # a URDF's placeholder inertias (e.g. 0.01 kg m^2 on a 14 g phalanx) make fingers
        # flywheels that cannot follow the object: a solid box of the link's mass and
        # collision size instead (`planner.handtool.replay_inertia`; `regrasp hand check` says so)
        from planner.handtool import replay_inertia

        by_name = {v: k for k, v in link_name.items()}
        for link, (_, _, box) in replay_inertia(info.hand).items():
            if link in by_name:
                p.changeDynamics(self.hand, by_name[link], localInertiaDiagonal=box.tolist(), physicsClientId=cid)
        p.changeDynamics(self.obj, -1, lateralFriction=friction.mu, spinningFriction=friction.gamma,
                         rollingFriction=0.0, restitution=0.0, linearDamping=0.0, angularDamping=0.0,
                         physicsClientId=cid)
        g_max = float(np.linalg.norm(params["gravity"]))
        self.ctl = Controller(cid, self.hand, self.obj, info.hand, self.jidx, self.link_finger, link_name,
                              self.mass, friction, g_max, force_n=params["finger_force_n"], dt_s=self.dt,
                              object_radius_m=radius_m)
        self.filter = ContactFilter(params["filter_k"])
        self.steps_done = 0
        self.max_mm = self.max_deg = 0.0
        self.phase = "acquiring the initial grasp"
        self.sampling = False
        self.traj_every = max(1, int(round(TRAJECTORY_DT_S / self.dt)))
        self.trajectory: dict = {"joints": list(info.hand.joint_names), "t": [], "q": [], "object_position": [],
                                 "object_quat_xyzw": []}
        self.failure: str | None = None
        self.fail_step: int | None = None  # plan step (-1: state 0) at which the drift first left the limits
        self.step_k = -1
        self.carried: dict[str, float] = {}  # finger or "palm" -> summed normal force over the sampling window
        self.samples = 0
        self.last_patches: Mapping[str, tuple[np.ndarray, np.ndarray]] = {}

    def _q(self, state) -> dict[str, float]:
        """Joint name -> value of a plan state."""
        return dict(zip(self.joints, state.q))

    def _reset_q(self, q: Mapping[str, float]):
        for j, v in q.items():
            p.resetJointState(self.hand, self.jidx[j], v, 0.0, physicsClientId=self.cid)

    def _obj_pose(self, pose=None) -> np.ndarray:
        """The object's pose (4, 4); ``pose``: its (position, quaternion) when already read."""
        pos, quat = pose or p.getBasePositionAndOrientation(self.obj, physicsClientId=self.cid)
        T = np.eye(4)
        T[:3, :3] = np.reshape(p.getMatrixFromQuaternion(quat, physicsClientId=self.cid), (3, 3))
        T[:3, 3] = pos
        return T

    def _tick(self):
        self.ctl.step()
        p.stepSimulation(physicsClientId=self.cid)
        self.steps_done += 1
        pos, quat = p.getBasePositionAndOrientation(self.obj, physicsClientId=self.cid)
        if self.sampling:  # the temporal filter only needs the samples before a measurement
            self.filter.update(self._contact_sample(self._obj_pose((pos, quat)), carry=True))
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
                self.failure = self._explain(self._obj_pose((pos, quat)), mm, deg)
                self.fail_step = self.step_k
        self.last = (mm, deg)
        if self.recorder is not None and self.steps_done % self.every == 0:
            self.recorder.grab()
        if self.realtime:
            time.sleep(self.dt)
        return mm

    def _contact_sample(self, T: np.ndarray, carry: bool = False) -> list:
        """This step's contacts as (link, p_obj (1, 3), n_obj (1, 3)), normals INTO the object;
        ``carry``: also add their normal forces to the measurement window's (`carried`), once
        per physics step (a picture or an explanation reads the contacts too)."""
        R_t = T[:3, :3].T
        sample = []
        if carry:
            self.samples += 1
        for cp in p.getContactPoints(self.hand, self.obj, physicsClientId=self.cid):
            if cp[8] > TOUCH_TOL_M:
                continue
            if carry:
                who = self.link_finger.get(cp[3], "palm")
                self.carried[who] = self.carried.get(who, 0.0) + float(cp[9])
            p_obj = R_t @ (np.asarray(cp[6]) - T[:3, 3])  # point on the object (B)
            n_obj = R_t @ (-np.asarray(cp[7]))  # into the object
            sample.append((cp[3], p_obj[None, :], n_obj[None, :]))
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
        touching = {self.link_finger.get(cp[3], "palm") for cp in
                    p.getContactPoints(self.hand, self.obj, physicsClientId=self.cid) if cp[8] <= TOUCH_TOL_M}
        lost = [f for f in self.ctl.holding if f not in touching]
        if lost:
            what.append(f"contact lost: {', '.join(lost)}")
        if not self.ctl.balanced:
            what.append("no forces at the touching links balance the load inside the friction cones")
        stray = sorted(f for f in touching if f not in self.ctl.holding)
        if stray:
            what.append(f"touched by {', '.join(stray)} (not holding)")
        now: dict[str, list] = {}
        for link, pt, _ in self._contact_sample(T):
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
        return StateReport(index, True, self.steps_done * self.dt, state.touching, tuple(sorted(patches)),
                           state.is_force_closure, state.metric, fc, metric, n_pts, mm, deg, patches,
                           {f: round(v, 6) for f, v in sorted(carried.items())}, carriers, offsets)

    def run(self, states, steps, recorder=None, every=8, realtime=False):
        self.recorder, self.every, self.realtime = recorder, every, realtime
        self.released = False
        ctl, prm = self.ctl, self.params
        g_full = np.asarray(prm["gravity"], float)
        self._reset_q(self._q(states[0]))
        pos, quat = list(self._p_ref), list(self._quat_ref)
        p.resetBasePositionAndOrientation(self.obj, pos, quat, physicsClientId=self.cid)
        p.resetBaseVelocity(self.obj, [0, 0, 0], [0, 0, 0], physicsClientId=self.cid)
        # 1. acquire the planned contacts with gravity off, the object held where the plan has it
        hold = p.createConstraint(self.obj, -1, -1, -1, p.JOINT_FIXED, [0, 0, 0], [0, 0, 0], pos,
                                  childFrameOrientation=quat, physicsClientId=self.cid)
        p.changeConstraint(hold, maxForce=1000.0, physicsClientId=self.cid)
        ctl.set_gravity(np.zeros(3))
        ctl.command(self._q(states[0]), states[0].touching)
        self._run_for(prm["acquire_s"])
        ctl.latch(states[0].touching)
        p.removeConstraint(hold, physicsClientId=self.cid)
        self.released = True
        # 2. gravity comes in gradually; the forces follow the load
        self.phase = "gravity ramp at state 0"
        ok = self._run_for(prm["ramp_s"], lambda s: ctl.set_gravity(s * g_full))
        self.phase = "settling at state 0"
        reports: dict[int, StateReport] = {}
        if ok:
            r0 = self._dwell_and_measure(prm["settle_s"], 0, states[0])
            ok = r0 is not None
            if ok:
                reports[0] = r0
        for k, st in enumerate(steps if ok else ()):
            frm, to = states[st.from_state], states[st.to_state]
            self.phase = f"step {k} ({st.action} {st.finger}, state {st.from_state} -> {st.to_state})"
            self.step_k = k
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
            for a, b in zip(path[:-1], path[1:]):
                n = max(1, int(math.ceil(float(np.max(np.abs(b - a))) / (prm["joint_speed_rad_s"] * self.dt))))
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
            r = self._dwell_and_measure(prm["dwell_s"], st.to_state, to) if ok else None
            if r is None:
                ok = False
                break
            reports[st.to_state] = r
        out = []
        for i, s in enumerate(states):
            if i in reports:
                out.append(reports[i])
            else:
                out.append(StateReport(i, False, self.steps_done * self.dt, s.touching, (), s.is_force_closure, s.metric,
                                       None, None, 0, float("nan"), float("nan")))
        mm, deg = self.last
        return out, not ok, self.max_mm, self.max_deg, mm, deg, self.steps_done, self.failure, self.fail_step
