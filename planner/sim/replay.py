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
the simulator's spinning friction provides: ``GFO_MARGINS``), no component above
``GFO_MAX_FORCE * F`` and a normal force of at least ``0.1 F`` (``F = finger_force_n``;
`_Sim._grasp_forces`). Plain normal squeezing is kept only when no balanced forces exist
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
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from planner.closure import CONTACT_MODELS, Friction, apply_contact_model, grasp_closure
from planner.errors import InputError, SimulationError, SpecError, UnknownNameError
from planner.sim.contact_filter import ContactFilter

try:  # pybullet prints a build banner on import: keep a command's stdout clean
    from planner.sim.render import quiet_native_output
except ImportError:  # pragma: no cover - render helper not present
    import contextlib

    quiet_native_output = contextlib.nullcontext
with quiet_native_output():
    import pybullet as p

_REPO = Path(__file__).resolve().parents[2]
_ROBOTS_DIR = _REPO / "robots"
#: A point more than this far outside the object is not a contact (pybullet reports
#: speculative manifold points with positive distance).
TOUCH_TOL_M = 0.0005
#: Joint torque cap of fingers that do not touch the object (they only track their path).
FREE_TORQUE_NM = 0.5
#: Minimum torque of every joint of a squeezing finger, so joints orthogonal to the
#: contact normal still hold their posture.
HOLD_TORQUE_NM = 0.05
#: Squeeze target: joint offset per metre of ``squeeze_m`` (1 mm ~ 0.05 rad at 20 mm).
SQUEEZE_RAD_PER_M = 50.0
#: A landing finger closer than this to the object finishes its path with its squeeze
#: torque caps instead of ``FREE_TORQUE_NM``, so it touches down softly instead of
#: striking the object with the free-motion torque (up to ~10 N at a fingertip).
LANDING_ZONE_M = 0.002
#: Grasp force optimization: (friction-cone fraction, torsional-friction fraction) tried in
#: turn; point-contact forces first, the soft-finger torsion only when they do not exist.
GFO_MARGINS = ((0.5, 0.0), (0.5, 0.5), (0.75, 0.0), (0.75, 0.75), (1.0, 0.0), (1.0, 1.0))
#: A force solution with a component above this multiple of ``finger_force_n`` is rejected
#: (an almost singular grasp balanced by large internal forces the fingers cannot hold).
GFO_MAX_FORCE = 5.0
#: Before a finger lifts, the other fingers take over its load for this long, s.
UNLOAD_S = 0.1


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


