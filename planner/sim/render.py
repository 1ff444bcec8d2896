"""Headless pictures of a hand holding an object (pybullet TinyRenderer, CPU only).

Every pybullet call names its client explicitly: nothing here relies on a global
connection, so a caller (e.g. the replay) can render from its own simulation.
"""

from __future__ import annotations

import contextlib
import os
import sys
from pathlib import Path

import numpy as np

from planner.errors import SimulationError


@contextlib.contextmanager
def quiet_native_output():
    """Silence what pybullet's C++ code prints on stdout/stderr (build banner, URDF
    warnings): a command's own stdout (e.g. ``--json``) must stay parseable."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        os.dup2(devnull, 2)
        yield
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in (*saved, devnull):
            os.close(fd)


with quiet_native_output():
    import pybullet as p

OBJECT_RGBA = (0.95, 0.55, 0.15, 1.0)
HAND_RGBA = (0.72, 0.74, 0.78, 1.0)


def _pose(T: np.ndarray) -> tuple[list[float], list[float]]:
    """(position, quat_xyzw) of a 4x4 pose."""
    from scipy.spatial.transform import Rotation

    return list(map(float, T[:3, 3])), list(map(float, Rotation.from_matrix(T[:3, :3]).as_quat()))


def load_hand(hand, q, client: int, color_rgba=HAND_RGBA) -> int:
    """Load `hand`'s URDF with its root link at the world origin and set configuration q.

    Args:
        hand: `planner.hand.Hand`.
        q: (nq,) joint values in `hand.joint_names` order.
        client: pybullet physics client id.
        color_rgba: colour given to every link; None keeps the URDF's colours.

    Returns:
        The pybullet body id.
    """
    for d in getattr(hand, "package_dirs", ()) or ():
        p.setAdditionalSearchPath(str(d), physicsClientId=client)
    try:
        with quiet_native_output():
            body = p.loadURDF(str(hand.urdf_path), useFixedBase=True, physicsClientId=client)
    except p.error as err:
        raise SimulationError(f"pybullet cannot load {hand.urdf_path}: {err}") from err
    set_hand_configuration(body, hand, q, client)
    if color_rgba is not None:
        for link in range(-1, p.getNumJoints(body, physicsClientId=client)):
            p.changeVisualShape(body, link, rgbaColor=list(color_rgba), physicsClientId=client)
    return body


def set_hand_configuration(body: int, hand, q, client: int) -> None:
    """resetJointState every joint of `body` named in `hand.joint_names` to its value in q."""
    index = {name: i for i, name in enumerate(hand.joint_names)}
    q = np.asarray(q, dtype=float)
    for j in range(p.getNumJoints(body, physicsClientId=client)):
        name = p.getJointInfo(body, j, physicsClientId=client)[1].decode()
        if name in index:
            p.resetJointState(body, j, float(q[index[name]]), physicsClientId=client)


def root_link_name(body: int, client: int) -> str:
    return p.getBodyInfo(body, physicsClientId=client)[0].decode()


def add_object(obj, T_world_obj: np.ndarray, client: int, mass_kg: float = 0.0, rgba=OBJECT_RGBA) -> int:
    """Create `obj` (a `planner.objects.GraspObject`) as a pybullet body at T_world_obj.

    Primitives keep their exact shape (cylinder axis = object z in both conventions).

    Returns:
        The pybullet body id.
    """
    size = tuple(float(s) for s in obj.size)
    if obj.shape == "box":
        half = [s / 2 for s in size]
        vis = p.createVisualShape(p.GEOM_BOX, halfExtents=half, rgbaColor=list(rgba), physicsClientId=client)
        col = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=client)
    elif obj.shape == "cylinder":
        radius, length = size
        vis = p.createVisualShape(
            p.GEOM_CYLINDER, radius=radius, length=length, rgbaColor=list(rgba), physicsClientId=client
        )
        col = p.createCollisionShape(p.GEOM_CYLINDER, radius=radius, height=length, physicsClientId=client)
    elif obj.shape == "sphere":
        vis = p.createVisualShape(p.GEOM_SPHERE, radius=size[0], rgbaColor=list(rgba), physicsClientId=client)
        col = p.createCollisionShape(p.GEOM_SPHERE, radius=size[0], physicsClientId=client)
    elif obj.shape == "mesh":
        scale = list(size) * 3 if len(size) == 1 else list(size)
        vis = p.createVisualShape(
            p.GEOM_MESH, fileName=str(obj.mesh_path), meshScale=scale, rgbaColor=list(rgba), physicsClientId=client
        )
        col = p.createCollisionShape(p.GEOM_MESH, fileName=str(obj.mesh_path), meshScale=scale, physicsClientId=client)
    else:
        raise SimulationError(f"cannot build a pybullet shape for object shape {obj.shape!r}")
    if vis < 0 or col < 0:
        raise SimulationError(f"pybullet could not create the {obj.shape} object")
    pos, quat = _pose(T_world_obj)
    return p.createMultiBody(
        baseMass=float(mass_kg),
        baseCollisionShapeIndex=col,
        baseVisualShapeIndex=vis,
        basePosition=pos,
        baseOrientation=quat,
        physicsClientId=client,
    )


def render_rgb(
    client: int,
    target_world,
    *,
    width: int = 640,
    height: int = 480,
    distance_m: float = 0.28,
    yaw_deg: float = 40.0,
    pitch_deg: float = -35.0,
    up_axis: int = 2,
    fov_deg: float = 40.0,
) -> np.ndarray:
    """Render the client's scene with the CPU TinyRenderer.

    Args:
        client: pybullet physics client id.
        target_world: (3,) point the camera looks at, world frame, metres.
        width, height: image size in pixels.
        distance_m, yaw_deg, pitch_deg: camera orbit around the target.
        up_axis: 1 (y) or 2 (z) is the image's up direction.
        fov_deg: vertical field of view.

    Returns:
        (height, width, 3) uint8 RGB image.
    """
    view = p.computeViewMatrixFromYawPitchRoll(
        cameraTargetPosition=[float(v) for v in target_world],
        distance=float(distance_m),
        yaw=float(yaw_deg),
        pitch=float(pitch_deg),
        roll=0.0,
        upAxisIndex=int(up_axis),
        physicsClientId=client,
    )
    proj = p.computeProjectionMatrixFOV(
        fov=float(fov_deg), aspect=width / height, nearVal=0.01, farVal=2.0, physicsClientId=client
    )
    _, _, rgba, _, _ = p.getCameraImage(
        int(width),
        int(height),
        viewMatrix=view,
        projectionMatrix=proj,
        renderer=p.ER_TINY_RENDERER,
        lightDirection=[0.4, -0.6, 1.0],
        shadow=0,
        physicsClientId=client,
    )
    img = np.asarray(rgba, dtype=np.uint8).reshape(int(height), int(width), 4)
    return img[:, :, :3].copy()


def _add_markers(markers, T_root_palm: np.ndarray, client: int) -> list[int]:
    """Visual-only dots and rods (no collision, no mass) for `render_png`'s ``markers``."""
    out = []
    for a, b, rgba in markers:
        a = T_root_palm[:3, :3] @ np.asarray(a, dtype=float) + T_root_palm[:3, 3]
        b = T_root_palm[:3, :3] @ np.asarray(b, dtype=float) + T_root_palm[:3, 3]
        dot = p.createVisualShape(p.GEOM_SPHERE, radius=0.0025, rgbaColor=list(rgba), physicsClientId=client)
        out.append(p.createMultiBody(0, -1, dot, basePosition=a.tolist(), physicsClientId=client))
        d = b - a
        length = float(np.linalg.norm(d))
        if length > 1e-6:
            z = d / length
            axis = np.cross([0.0, 0.0, 1.0], z)
            s_ = float(np.linalg.norm(axis))
            ang = float(np.arctan2(s_, z[2]))
            axis = axis / s_ if s_ > 1e-9 else np.array([1.0, 0.0, 0.0])
            quat = list(axis * np.sin(ang / 2)) + [float(np.cos(ang / 2))]
            rod = p.createVisualShape(p.GEOM_CYLINDER, radius=0.0006, length=length, rgbaColor=list(rgba),
                                      physicsClientId=client)
            out.append(p.createMultiBody(0, -1, rod, basePosition=(0.5 * (a + b)).tolist(), baseOrientation=quat,
                                         physicsClientId=client))
    return out


