"""See a plan or a grasp: one self-contained interactive HTML page (``regrasp view``).

The 3D scene is built with pinocchio's ``MeshcatVisualizer`` (the hand's URDF visual
geometry) and meshcat's geometry and command objects; the page is meshcat's own static
viewer (three.js, inlined) with the recorded scene commands, plus a small panel of our
own: a timeline of the plan's states and steps (play, pause, step, scrub), a caption,
per state the closure metric, the removable fingers and grip force, and, with a replay
report, the simulator's contacts, closure and drift. Nothing is fetched when the page
is opened: it works offline from a file.

No meshcat server is started: the scene commands meshcat would send to its server are
recorded in-process (`_CommandRecorder`) and packed into the page, which is what
meshcat's ``Visualizer.static_html()`` does through its server.

Frames: the scene root is the palm frame rotated so that the hand's ``palm_normal`` is
the page's up (+z); the object, its contacts and the friction cones are in the object
frame below it, exactly as in the plan file (normals INTO the object; cones drawn
opening out of the object, half-angle ``atan(mu)``).
"""

from __future__ import annotations

import base64
import html
import json
import math
import warnings
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import pinocchio as pin
from scipy.spatial.transform import Rotation

from planner.audit import require_sound
from planner.errors import InputError, SpecError
from planner.fileio import (MAX_PLAN_BYTES, as_path, check_format, check_outputs, load_json, load_yaml, read_limited,
                            write_atomic)
from planner.frames import hand_of_plan, object_of_plan, plain_plan, pose_matrix, resample
from planner.grasp import grasp_files, load_grasp
from planner.objects import load_mesh
from planner.plan import plan_files, read_plan
from planner.plan_data import PLAN_KIND, pose_between, pose_matrix as plan_pose_matrix
from planner.realization import realize
from planner.urdf_check import library_message
from planner.view_page import PAGE

#: frames drawn per plan step (finger paths are resampled by joint-space arc length)
FRAMES_PER_STEP = 12
#: at most this many friction cones per finger patch (evenly chosen points; all points are drawn)
MAX_CONES_PER_PATCH = 8
#: finger colours (hex, RGB), in hand.yaml finger order; the moving finger is drawn in MOVING_COLOR
FINGER_COLORS = (0x1F77B4, 0x2CA02C, 0x9467BD, 0x8C564B, 0x17BECF, 0xBCBD22)
MOVING_COLOR = 0xE6007E
HAND_COLOR = 0x9AA1AD
BACKGROUND = 0xEEF1F5
OBJECT_COLOR = 0xF28C28
SIM_COLOR = 0x00C8FF
_DIGITS = 5


def _hex(c: int) -> str:
    return f"#{c:06x}"


class _CommandRecorder:
    """A meshcat "window" that records the scene commands instead of sending them to a
    server (``meshcat.Visualizer(window=...)``): the same commands the static page replays."""

    def __init__(self):
        self.commands: list[dict] = []

    def send(self, command) -> None:
        self.commands.append(command.lower())

    def packed(self) -> list[str]:
        """Every command msgpack-encoded (meshcat's wire format) as base64 text."""
        import umsgpack  # meshcat's wire format: loaded only when a page is written

        return [base64.b64encode(umsgpack.packb(c)).decode("ascii") for c in self.commands]


def _meshcat():
    try:
        with warnings.catch_warnings():  # meshcat's server module imports a deprecated pyzmq name
            warnings.simplefilter("ignore", DeprecationWarning)
            import meshcat  # meshcat (and pyzmq): loaded only when a page is drawn
            import meshcat.geometry as mg
    except ImportError as err:  # pragma: no cover - a dependency of the package
        raise InputError(f"regrasp view needs the meshcat package (pip install meshcat): {err}") from err
    return meshcat, mg


def _rot_to_z(n) -> np.ndarray:
    """A rotation taking the unit vector n onto +z (the page's up)."""
    n = np.asarray(n, float) / np.linalg.norm(n)
    z = np.array([0.0, 0.0, 1.0])
    c = float(n @ z)
    if c > 1 - 1e-12:
        return np.eye(3)
    if c < -1 + 1e-12:
        return np.diag([1.0, -1.0, -1.0])
    v = np.cross(n, z)
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1 + c)