@dataclass(frozen=True)
class ReplayReport:
    """Outcome of `replay_plan`.

    Attributes:
        passed: no drop and the drift stayed within both thresholds at every state.
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


class _PlanReader:
    """Key access into plan data that fails with SpecError(file, key path)."""

    def __init__(self, data: Any, path: str):
        self.data = data
        self.path = path

    def get(self, *keys, default=..., parent=None):
        node = self.data if parent is None else parent[0]
        where = [] if parent is None else [parent[1]]
        for key in keys:
            where.append(f"[{key}]" if isinstance(key, int) else str(key))
            try:
                node = node[key]
            except (KeyError, IndexError, TypeError):
                if default is not ...:
                    return default
                raise SpecError(self.path, ".".join(where).replace(".[", "["), "missing key") from None
        return node

    def fail(self, key: str, message: str) -> SpecError:
        return SpecError(self.path, key, message)


def _read_plan(plan: Mapping | str | os.PathLike) -> tuple[dict, str]:
    if isinstance(plan, Mapping):
        return dict(plan), "<plan>"
    path = Path(plan)
    try:
        from planner.plan import read_plan
    except ImportError:  # plan module not available: plain YAML/JSON read
        read_plan = None
    if read_plan is not None:
        return read_plan(path), str(path)
    import yaml

    try:
        text = path.read_text()
    except OSError as err:
        raise SpecError(str(path), "", f"cannot read plan: {err.strerror}") from err
    try:
        data = json.loads(text) if path.suffix.lower() == ".json" else yaml.safe_load(text)
    except (json.JSONDecodeError, yaml.YAMLError) as err:
        raise SpecError(str(path), "", f"not valid YAML/JSON: {str(err).splitlines()[0]}") from err
    if not isinstance(data, dict):
        raise SpecError(str(path), "", "expected a mapping at the top level")
    return data, str(path)


@dataclass(frozen=True)
class _HandInfo:
    urdf_path: str
    fingers: dict[str, tuple[str, ...]]  # finger -> joint names
    T_palm_base: np.ndarray  # pose of the URDF root link in the palm frame


def _resolve(path_str: str, plan_path: str) -> Path | None:
    cand = [Path(path_str)]
    if plan_path != "<plan>":
        cand.append(Path(plan_path).resolve().parent / path_str)
    cand += [Path.cwd() / path_str, _REPO / path_str]
    for c in cand:
        if c.exists():
            return c.resolve()
    return None


def _T_palm_root(hand) -> np.ndarray:
    """Pose of the URDF root link in the palm frame (identity when the root is the palm)."""
    root = getattr(getattr(hand, "model", None), "frames", None)
    if root is None or len(root) < 2 or not hasattr(hand, "link_pose"):
        return np.eye(4)
    root_name = root[1].name  # frame 0 is "universe", frame 1 the root link
    if root_name == getattr(hand, "palm_frame", root_name):
        return np.eye(4)
    return np.asarray(hand.link_pose(hand.q_open, root_name), dtype=float)


def _load_hand(rd: _PlanReader, joints: list[str], hand=None) -> _HandInfo:
    """Hand URDF and finger -> joints, from `planner.hand.Hand` when available."""
    if hand is None:
        name = rd.get("hand", "name")
        spec = rd.get("hand", "spec", default=None)
        target = name
        if spec:
            resolved = _resolve(str(spec), rd.path)
            target = str(resolved) if resolved is not None else name
        try:
            from planner.hand import Hand
        except ImportError:
            Hand = None
        if Hand is not None:
            hand = Hand.load(target)
    if hand is not None:
        fingers = {f: tuple(fg.joints) for f, fg in hand.fingers.items()}
        return _HandInfo(str(hand.urdf_path), fingers, _T_palm_root(hand))
    # fallback without planner.hand: robots/<name>/<name>.urdf, fingers by joint-name prefix
    urdf = _ROBOTS_DIR / name / f"{name}.urdf"
    if not urdf.exists():
        raise rd.fail("hand.name", f"no URDF for hand {name!r} at {urdf}")
    fingers: dict[str, list[str]] = {}
    for j in joints:
        fingers.setdefault(j.rsplit("_", 1)[0], []).append(j)
    return _HandInfo(str(urdf), {f: tuple(js) for f, js in fingers.items()}, np.eye(4))


@dataclass(frozen=True)
class _State:
    q: dict[str, float]
    fingers: tuple[str, ...]  # touching fingers in the plan
    is_fc: bool
    metric: float


@dataclass(frozen=True)
class _Step:
    finger: str
    action: str
    from_state: int
    to_state: int
    joints: tuple[str, ...]
    path: np.ndarray  # (m, len(joints))


def _parse(rd: _PlanReader) -> tuple[list[str], list[_State], list[_Step], dict, Friction]:
    joints = [str(j) for j in rd.get("joints")]
    states_raw = rd.get("states")
    if not isinstance(states_raw, list) or not states_raw:
        raise rd.fail("states", "expected a non-empty list of states")
    states = []
    for i, s in enumerate(states_raw):
        q = rd.get("states", i, "q")
        missing = [j for j in joints if j not in q]
        if missing:
            raise rd.fail(f"states[{i}].q", f"missing joints {missing}")
        patches = rd.get("states", i, "patches", default={}) or {}
        states.append(_State(
            q={j: float(q[j]) for j in joints},
            fingers=tuple(patches),
            is_fc=bool(rd.get("states", i, "closure", "is_force_closure")),
            metric=float(rd.get("states", i, "closure", "metric")),
        ))
    steps = []
    for i, st in enumerate(rd.get("steps") or []):
        sj = tuple(str(j) for j in rd.get("steps", i, "joints"))
        path = np.asarray(rd.get("steps", i, "path"), dtype=float)
        if path.ndim != 2 or path.shape[1] != len(sj) or len(path) < 1:
            raise rd.fail(f"steps[{i}].path", f"expected waypoints of {len(sj)} joint values")
        unknown = [j for j in sj if j not in joints]
        if unknown:
            raise rd.fail(f"steps[{i}].joints", f"joints {unknown} are not in the plan's joints")
        fs, ts = int(rd.get("steps", i, "from_state")), int(rd.get("steps", i, "to_state"))
        for key, v in (("from_state", fs), ("to_state", ts)):
            if not 0 <= v < len(states):
                raise rd.fail(f"steps[{i}].{key}", f"expected a state index in 0..{len(states) - 1}")
        steps.append(_Step(str(rd.get("steps", i, "finger")), str(rd.get("steps", i, "action")), fs, ts, sj, path))
    obj = dict(rd.get("object"))
    for key in ("shape", "size", "position", "quat_xyzw"):
        rd.get("object", key)
    fr = rd.get("friction")
    try:
        friction = Friction(rd.get("friction", "mu"), rd.get("friction", "gamma"), fr.get("edges", 5))
    except InputError as err:
        raise rd.fail("friction", str(err)) from err
    return joints, states, steps, obj, friction


# --------------------------------------------------------------------------- helpers


def _T(pos, quat_xyzw) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(quat_xyzw).as_matrix()
    T[:3, 3] = pos
    return T


def _drift(T_ref: np.ndarray, T: np.ndarray) -> tuple[float, float]:
    """(translation mm, rotation deg) of pose T relative to T_ref."""
    d_mm = float(np.linalg.norm(T[:3, 3] - T_ref[:3, 3]) * 1000.0)
    R = T_ref[:3, :3].T @ T[:3, :3]
    ang = math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(R) - 1.0) / 2.0))))
    return d_mm, ang


def _object_volume(shape: str, size) -> float | None:
    if shape == "box":
        return float(np.prod(size[:3]))
    if shape == "cylinder":
        return math.pi * size[0] ** 2 * size[1]
    if shape == "sphere":
        return 4.0 / 3.0 * math.pi * size[0] ** 3
    return None


def _create_object(cid: int, rd: _PlanReader, obj: dict, density_kg_m3: float, default_mass_kg: float) -> tuple[int, float]:
    shape = str(obj["shape"])
    size = [float(v) for v in obj["size"]]
    if shape == "box":
        if len(size) != 3:
            raise rd.fail("object.size", "a box needs 3 full extents (x, y, z)")
        kw = dict(shapeType=p.GEOM_BOX, halfExtents=[s / 2 for s in size])
        vkw = dict(kw)
    elif shape == "cylinder":
        if len(size) != 2:
            raise rd.fail("object.size", "a cylinder needs (radius, length)")
        kw = dict(shapeType=p.GEOM_CYLINDER, radius=size[0], height=size[1])
        vkw = dict(shapeType=p.GEOM_CYLINDER, radius=size[0], length=size[1])
    elif shape == "sphere":
        if len(size) != 1:
            raise rd.fail("object.size", "a sphere needs (radius,)")
        kw = dict(shapeType=p.GEOM_SPHERE, radius=size[0])
        vkw = dict(kw)
    elif shape == "mesh":
        mesh = obj.get("mesh")
        resolved = _resolve(str(mesh), rd.path) if mesh else None
        if resolved is None:
            raise rd.fail("object.mesh", f"mesh file {mesh!r} not found")
        scale = size * 3 if len(size) == 1 else size
        kw = dict(shapeType=p.GEOM_MESH, fileName=str(resolved), meshScale=scale)
        vkw = dict(kw)
    else:
        raise UnknownNameError("object shape", shape, ("box", "cylinder", "sphere", "mesh"))
    mass = obj.get("mass_kg")
    if mass is None:
        vol = _object_volume(shape, size)
        mass = density_kg_m3 * vol if vol is not None else default_mass_kg
    mass = float(mass)
    if not mass > 0:
        raise rd.fail("object.mass_kg", f"expected a positive mass, got {mass}")
    col = p.createCollisionShape(physicsClientId=cid, **kw)
    if col < 0:
        raise SimulationError(f"pybullet could not create the {shape} collision shape")
    vis = p.createVisualShape(rgbaColor=[0.85, 0.45, 0.15, 1.0], physicsClientId=cid, **vkw)
    T = _T(obj["position"], obj["quat_xyzw"])
    body = p.createMultiBody(baseMass=mass, baseCollisionShapeIndex=col, baseVisualShapeIndex=vis,
                             basePosition=T[:3, 3].tolist(), baseOrientation=list(obj["quat_xyzw"]),
                             physicsClientId=cid)
    return body, mass


class _Recorder:
    """Frames from TinyRenderer (headless) for GIF/MP4 output."""

    def __init__(self, cid: int, width: int, height: int, target, up):
        self.cid, self.width, self.height = cid, int(width), int(height)
        up = np.asarray(up, float)
        target = np.asarray(target, float)
        # look from the thumb side, slightly above the hand, with "up" against gravity
        side = np.array([0.35, -1.0, 0.0])
        side -= up * side.dot(up)
        eye = target + 0.17 * side / np.linalg.norm(side) + 0.09 * up
        self.view = p.computeViewMatrix(eye.tolist(), target.tolist(), up.tolist(), physicsClientId=cid)
        self.proj = p.computeProjectionMatrixFOV(45.0, self.width / self.height, 0.01, 2.0, physicsClientId=cid)
        self.frames: list[np.ndarray] = []

    def grab(self):
        _, _, rgba, _, _ = p.getCameraImage(self.width, self.height, self.view, self.proj,
                                            renderer=p.ER_TINY_RENDERER, physicsClientId=self.cid)
        img = np.reshape(np.asarray(rgba, dtype=np.uint8), (self.height, self.width, 4))[:, :, :3]
        self.frames.append(img.copy())


def _write_gif(frames: list[np.ndarray], path: str, frame_dt_s: float) -> None:
    from PIL import Image

    if not frames:
        raise SimulationError("no frames were rendered for the GIF")
    images = [Image.fromarray(f) for f in frames]
    duration_ms = max(20, int(round(frame_dt_s * 1000)))
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    images[0].save(path, save_all=True, append_images=images[1:], duration=duration_ms, loop=0, optimize=False)


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
    gravity: tuple[float, float, float] = (0.0, 0.0, 9.81),
    squeeze_s: float = 0.3,
    settle_s: float = 0.5,
    dwell_s: float = 0.25,
    joint_speed_rad_s: float = 1.5,
    finger_force_n: float = 1.0,
    squeeze_m: float = 0.0005,
    solver_iterations: int = 150,
    drift_mm_max: float = 5.0,
    drift_deg_max: float = 5.0,
    drop_mm: float = 30.0,
    filter_k: int = 12,
    density_kg_m3: float = 500.0,
    gif: str | os.PathLike | None = None,
    gif_every: int = 8,
    mp4: str | os.PathLike | None = None,
    width: int = 320,
    height: int = 240,
) -> ReplayReport:
    """Replay a plan in pybullet with gravity on; re-measure contacts, closure and drift.

    Args:
        plan: plan data (the schema of docs/INTERFACES.md) or a plan file (.yaml/.json).
        client: an existing pybullet client id; the replay adds its bodies there and removes
            them at the end. None: a private DIRECT (or GUI) client, disconnected at the end.
        gui: open a pybullet GUI window (needs a display) and run in real time.
        hand: a `planner.hand.Hand` to use instead of loading the plan's ``hand``.
        dt: physics time step, s.
        gravity: gravity vector in the palm (= world) frame, m/s^2. Default +z: palm down,
            the object hangs from the fingers (module docstring).
        squeeze_s: time the fingers squeeze while the object is still held, s.
        settle_s: time after releasing the object before state 0 is measured, s.
        dwell_s: time spent at every state after its step, before measuring it, s.
        joint_speed_rad_s: largest joint speed along a step's path, rad/s.
        finger_force_n: normal force each touching finger presses with, N.
        squeeze_m: how far inside the object a touching finger's target lies, m.
        solver_iterations: pybullet numSolverIterations.
        drift_mm_max, drift_deg_max: pass thresholds on the object's drift.
        drop_mm: displacement beyond which the object counts as dropped; the replay stops.
        filter_k: contact filter: a contact is removed after this many missing samples.
        density_kg_m3: density used when the plan gives no ``object.mass_kg``.
        gif: write an animated GIF here (TinyRenderer, headless).
        gif_every: render one frame every this many physics steps.
        mp4: write an MP4 here (needs ``ffmpeg`` on PATH).
        width, height: frame size in pixels.

    Returns:
        ReplayReport with a pass/fail verdict, per-state closure and drift.

    Raises:
        SpecError: the plan lacks a key or has a bad value (names the file and key).
        SimulationError: pybullet could not set up the scene, or ffmpeg is missing for mp4.
    """
    rd = _PlanReader(*_read_plan(plan))
    joints, states, steps, obj, friction = _parse(rd)
    for name, v in (("dt", dt), ("finger_force_n", finger_force_n), ("drift_mm_max", drift_mm_max),
                    ("drift_deg_max", drift_deg_max), ("drop_mm", drop_mm), ("joint_speed_rad_s", joint_speed_rad_s)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise InputError(f"{name} must be a positive number, got {v!r}")
    if int(gif_every) < 1:
        raise InputError(f"gif_every must be >= 1, got {gif_every!r}")
    ffmpeg = None
    if mp4 is not None:
        ffmpeg = shutil.which("ffmpeg")
        if ffmpeg is None:
            raise SimulationError("--mp4 needs ffmpeg on PATH and none was found; use --gif instead")
    info = _load_hand(rd, joints, hand)
    contact_model = rd.get("parameters", "contact_model", default="patch")
    if contact_model not in CONTACT_MODELS:
        raise rd.fail("parameters.contact_model", f"unknown contact model {contact_model!r}; "
                                                   f"valid: {', '.join(CONTACT_MODELS)}")
    params = dict(dt=dt, contact_model=contact_model, gravity=list(map(float, gravity)), squeeze_s=squeeze_s,
                  settle_s=settle_s, dwell_s=dwell_s,
                  joint_speed_rad_s=joint_speed_rad_s, finger_force_n=finger_force_n, squeeze_m=squeeze_m,
                  solver_iterations=int(solver_iterations), drop_mm=drop_mm, filter_k=int(filter_k),
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
        sim = _Sim(cid, rd, info, joints, obj, friction, params, density_kg_m3, bodies)
        params["object_mass_kg"] = sim.mass
        recorder = None
        if gif is not None or mp4 is not None:
            up = -np.asarray(gravity, float)
            up = up / np.linalg.norm(up) if np.linalg.norm(up) > 0 else np.array([0.0, 0.0, 1.0])
            recorder = _Recorder(cid, width, height, sim.T_ref[:3, 3], up)
        result = sim.run(states, steps, recorder=recorder, every=int(gif_every), realtime=gui and own)
    finally:
        if own:
            p.disconnect(physicsClientId=cid)
        else:
            for b in bodies:
                p.removeBody(b, physicsClientId=cid)
    wall = time.perf_counter() - t0

    gif_frames = 0
    if recorder is not None:
        frame_dt = dt * int(gif_every)
        if gif is not None:
            _write_gif(recorder.frames, str(gif), frame_dt)
            gif_frames = len(recorder.frames)
        if mp4 is not None:
            _write_mp4(recorder.frames, str(mp4), 1.0 / frame_dt, ffmpeg)

    reports, dropped, max_mm, max_deg, fin_mm, fin_deg, n_steps = result
    reached = [r for r in reports if r.reached]
    agree = sum(1 for r in reached if r.sim_force_closure == r.planned_force_closure)
    passed = (not dropped) and max_mm <= drift_mm_max and max_deg <= drift_deg_max
    if dropped:
        last = max((r.index for r in reached), default=0)
        verdict = f"FAIL: object dropped after state {last} (moved more than {drop_mm:g} mm)"
    elif not passed:
        verdict = (f"FAIL: drift {max_mm:.1f} mm / {max_deg:.1f} deg exceeds the limits "
                   f"{drift_mm_max:g} mm / {drift_deg_max:g} deg")
    else:
        verdict = (f"PASS: max drift {max_mm:.1f} mm / {max_deg:.1f} deg "
                   f"(limits {drift_mm_max:g} mm / {drift_deg_max:g} deg)")
    return ReplayReport(
        passed=passed, verdict=verdict, dropped=dropped,
        max_drift_mm=max_mm, max_drift_deg=max_deg, final_drift_mm=fin_mm, final_drift_deg=fin_deg,
        drift_mm_max=float(drift_mm_max), drift_deg_max=float(drift_deg_max),
        closure_agreement=(agree, len(reached)), states=tuple(reports),
        sim_time_s=n_steps * dt, wall_time_s=wall, sim_steps=n_steps,
        gif=str(gif) if gif is not None else None, gif_frames=gif_frames,
        mp4=str(mp4) if mp4 is not None else None, parameters=params,
    )


class _Sim:
    """The pybullet scene of one replay (hand, object, controllers, measurements)."""

    def __init__(self, cid, rd, info: _HandInfo, joints, obj, friction, params, density_kg_m3, bodies):
        self.cid, self.rd, self.params, self.friction = cid, rd, params, friction
        self.dt = params["dt"]
        p.setPhysicsEngineParameter(fixedTimeStep=self.dt, numSolverIterations=params["solver_iterations"],
                                    numSubSteps=0, deterministicOverlappingPairs=1, physicsClientId=cid)
        p.setGravity(0, 0, 0, physicsClientId=cid)
        base_pos = info.T_palm_base[:3, 3].tolist()
        base_quat = Rotation.from_matrix(info.T_palm_base[:3, :3]).as_quat().tolist()
        try:
            self.hand = p.loadURDF(info.urdf_path, base_pos, base_quat, useFixedBase=True,
                                   flags=p.URDF_USE_INERTIA_FROM_FILE, physicsClientId=cid)
        except p.error as err:
            raise SimulationError(f"pybullet could not load the hand URDF {info.urdf_path}: {err}") from err
        bodies.append(self.hand)
        self.obj, self.mass = _create_object(cid, rd, obj, density_kg_m3, 0.05)
        bodies.append(self.obj)
        self.T_ref = _T(obj["position"], obj["quat_xyzw"])

        # joint and link maps
        n = p.getNumJoints(self.hand, physicsClientId=cid)
        self.jidx: dict[str, int] = {}
        parent, jname = {}, {}
        for i in range(n):
            ji = p.getJointInfo(self.hand, i, physicsClientId=cid)
            jname[i] = ji[1].decode()
            parent[i] = ji[16]
            if ji[2] in (p.JOINT_REVOLUTE, p.JOINT_PRISMATIC):
                self.jidx[jname[i]] = i
        unknown = [j for j in joints if j not in self.jidx]
        if unknown:
            raise rd.fail("joints", f"joints {unknown} are not movable joints of {info.urdf_path}")
        self.joints = joints
        self.movable = [i for i in range(n) if p.getJointInfo(self.hand, i, physicsClientId=cid)[2] != p.JOINT_FIXED]
        self.fingers = info.fingers
        finger_of_joint = {j: f for f, js in info.fingers.items() for j in js}
        self.link_finger: dict[int, str] = {-1: "palm"}
        for i in range(n):
            k, f = i, None
            while k >= 0 and f is None:
                f = finger_of_joint.get(jname[k])
                k = parent[k]
            self.link_finger[i] = f or "palm"
        self.finger_links = {f: [i for i, g in self.link_finger.items() if g == f] for f in info.fingers}

        # friction: see the module docstring for Bullet's combination rules
        for link in range(-1, n):
            p.changeDynamics(self.hand, link, lateralFriction=1.0, spinningFriction=0.0, rollingFriction=0.0,
                             restitution=0.0, physicsClientId=cid)
        p.changeDynamics(self.obj, -1, lateralFriction=friction.mu, spinningFriction=friction.gamma,
                         rollingFriction=0.0, restitution=0.0, linearDamping=0.0, angularDamping=0.0,
                         physicsClientId=cid)
        self.filter = ContactFilter(params["filter_k"])
        self.steps_done = 0
        self.max_mm = self.max_deg = 0.0

    # -- kinematics -----------------------------------------------------------------

    def _reset_q(self, q: Mapping[str, float]):
        for j, v in q.items():
            p.resetJointState(self.hand, self.jidx[j], v, 0.0, physicsClientId=self.cid)

    def _squeeze(self, state) -> tuple[dict[str, float], dict[str, float]]:
        """Position targets and torque caps for a state (module docstring, "Squeeze")."""
        targets = dict(state.q)
        caps = {j: FREE_TORQUE_NM for j in self.joints}
        if not state.fingers:
            return targets, caps
        self._reset_q(state.q)
        pos, quat = self.T_ref[:3, 3].tolist(), Rotation.from_matrix(self.T_ref[:3, :3]).as_quat().tolist()
        p.resetBasePositionAndOrientation(self.obj, pos, quat, physicsClientId=self.cid)
        d, F = self.params["squeeze_m"], self.params["finger_force_n"]
        # one contact per finger, on its link nearest the object: (finger, joints, J (3, n) of
        # the contact point over the finger's joints, contact point, inward normal), palm frame
        found = []
        for f in state.fingers:
            if f not in self.fingers:
                raise UnknownNameError("finger", f, self.fingers)
            fj = [j for j in self.fingers[f] if j in self.jidx]
            best = self._closest_point(f, 0.01)
            if best is None:
                continue  # planned contact not within 1 cm: nothing to squeeze
            n_in = -np.asarray(best[7])  # contactNormalOnB points from the object (B) to the hand (A)
            J = self._point_jacobian(best[3], np.asarray(best[5]), fj)  # (3, len(fj))
            if float(np.linalg.norm(J.T @ n_in)) > 1e-5:
                found.append((f, fj, J, np.asarray(best[6]), n_in))
        forces = self._grasp_forces([(x[3], x[4]) for x in found], F)
        for (_, fj, J, _, _), f_c in zip(found, forces):
            t = J.T @ f_c  # joint torques that press the contact with f_c
            norm = float(np.linalg.norm(t))
            if norm <= 1e-9:
                continue
            # target: SQUEEZE_RAD_PER_M * d radians beyond the contact along tau; the object
            # blocks the finger, every joint saturates at its cap and the finger presses with tau
            dq = (d * SQUEEZE_RAD_PER_M) * t / norm
            for j, dqi, ti in zip(fj, dq, t):
                targets[j] = state.q[j] + float(dqi)
                caps[j] = max(HOLD_TORQUE_NM, abs(float(ti)))
        return targets, caps

    def _closest_point(self, finger: str, within_m: float):
        """pybullet's closest-point record between the finger's links and the object (the
        nearest over its links), or None when none is within ``within_m``."""
        best = None
        for link in self.finger_links.get(finger, ()):
            for cp in p.getClosestPoints(self.hand, self.obj, within_m, linkIndexA=link, physicsClientId=self.cid):
                if best is None or cp[8] < best[8]:
                    best = cp
        return best

    def _finger_distance(self, finger: str) -> float:
        """Smallest distance between the finger's links and the object, m (inf beyond 5 cm)."""
        cp = self._closest_point(finger, 0.05)
        return math.inf if cp is None else float(cp[8])

    def _point_jacobian(self, link: int, p_palm: np.ndarray, joints: list[str]) -> np.ndarray:
        """(3, len(joints)) linear Jacobian of a point fixed to ``link``, by central differences
        of pybullet's forward kinematics (the analytic call prints warnings for unit axes)."""
        ls = p.getLinkState(self.hand, link, computeForwardKinematics=True, physicsClientId=self.cid)
        R = np.array(p.getMatrixFromQuaternion(ls[5])).reshape(3, 3)
        p_link = R.T @ (p_palm - np.asarray(ls[4]))
        J = np.zeros((3, len(joints)))
        h = 1e-6
        for c, j in enumerate(joints):
            i = self.jidx[j]
            q0 = p.getJointState(self.hand, i, physicsClientId=self.cid)[0]
            pts = []
            for qv in (q0 + h, q0 - h):
                p.resetJointState(self.hand, i, qv, 0.0, physicsClientId=self.cid)
                s = p.getLinkState(self.hand, link, computeForwardKinematics=True, physicsClientId=self.cid)
                Rs = np.array(p.getMatrixFromQuaternion(s[5])).reshape(3, 3)
                pts.append(np.asarray(s[4]) + Rs @ p_link)
            p.resetJointState(self.hand, i, q0, 0.0, physicsClientId=self.cid)
            J[:, c] = (pts[0] - pts[1]) / (2 * h)
        return J

    def _grasp_forces(self, contacts, F: float) -> list[np.ndarray]:
        """Contact forces (palm frame) that hold the object still: grasp force optimization.

        Squeezing every finger along its normal leaves a net wrench whenever the normals do
        not meet (the thumb on the back of a box, the fingertips under its front), and the
        object turns as soon as it is released. Instead the forces solve

            min  sum_i |f_i - F n_i|_1
            s.t. sum_i [f_i; (p_i - c) x f_i + t_i n_i] = -[m g; 0]   (the object is in
                                                                          equilibrium)
                 |f_i - (f_i.n_i) n_i| <= s mu (f_i.n_i)       (inside the friction cone scaled
                                                                 by s, 8-sided pyramid)
                 |t_i| <= s_t gamma (f_i.n_i)                  (torsional friction about n_i)
                 f_i.n_i >= 0.1 F

        (a linear program, HiGHS), with the margins (s, s_t) of ``GFO_MARGINS`` in turn:
        (0.5, 0), (0.5, 0.5), (0.75, 0), (0.75, 0.75), (1, 0), (1, 1); a solution with a
        component above ``GFO_MAX_FORCE * F`` is skipped (internal forces the finger torques
        would not hold; seen at 50-200 N on near-singular point contacts). The torsion
        t_i is the soft-finger moment of the plan's closure model (thesis eq. 1), which the
        simulator provides as spinning friction; it is a reaction, not commanded: only f_i
        becomes joint torques. When no such forces exist (a grasp without force closure at
        its contacts) every finger keeps the plain normal squeeze ``F n_i``.
        """
        k = len(contacts)
        if k == 0:
            return []
        c = self.T_ref[:3, 3]
        P = np.array([pt for pt, _ in contacts])
        N = np.array([n / np.linalg.norm(n) for _, n in contacts])
        A = np.zeros((6, 3 * k))
        for i in range(k):
            A[:3, 3 * i:3 * i + 3] = np.eye(3)
            r = P[i] - c
            A[3:, 3 * i:3 * i + 3] = np.array([[0, -r[2], r[1]], [r[2], 0, -r[0]], [-r[1], r[0], 0]])
        b = np.zeros(6)
        b[:3] = -self.mass * np.asarray(self.params["gravity"], float)
        scale = np.array([1.0] * 3 + [1.0 / max(1e-3, float(np.max(np.linalg.norm(P - c, axis=1))))] * 3)
        A, b = A * scale[:, None], b * scale
        A_t = np.zeros((6, k))  # the torsional moments t_i n_i
        A_t[3:, :] = N.T * scale[3]
        f0 = (F * N).ravel()
        x = f0  # no balanced forces at these contacts: keep the normal squeeze
        for margin, torsion in GFO_MARGINS:
            x_m = self._gfo_lp(A, A_t, b, N, f0, margin * self.friction.mu, torsion * self.friction.gamma, 0.1 * F)
            if x_m is not None and float(np.abs(x_m).max()) <= GFO_MAX_FORCE * F:
                x = x_m
                break
        return [x[3 * i:3 * i + 3] for i in range(k)]

    @staticmethod
    def _gfo_lp(A, A_t, b, N, f0, mu, gamma, fn_min):
        """min |f - f0|_1 over forces f and torsions t s.t. A f + A_t t = b, f_i in the
        8-sided pyramid of friction ``mu`` about n_i (inscribed), |t_i| <= gamma f_i.n_i,
        f_i.n_i >= fn_min; the forces f (3k,), or None when infeasible."""
        from scipy.optimize import linprog

        k = len(N)
        m = 3 * k
        rows, h = [], []
        for i, n in enumerate(N):
            t1 = np.cross(n, [1.0, 0, 0] if abs(n[0]) < 0.9 else [0, 1.0, 0])
            t1 /= np.linalg.norm(t1)
            t2 = np.cross(n, t1)
            for a in np.linspace(0, 2 * np.pi, 8, endpoint=False):
                row = np.zeros(m)
                row[3 * i:3 * i + 3] = mu * math.cos(math.pi / 8) * n - (math.cos(a) * t1 + math.sin(a) * t2)
                rows.append(row)
                h.append(0.0)
            row = np.zeros(m)
            row[3 * i:3 * i + 3] = n
            rows.append(row)
            h.append(fn_min)
        G, h = np.array(rows), np.array(h)
        # torsion: t_i - gamma f_i.n_i <= 0 and -t_i - gamma f_i.n_i <= 0
        T = np.zeros((2 * k, m + k))
        for i, n in enumerate(N):
            for r, sign in ((2 * i, 1.0), (2 * i + 1, -1.0)):
                T[r, 3 * i:3 * i + 3] = -gamma * n
                T[r, m + i] = sign
        I, Z = np.eye(m), np.zeros
        # variables: f (m), t (k), slack (m) with |f - f0| <= slack
        res = linprog(np.r_[np.zeros(m + k), np.ones(m)],
                      A_ub=np.block([[-G, Z((len(G), k)), Z((len(G), m))],
                                     [T, Z((2 * k, m))],
                                     [I, Z((m, k)), -I], [-I, Z((m, k)), -I]]),
                      b_ub=np.r_[-h, np.zeros(2 * k), f0, -f0], A_eq=np.c_[A, A_t, Z((6, m))], b_eq=b,
                      bounds=[(None, None)] * (m + k) + [(0, None)] * m, method="highs")
        return res.x[:m] if res.status == 0 else None

    # -- simulation -----------------------------------------------------------------

    def _command(self, targets: Mapping[str, float], caps: Mapping[str, float]):
        idx = [self.jidx[j] for j in self.joints]
        p.setJointMotorControlArray(self.hand, idx, p.POSITION_CONTROL,
                                    targetPositions=[targets[j] for j in self.joints],
                                    forces=[caps[j] for j in self.joints], physicsClientId=self.cid)

    def _obj_pose(self) -> np.ndarray:
        pos, quat = p.getBasePositionAndOrientation(self.obj, physicsClientId=self.cid)
        return _T(pos, quat)

    def _tick(self):
        p.stepSimulation(physicsClientId=self.cid)
        self.steps_done += 1
        T = self._obj_pose()
        R_t = T[:3, :3].T
        sample = []
        for cp in p.getContactPoints(self.hand, self.obj, physicsClientId=self.cid):
            if cp[8] > TOUCH_TOL_M:
                continue
            p_obj = R_t @ (np.asarray(cp[6]) - T[:3, 3])  # point on the object (B)
            n_obj = R_t @ (-np.asarray(cp[7]))  # into the object
            sample.append((cp[3], p_obj[None, :], n_obj[None, :]))
        self.filter.update(sample)
        mm, deg = _drift(self.T_ref, T)
        if self.released:
            self.max_mm, self.max_deg = max(self.max_mm, mm), max(self.max_deg, deg)
        self.last = (mm, deg)
        if self.recorder is not None and self.steps_done % self.every == 0:
            self.recorder.grab()
        if self.realtime:
            time.sleep(self.dt)
        return mm

    def _run_for(self, seconds: float) -> bool:
        """Step for a duration; False when the object dropped."""
        for _ in range(max(1, int(round(seconds / self.dt)))):
            if self._tick() > self.params["drop_mm"]:
                return False
        return True

    def _measure(self, index: int, state) -> StateReport:
        patches = self.filter.patches(lambda link: self.link_finger.get(link, "palm"))
        n_pts = sum(len(v[0]) for v in patches.values())
        if patches:
            c = grasp_closure(apply_contact_model(patches, self.params["contact_model"]), self.friction)
            fc, metric = bool(c.is_force_closure), float(c.metric)
        else:
            fc, metric = False, float("nan")
        mm, deg = self.last
        return StateReport(index, True, self.steps_done * self.dt, tuple(state.fingers), tuple(sorted(patches)),
                           state.is_fc, state.metric, fc, metric, n_pts, mm, deg, patches)

    def run(self, states, steps, recorder=None, every=8, realtime=False):
        self.recorder, self.every, self.realtime = recorder, every, realtime
        self.released = False
        targets_of = [self._squeeze(s) for s in states]
        self._reset_q(states[0].q)
        pos, quat = self.T_ref[:3, 3].tolist(), Rotation.from_matrix(self.T_ref[:3, :3]).as_quat().tolist()
        p.resetBasePositionAndOrientation(self.obj, pos, quat, physicsClientId=self.cid)
        p.resetBaseVelocity(self.obj, [0, 0, 0], [0, 0, 0], physicsClientId=self.cid)
        # hold the object where the plan has it while the fingers squeeze
        hold = p.createConstraint(self.obj, -1, -1, -1, p.JOINT_FIXED, [0, 0, 0], [0, 0, 0], pos,
                                  childFrameOrientation=quat, physicsClientId=self.cid)
        p.changeConstraint(hold, maxForce=1000.0, physicsClientId=self.cid)
        p.setGravity(*self.params["gravity"], physicsClientId=self.cid)
        self._command(*targets_of[0])
        self._run_for(self.params["squeeze_s"])
        p.removeConstraint(hold, physicsClientId=self.cid)
        self.released = True
        reports: dict[int, StateReport] = {}
        ok = self._run_for(self.params["settle_s"])
        if ok:
            reports[0] = self._measure(0, states[0])
        current = dict(targets_of[0][0]), dict(targets_of[0][1])
        for st in steps if ok else ():
            to_targets, to_caps = targets_of[st.to_state]
            landing = st.action == "land"
            if landing:
                # until it touches down, the other fingers keep the forces that balance the
                # object without it (the from-state's); the to-state's count on its force
                targets, caps = dict(current[0]), dict(current[1])
            else:
                # unload before lifting: the other fingers take the forces that balance the
                # object without this finger while it still touches, holding its posture
                targets, caps = dict(to_targets), dict(to_caps)
                for j in st.joints:
                    targets[j], caps[j] = current[0][j], HOLD_TORQUE_NM
                self._command(targets, caps)
                if not self._run_for(UNLOAD_S):
                    ok = False
                    break
            # the moving finger tracks its path with the free-finger torque; a landing
            # finger switches to its squeeze caps once within LANDING_ZONE_M of the object
            start = np.array([current[0][j] for j in st.joints])
            path = np.vstack([start[None, :], st.path])
            for j in st.joints:
                caps[j] = FREE_TORQUE_NM
            for a, b in zip(path[:-1], path[1:]):
                if landing and self._finger_distance(st.finger) <= LANDING_ZONE_M:
                    caps.update({j: to_caps[j] for j in st.joints})
                    landing = False
                n = max(1, int(math.ceil(float(np.max(np.abs(b - a))) / (self.params["joint_speed_rad_s"] * self.dt))))
                for k in range(1, n + 1):
                    wp = a + (b - a) * k / n
                    full = dict(targets)
                    full.update({j: float(v) for j, v in zip(st.joints, wp)})
                    self._command(full, caps)
                    if self._tick() > self.params["drop_mm"]:
                        ok = False
                        break
                if not ok:
                    break
            if not ok:
                break
            # at the end of the path the finger takes its state target (squeezing if it landed)
            self._command(to_targets, to_caps)
            current = dict(to_targets), dict(to_caps)
            if not self._run_for(self.params["dwell_s"]):
                ok = False
                break
            reports[st.to_state] = self._measure(st.to_state, states[st.to_state])
        out = []
        for i, s in enumerate(states):
            if i in reports:
                out.append(reports[i])
            else:
                out.append(StateReport(i, False, self.steps_done * self.dt, tuple(s.fingers), (), s.is_fc, s.metric,
                                       None, None, 0, float("nan"), float("nan")))
        mm, deg = self.last
        return out, not ok, self.max_mm, self.max_deg, mm, deg, self.steps_done