def render_png(
    hand,
    q,
    obj,
    path,
    width: int = 640,
    height: int = 480,
    client: int | None = None,
    *,
    distance_m: float | None = None,
    yaw_deg: float = 200.0,
    pitch_deg: float = -30.0,
    markers=None,
) -> Path:
    """Save a picture of `hand` at configuration q holding `obj` (palm frame poses).

    The hand's URDF root is put at the world origin; the object at
    ``T_root_obj = inv(T_palm_root) @ obj.T_palm_obj``. The camera looks at the
    object centre with the palm's +z (grasping face) up.

    Args:
        hand: `planner.hand.Hand`.
        q: (nq,) joint values in `hand.joint_names` order.
        obj: `planner.objects.GraspObject`.
        path: PNG file to write.
        width, height: image size in pixels.
        client: pybullet client to draw into (bodies are added to it and removed
            afterwards); None opens a private DIRECT client and closes it.
        distance_m: camera distance; None picks one from the object size.
        yaw_deg, pitch_deg: camera orbit angles.
        markers: optional [(a_palm (3,), b_palm (3,), rgba)]: a dot at ``a`` and a thin rod
            from ``a`` to ``b`` (e.g. contact points and normals, `planner.grasp.contact_markers`).

    Returns:
        The written path.
    """
    from PIL import Image

    own = client is None
    if own:
        client = p.connect(p.DIRECT)
        if client < 0:
            raise SimulationError("cannot start a pybullet DIRECT client")
    bodies = []
    try:
        hand_body = load_hand(hand, q, client)
        bodies.append(hand_body)
        T_palm_root = np.asarray(hand.link_pose(np.asarray(q, dtype=float), root_link_name(hand_body, client)))
        T_root_obj = np.linalg.solve(T_palm_root, np.asarray(obj.T_palm_obj))
        bodies.append(add_object(obj, T_root_obj, client))
        bodies.extend(_add_markers(markers or (), np.linalg.inv(T_palm_root), client))
        # look between the palm centre and the object so both are in the picture
        T_root_palm = np.linalg.inv(T_palm_root)
        target = 0.5 * (T_root_obj[:3, 3] + T_root_palm[:3, 3])
        if distance_m is None:
            reach = np.linalg.norm(T_root_obj[:3, 3] - T_root_palm[:3, 3])
            distance_m = max(0.16, 1.5 * reach + 2.0 * float(max(obj.size)))
        img = render_rgb(
            client, target, width=width, height=height, distance_m=distance_m, yaw_deg=yaw_deg, pitch_deg=pitch_deg
        )
    finally:
        if own:
            p.disconnect(physicsClientId=client)
        else:
            for b in bodies:
                p.removeBody(b, physicsClientId=client)
    path = Path(path)
    if path.parent and not path.parent.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(img).save(path)
    return path