def cone_mesh(points, normals, mu: float, height_m: float, sides: int = 12):
    """One triangle mesh of friction cones, one per contact: apex at the point, axis along
    minus the (inward) normal, half-angle atan(mu), open base.

    Returns:
        (V (k*(sides+1), 3), F (k*sides, 3) int) in the points' frame.
    """
    P = np.asarray(points, float).reshape(-1, 3)
    N = np.asarray(normals, float).reshape(-1, 3)
    r = float(mu) * height_m
    ang = 2 * np.pi * np.arange(sides) / sides
    V, F = [], []
    for p, n in zip(P, N):
        n = n / np.linalg.norm(n)
        a = np.cross(n, [1.0, 0, 0] if abs(n[0]) < 0.9 else [0, 1.0, 0])
        a /= np.linalg.norm(a)
        b = np.cross(n, a)
        base = p - height_m * n
        rim = base + r * (np.cos(ang)[:, None] * a + np.sin(ang)[:, None] * b)
        k = len(V) * (sides + 1)
        V.append(np.vstack([p, rim]))
        F.append(np.array([[k, k + 1 + i, k + 1 + (i + 1) % sides] for i in range(sides)]))
    if not V:
        return np.zeros((0, 3)), np.zeros((0, 3), int)
    return np.vstack(V), np.vstack(F)


def _subsample(n: int, k: int) -> np.ndarray:
    return np.arange(n) if n <= k else np.unique(np.round(np.linspace(0, n - 1, k)).astype(int))


class _Scene:
    """Builds the meshcat scene and the page's data for one hand, object and list of states."""

    def __init__(self, hand, obj, mu: float):
        meshcat, self.mg = _meshcat()
        from pinocchio.visualize import MeshcatVisualizer  # imports meshcat: only when a page is drawn

        self.hand, self.obj, self.mu = hand, obj, float(mu)
        self.rec = _CommandRecorder()
        self.vis = meshcat.Visualizer(window=self.rec)
        try:
            from planner.urdf_check import given_package_dirs_only

            with given_package_dirs_only():  # the URDF's folder first
                vmodel = pin.buildGeomFromUrdf(hand.model, str(hand.urdf_path), pin.GeometryType.VISUAL,
                                               package_dirs=list(getattr(hand, "mesh_dirs", hand.package_dirs)))
        except (RuntimeError, ValueError) as err:
            raise SpecError(str(hand.urdf_path), "visual",
                            f"cannot load the visual geometry: {library_message(err)}") from None
        self.vmodel, self.vdata = vmodel, vmodel.createData()
        self.pv = MeshcatVisualizer(hand.model, None, vmodel)
        self.pv.initViewer(viewer=self.vis)
        self.pv.loadViewerModel(rootNodeName="regrasp/hand", visual_color=_rgba(HAND_COLOR))
        # which finger each visual geometry belongs to (None: palm)
        joint_finger = {hand.model.getJointId(j): f for f, fg in hand.fingers.items() for j in fg.joints}
        self.geom_names, self.geom_finger = [], []
        for g in vmodel.geometryObjects:
            jid, finger = g.parentJoint, None
            while jid != 0 and finger is None:
                finger, jid = joint_finger.get(jid), hand.model.parents[jid]
            self.geom_names.append(self.pv.getViewerNodeName(g, pin.GeometryType.VISUAL))
            self.geom_finger.append(finger)
        self.fingers = list(hand.fingers)
        self.finger_color = {f: FINGER_COLORS[i % len(FINGER_COLORS)] for i, f in enumerate(self.fingers)}
        # palm frame -> page: palm normal up; hand geometry is placed in the model's world frame
        # the model's world is its root link: T_palm_world = pose of the root link in the palm frame
        T_palm_world = np.asarray(hand.state(hand.q_open).link_pose(hand.model.frames[1].name), dtype=float)
        self.T_palm_world = T_palm_world
        self.R_page = _rot_to_z(hand.palm_normal)
        self.vis["regrasp"].set_transform(pose_matrix(self.R_page))
        self.vis["regrasp/hand"].set_transform(T_palm_world)
        self.T_palm_obj = np.asarray(obj.T_palm_obj, float)
        self.vis["regrasp/object"].set_transform(self.T_palm_obj)
        self._add_object()
        for path in ("/Grid", "/Axes"):
            self.vis[path].set_property("visible", False)
        self.scale = float(max(_object_extent(obj), 0.02))
        self.contact_sets: dict[str, str] = {}   # key -> node name
        self.n_sets = 0

    # ------------------------------------------------------------------ geometry
    def _add_object(self):
        mg, obj = self.mg, self.obj
        size = [float(s) for s in obj.size]
        mat = mg.MeshPhongMaterial(color=OBJECT_COLOR, opacity=0.55, transparent=True)
        node = self.vis["regrasp/object/body"]
        if obj.shape == "box":
            node.set_object(mg.Box(size), mat)
        elif obj.shape == "sphere":
            node.set_object(mg.Sphere(size[0]), mat)
        elif obj.shape == "cylinder":
            node.set_object(mg.Cylinder(size[1], size[0]), mat)
            node.set_transform(pose_matrix(np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])))  # three.js y axis -> object z
        elif obj.shape == "mesh":
            scale = size * 3 if len(size) == 1 else size
            V, F = load_mesh(obj.mesh_path, scale)
            node.set_object(mg.TriangularMeshGeometry(np.asarray(V, float), np.asarray(F, int)), mat)
        else:
            raise InputError(f"cannot draw object shape {obj.shape!r}; shapes: box, cylinder, sphere, mesh")

    def contact_set(self, points, normals, color: int, *, cones: bool, kind: str = "plan") -> str:
        """Add (once) a set of contacts in the object frame; returns its node name."""
        P = np.round(np.asarray(points, float).reshape(-1, 3), 6)
        N = np.asarray(normals, float).reshape(-1, 3)
        key = f"{kind}:{color}:{P.tobytes().hex()}"
        if key in self.contact_sets:
            return self.contact_sets[key]
        name = f"{kind}{self.n_sets}"
        self.n_sets += 1
        mg = self.mg
        node = self.vis[f"regrasp/object/contacts/{name}"]
        r = 0.0018 * self.scale / 0.05 if kind == "plan" else 0.0013 * self.scale / 0.05
        r = float(np.clip(r, 0.0009, 0.003))
        for i, p in enumerate(P):
            node[f"p{i}"].set_object(mg.Sphere(r), mg.MeshLambertMaterial(color=color))
            node[f"p{i}"].set_transform(pose_matrix(t=p))
        if cones and len(P):
            pick = _subsample(len(P), MAX_CONES_PER_PATCH)
            V, F = cone_mesh(P[pick], N[pick], self.mu, height_m=0.15 * self.scale)
            node["cones"].set_object(mg.TriangularMeshGeometry(V, F),
                                     mg.MeshLambertMaterial(color=color, opacity=0.35, transparent=True, side=2))
        if kind != "plan" and len(P):  # simulator normals as short segments
            seg = np.empty((2 * len(P), 3))
            seg[0::2], seg[1::2] = P, P - 0.2 * self.scale * N / np.linalg.norm(N, axis=1, keepdims=True)
            node["normals"].set_object(mg.LineSegments(mg.PointsGeometry(seg.T), mg.LineBasicMaterial(color=color)))
        node.set_property("visible", False)
        self.contact_sets[key] = name
        return name

    def transforms(self, q) -> list[np.ndarray]:
        """World (model root) pose of every visual geometry at q, as meshcat draws it."""
        from pinocchio.visualize.meshcat_visualizer import applyScalingOnHomegeneousTransform  # imports meshcat

        self.hand.kinematics(np.asarray(q, float)).place_geometries(self.vmodel, self.vdata)
        out = []
        for i, g in enumerate(self.vmodel.geometryObjects):
            out.append(applyScalingOnHomegeneousTransform(self.vdata.oMg[i].homogeneous, g.meshScale))
        return out

    def camera(self, points_palm: np.ndarray) -> dict:
        """Eye and target (page frame) that see the contacts from the grasping side of the palm:
        the target is the contact centroid (object centre without contacts), the eye is along the
        palm normal, tilted towards the thumb side (-y) and the fingertips (+x)."""
        n = np.asarray(self.hand.palm_normal, float)
        c = points_palm.mean(axis=0) if len(points_palm) else self.T_palm_obj[:3, 3]
        side = np.array([0.35, -0.55, 0.0])
        side -= n * (side @ n)
        d = n + side
        # far enough to see every geometry origin and the object around the target (fov 40 deg)
        origins = [(self.T_palm_world @ T)[:3, 3] for T in self.transforms(self.hand.q_open)]
        reach = max([np.linalg.norm(o - c) for o in origins] + [0.5 * self.scale + np.linalg.norm(self.T_palm_obj[:3, 3] - c)])
        dist = max(0.12, 3.2 * reach)
        eye = c + dist * d / np.linalg.norm(d)
        to_page = lambda v: (self.R_page @ v).round(_DIGITS).tolist()  # noqa: E731
        return {"eye": to_page(eye), "target": to_page(c)}

    def html(self, data: Mapping[str, Any], title: str) -> str:
        """The page: meshcat's viewer script, the recorded commands and our panel."""
        import meshcat  # meshcat: loaded only when a page is drawn

        viewer_js = (Path(meshcat.__file__).parent / "viewer" / "dist" / "main.min.js").read_text()
        commands = json.dumps(self.rec.packed())
        return (PAGE.replace("/*TITLE*/", html.escape(title))
                .replace("/*MESHCAT_JS*/", viewer_js.replace("</script", "<\\/script"))
                .replace("/*COMMANDS*/", commands)
                .replace("/*DATA*/", json.dumps(data, separators=(",", ":"), allow_nan=False).replace("</", "<\\/")))


def _rgba(c: int) -> list[float]:
    return [((c >> 16) & 255) / 255, ((c >> 8) & 255) / 255, (c & 255) / 255, 1.0]


def _object_extent(obj) -> float:
    s = [float(v) for v in obj.size]
    if obj.shape == "cylinder":
        return max(2 * s[0], s[1])
    if obj.shape == "sphere":
        return 2 * s[0]
    if obj.shape == "mesh":  # the mesh was read when the grasp or plan was: a failure here is a bug
        V, _ = load_mesh(obj.mesh_path, s * 3 if len(s) == 1 else s)
        return float(np.ptp(np.asarray(V), axis=0).max())
    return max(s)


def _m4(T) -> list[float]:
    """A 4x4 pose as meshcat's column-major 16 numbers, rounded."""
    return np.round(np.asarray(T, float).T.reshape(-1), _DIGITS).tolist()


def _num(x) -> float | None:
    return None if x is None or not math.isfinite(float(x)) else round(float(x), 6)


# ---------------------------------------------------------------------- inputs


def _load_report(path, n_states: int) -> list[dict]:
    """Replay report(s) of ``regrasp replay --report``: [{name, passed, verdict, states}]."""
    path = as_path(path, "--report", "a replay report (regrasp replay --report)")  # ('' read the current folder)
    # a FIFO, a device, a huge or deeply nested file: one line
    data = load_json(read_limited(path, MAX_PLAN_BYTES, "replay report"), path)
    if not isinstance(data, dict):
        raise SpecError(str(path), "", "expected a replay report (regrasp replay --report)")
    if data.get("kind") == PLAN_KIND:  # a plan's states pass for a report's below: say what it is
        raise SpecError(str(path), "kind", "is a plan file, not a replay report (regrasp replay PLAN --report FILE "
                                           "writes one)")
    if isinstance(data.get("engines"), list):  # replay --engine both: each engine's run(s), named by engine
        runs = []
        for e in data["engines"]:
            e = e if isinstance(e, dict) else {}
            rep, engine = e.get("report"), str(e.get("engine", "engine"))
            if isinstance(rep, dict) and isinstance(rep.get("directions"), list):
                runs += [(f"{engine} {d.get('name', i)}", d.get("report")) for i, d in enumerate(rep["directions"])]
            else:
                runs.append((engine, rep))
    elif "directions" in data:
        runs = [(d.get("name", f"direction {i}"), d.get("report")) for i, d in enumerate(data["directions"])]
    elif "states" in data:
        runs = [("replay", data)]
    else:
        raise SpecError(str(path), "states", "missing key: expected a replay report (regrasp replay --report)")
    out = []
    for name, rep in runs:
        if not isinstance(rep, dict) or not isinstance(rep.get("states"), list):
            raise SpecError(str(path), f"{name}.states", "missing key")
        if not all(isinstance(st, dict) and "reached" in st for st in rep["states"]):
            raise SpecError(str(path), f"{name}.states", "expected the simulator's states (index, reached, "
                                                         "sim_fingers, ...): not a replay report (regrasp replay "
                                                         "--report)")
        if len(rep["states"]) != n_states:
            raise SpecError(str(path), "states", f"the report has {len(rep['states'])} states, the plan {n_states}: "
                                                 "not a replay of this plan")
        out.append({"name": str(name), "passed": bool(rep.get("passed")), "verdict": str(rep.get("verdict", "")),
                    "states": rep["states"], "trajectory": rep.get("trajectory")})
    return out


#: Most simulator frames a page plays per replay (a longer trajectory is resampled evenly).
MAX_SIM_FRAMES = 400


def _sim_frames(scene, hand, traj, report_path) -> dict | None:
    """What the simulator did, as the page draws it: per sampled frame the hand's geometry
    poses that changed since the previous frame, the object's pose (palm frame) and the time."""
    if not isinstance(traj, dict) or not traj.get("t"):
        return None
    try:
        joints = [str(j) for j in traj["joints"]]
        t = np.asarray(traj["t"], float).reshape(-1)
        Q = np.asarray(traj["q"], float).reshape(len(t), len(joints))
        P = np.asarray(traj["object_position"], float).reshape(len(t), 3)
        Qo = np.asarray(traj["object_quat_xyzw"], float).reshape(len(t), 4)
    except (KeyError, TypeError, ValueError) as err:
        raise SpecError(str(report_path), "trajectory", f"expected joints, t, q, object_position, object_quat_xyzw "
                                                        f"of equal lengths ({err})") from None
    if not (np.all(np.isfinite(Q)) and np.all(np.isfinite(P)) and np.all(np.isfinite(Qo))):
        raise SpecError(str(report_path), "trajectory", "expected finite numbers")
    cols = [(i, hand.joint_names.index(j)) for i, j in enumerate(joints) if j in hand.joint_names]
    keep = np.unique(np.linspace(0, len(t) - 1, min(len(t), MAX_SIM_FRAMES)).round().astype(int))
    frames, prev = [], None
    for k in keep:
        q = np.array(hand.q_open, dtype=float)
        for i, c in cols:
            q[c] = Q[k, i]
        Ts = [_m4(T) for T in scene.transforms(q)]
        T_obj = pose_matrix(Rotation.from_quat(Qo[k] / np.linalg.norm(Qo[k])).as_matrix(), P[k])
        frames.append({"t": round(float(t[k]), 4), "obj": _m4(T_obj),
                       "hand": {str(g): T for g, T in enumerate(Ts) if prev is None or T != prev[g]}})
        prev = Ts
    return {"frames": frames, "object_plan": _m4(scene.T_palm_obj)}


# ---------------------------------------------------------------------- page data


def _pose7_matrix(pose) -> np.ndarray:
    """(x, y, z, qx, qy, qz, qw), or a file's {position, quat_xyzw}, as a pose (4, 4)."""
    if isinstance(pose, Mapping):
        pose = [*pose["position"], *pose["quat_xyzw"]]
    return plan_pose_matrix(np.asarray(pose, float).reshape(7))


def _object_frames(object_path, path: np.ndarray, k: int) -> tuple[np.ndarray, list[np.ndarray]]:
    """A reposing step's ``k`` frames: joints and object poses evenly spaced along its waypoints
    (the object path's waypoints are evenly spaced; joints linear and the object's pose
    `planner.plan_data.pose_between` two waypoints)."""
    seven = [np.asarray([*p["position"], *p["quat_xyzw"]] if isinstance(p, Mapping) else p, float).reshape(7)
             for p in object_path]
    m = len(seven)
    qs, poses = [], []
    for u in np.linspace(0.0, m - 1, k):
        a = min(int(math.floor(u)), m - 2) if m > 1 else 0
        t = u - a if m > 1 else 0.0
        b = min(a + 1, m - 1)
        qs.append((1 - t) * path[a] + t * path[b])
        poses.append(plan_pose_matrix(pose_between(seven[a], seven[b], t)))
    return np.array(qs), poses


def _state_entry(scene: _Scene, i: int, q, fingers: Mapping, patches: Mapping, closure: Mapping,
                 removable, grip, T_obj=None) -> tuple[dict, np.ndarray]:
    sets, pts = [], []
    for f, patch in patches.items():
        P = np.asarray(patch["points"], float).reshape(-1, 3)
        N = np.asarray(patch["normals"], float).reshape(-1, 3)
        sets.append(scene.contact_set(P, N, scene.finger_color.get(f, 0x555555), cones=True))
        pts.append(P)
    P_obj = np.vstack(pts) if pts else np.zeros((0, 3))
    T_obj = scene.T_palm_obj if T_obj is None else np.asarray(T_obj, float)  # the state's object pose
    P_palm = P_obj @ T_obj[:3, :3].T + T_obj[:3, 3]
    entry = {
        "index": i,
        "fingers": {str(f): str(v) for f, v in fingers.items()},
        "contacts": sorted(patches),
        "points": {f: len(p["points"]) for f, p in patches.items()},
        "force_closure": bool(closure.get("is_force_closure")),
        "metric": _num(closure.get("metric")),
        "removable": sorted(removable),
        "grip_force_n": _num(grip),
        "sets": sets,
        "T": [_m4(T) for T in scene.transforms(q)],
        "obj": _m4(T_obj),  # the object's pose (palm frame): a reposing step moves it (schema 4)
    }
    return entry, P_palm


def plan_page_data(plan: Mapping, plan_path, hand=None, report_path=None) -> tuple[_Scene, dict]:
    """Scene and page data of a plan (`planner.plan.read_plan`'s result, or its plain data)."""
    plan = plain_plan(plan)
    plan_path = Path(plan_path)
    hand = hand if hand is not None else hand_of_plan(plan, plan_path)
    obj = object_of_plan(plan, plan_path)
    scene = _Scene(hand, obj, float(plan["friction"]["mu"]))
    joints = list(plan["joints"])
    index = {j: i for i, j in enumerate(hand.joint_names)}
    missing = [j for j in joints if j not in index]
    if missing:
        raise SpecError(str(plan_path), "joints", f"joints {missing} are not joints of hand {hand.name!r}")

    def q_of(state_q: Mapping) -> np.ndarray:
        q = np.array(hand.q_open, dtype=float)
        for j, v in state_q.items():
            if j in index:
                q[index[j]] = float(v)
        return q

    states, all_pts = [], []
    for i, st in enumerate(plan["states"]):
        pose = st.get("object_pose")
        entry, P = _state_entry(scene, i, q_of(st["q"]), st.get("fingers", {}), st["patches"], st["closure"],
                                st.get("removable", []), st.get("grip_force_n"),
                                None if pose is None else _pose7_matrix(pose))
        states.append(entry)
        all_pts.append(P)
    steps = []
    for k, sp in enumerate(plan["steps"]):
        a, b = int(sp["from_state"]), int(sp["to_state"])
        q = q_of(plan["states"][a]["q"])
        cols = [index[j] for j in sp["joints"]]
        base = states[a]["T"]
        frames = []
        path = np.asarray(sp["path"], float).reshape(len(sp["path"]), len(cols)) if sp["path"] else \
            np.array([[q[c] for c in cols]])
        obj_frames = None
        if sp.get("object_path"):  # a reposing step: the object moves with the holding fingers
            qs, poses = _object_frames(sp["object_path"], path, FRAMES_PER_STEP)
            obj_frames = [_m4(T) for T in poses]
        else:
            qs = resample(path, FRAMES_PER_STEP)
        for qf in qs:
            q[cols] = qf
            Ts = [_m4(T) for T in scene.transforms(q)]
            frames.append({str(g): T for g, T in enumerate(Ts) if T != base[g]})
        steps.append({"index": k, "finger": sp["finger"], "action": sp["action"], "from": a, "to": b,
                      "frames": frames, **({} if obj_frames is None else {"obj": obj_frames})})
    runs = []
    if report_path is not None:
        for run in _load_report(report_path, len(states)):
            per_state = []
            for st in run["states"]:
                sets = []
                for f, patch in (st.get("sim_patches") or {}).items():
                    P = np.asarray(patch.get("points", []), float).reshape(-1, 3)
                    if len(P):
                        sets.append(scene.contact_set(P, patch["normals"], SIM_COLOR, cones=False, kind="sim"))
                per_state.append({"reached": bool(st.get("reached")), "fingers": list(st.get("sim_fingers") or []),
                                  "force_closure": st.get("sim_force_closure"), "metric": _num(st.get("sim_metric")),
                                  "drift_mm": _num(st.get("drift_mm")), "drift_deg": _num(st.get("drift_deg")),
                                  "points": st.get("sim_points"), "sets": sets})
            runs.append({"name": run["name"], "passed": run["passed"], "verdict": run["verdict"], "states": per_state,
                         "traj": _sim_frames(scene, hand, run.get("trajectory"), report_path)})
    summary = plan.get("summary") or {}
    data = {
        "kind": "plan",
        "title": plan_path.name,
        "hand": hand.name,
        "object": f"{obj.shape} {[round(float(s), 4) for s in obj.size]} m",
        "mu": scene.mu,
        "summary": {k: summary.get(k) for k in ("gait_steps", "bottleneck_metric", "mean_metric",
                                                 "bottleneck_grip_force_n", "rank") if k in summary},
        "contact_model": (plan.get("parameters") or {}).get("contact_model"),
        "fingers": scene.fingers,
        "colors": {f: _hex(c) for f, c in scene.finger_color.items()},
        "moving_color": _hex(MOVING_COLOR), "hand_color": _hex(HAND_COLOR), "sim_color": _hex(SIM_COLOR),
        "background": _hex(BACKGROUND),
        "geoms": scene.geom_names, "geom_finger": scene.geom_finger,
        "states": states, "steps": steps, "runs": runs,
        "camera": scene.camera(np.vstack(all_pts) if all_pts else np.zeros((0, 3))),
        "frames_per_step": FRAMES_PER_STEP,
    }
    return scene, data


def grasp_page_data(grasp, grasp_path) -> tuple[_Scene, dict]:
    """Scene and page data of one realized grasp (`planner.realization.realize`): what `check` finds."""
    scene = _Scene(grasp.hand, grasp.obj, grasp.friction.mu)
    patches = {f: {"points": p, "normals": n} for f, (p, n) in grasp.patches.items()}
    fingers = {f.name: f.kind for f in grasp.spec.fingers}
    entry, P = _state_entry(scene, 0, grasp.q, fingers, patches,
                            {"is_force_closure": grasp.is_force_closure, "metric": grasp.metric},
                            grasp.removable, None)
    mean = grasp.mean_contact_closure()
    entry["mean_contact"] = {"force_closure": bool(mean["force_closure"]), "metric": _num(mean["metric"])}
    entry["missing"] = list(grasp.missing)
    entry["problems"] = list(grasp.problems)  # every reason check fails it (joint limits too)
    entry["collisions"] = [f"{a} - {b} {d * 1000:.2f} mm" for a, b, d in grasp.collisions]
    data = {
        "kind": "grasp", "title": Path(grasp_path).name, "hand": grasp.hand.name,
        "object": f"{grasp.obj.shape} {[round(float(s), 4) for s in grasp.obj.size]} m", "mu": scene.mu,
        "summary": {}, "contact_model": "patch", "fingers": scene.fingers,
        "colors": {f: _hex(c) for f, c in scene.finger_color.items()},
        "moving_color": _hex(MOVING_COLOR), "hand_color": _hex(HAND_COLOR), "sim_color": _hex(SIM_COLOR),
        "background": _hex(BACKGROUND),
        "geoms": scene.geom_names, "geom_finger": scene.geom_finger,
        "states": [entry], "steps": [], "runs": [], "camera": scene.camera(P), "frames_per_step": FRAMES_PER_STEP,
    }
    return scene, data


def _is_plan_file(path: Path) -> bool:
    if path.suffix.lower() not in (".yaml", ".yml", ".json"):
        raise SpecError(str(path), "", f"unknown file suffix {path.suffix!r}; view takes a plan or grasp "
                                       "file (.yaml, .yml, .json)")
    # the bounded readers: a FIFO, a device, a huge or deeply nested file is refused in one line
    text = read_limited(path, MAX_PLAN_BYTES, "plan or grasp file")
    data = load_json(text, path) if path.suffix.lower() == ".json" else load_yaml(text, path, "plan or grasp file")
    return isinstance(data, dict) and (data.get("kind") == "regrasp-plan" or "states" in data)


def _check_suffix(path, suffixes: tuple[str, ...], what: str) -> None:
    if Path(path).suffix.lower() not in suffixes:
        raise SpecError(str(path), "", f"unknown {what} suffix {Path(path).suffix!r}; use {suffixes[0]}")


def load_source(source) -> tuple[str, Any]:
    """("plan", plain plan data) for a plan file, ("grasp", `RealizedGrasp`) for a grasp file."""
    return read_source(source)[0]


def read_source(source) -> tuple[tuple[str, Any], list[str]]:
    """`load_source` and every file it read (no output may be one): a plan's
    (`planner.plan.plan_files`) or the grasp file, its hand's files and the object's mesh."""
    source = Path(source)
    if _is_plan_file(source):
        plan = read_plan(source)
        hand = hand_of_plan({"hand": plan.hand}, source)
        require_sound(plan, hand)  # a resealed, physically wrong plan is refused before any drawing
        return ("plan", plain_plan(plan)), plan_files(plan, hand)
    g = realize(load_grasp(source))
    return ("grasp", g), grasp_files(g.spec, g.hand, source)


def write_view(source, output, report=None, loaded=None) -> dict:
    """Write the page of a plan or grasp file; atomic (never half a file), never over the input.
    ``loaded``: `load_source(source)` when the caller has it already.

    Returns:
        {"path", "bytes", "states", "steps", "kind"}.
    """
    source, output = Path(source), Path(output)
    _check_suffix(output, (".html", ".htm"), "page")
    if output.exists() and output.resolve() == source.resolve():
        raise InputError(f"{output}: refusing to overwrite the input file")
    kind, value = loaded or load_source(source)
    if kind == "plan":
        scene, data = plan_page_data(value, source, report_path=report)
    else:
        if report is not None:
            raise InputError(f"{report}: --report goes with a plan file, and {source} is a grasp")
        scene, data = grasp_page_data(value, source)
    page = scene.html(data, f"regrasp view: {data['title']}")
    write_atomic(output, page)
    return {"path": str(output), "bytes": len(page.encode()), "states": len(data["states"]),
            "steps": len(data["steps"]), "kind": data["kind"]}


def write_film(source, gif, frames_per_step: int = 8, width: int = 640, height: int = 480, loaded=None) -> int:
    """A GIF of a plan file (`planner.sim.film.plan_frames`: captions, contacts, the moving
    finger coloured) or the picture of a grasp file as one frame; returns the frame count."""
    # pybullet: loaded only when a film is asked for
    from planner.sim.film import plan_frames, write_gif
    from planner.sim.render import patch_markers, render_image

    source = Path(source)
    check_format(gif, "--gif")
    kind, value = loaded or load_source(source)
    if kind == "plan":
        plan = value
        frames = plan_frames(plan, hand_of_plan(plan, source), object_of_plan(plan, source),
                             frames_per_step=frames_per_step, width=width, height=height)
    else:
        g = value
        frames = [render_image(g.hand, g.q, g.obj, width=width, height=height,
                               markers=patch_markers(g.hand, g.obj, g.patches),
                               caption=f"{source.name}: {'force closure' if g.is_force_closure else 'NO closure'}, "
                                       f"metric {g.metric:.4g}\nremovable: {', '.join(sorted(g.removable)) or '-'}")]
    write_gif(frames, gif)
    return len(frames)


def view_command(source, output, report=None, gif=None) -> int:
    """``regrasp view``: write the page (and the GIF) and say what they hold; exit 0."""
    _check_suffix(output, (".html", ".htm"), "page")  # before any work
    if gif is not None:
        check_format(gif, "--gif")
    loaded, files = read_source(source)
    check_outputs([(output, "-o"), (gif, "--gif")], [*files, report])
    out = write_view(source, output, report=report, loaded=loaded)
    what = (f"{out['states']} states, {out['steps']} steps" if out["kind"] == "plan" else "one grasp")
    print(f"wrote {out['path']} ({out['bytes'] / 1e6:.2f} MB, {what}"
          + (f", replay report {report}" if report else "") + "): open it in a browser, no server needed")
    if gif is not None:
        n = write_film(source, gif, loaded=loaded)
        print(f"wrote {gif} ({n} frames, 640x480)")
    return 0
