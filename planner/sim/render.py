"""Headless pictures of a hand holding an object (pybullet TinyRenderer, CPU only).

Every pybullet call names its client explicitly: nothing here relies on a global
connection, so a caller (e.g. the replay) can render from its own simulation.
"""

from __future__ import annotations

import contextlib
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont
from scipy.spatial.transform import Rotation

from planner.errors import SimulationError
from planner.fileio import write_atomic
from planner.sim.engine import engine_installed

if not engine_installed("pybullet"):  # every picture goes through this module: one line, no traceback
    raise SimulationError("pictures (check --png, view --gif, replay --gif/--mp4) are drawn by pybullet, which is not "
                          "installed (it has wheels up to Python 3.11): pip install pybullet, or use Python <= 3.11")

from planner.sim.scene import hand_body, object_body, p  # noqa: E402 (after the check above)

OBJECT_RGBA = (0.95, 0.55, 0.15, 1.0)
HAND_RGBA = (0.72, 0.74, 0.78, 1.0)


def _pose(T: np.ndarray) -> tuple[list[float], list[float]]:
    """(position, quat_xyzw) of a 4x4 pose."""
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
    body = hand_body(client, hand.urdf_path, package_dirs=getattr(hand, "package_dirs", ()) or ())
    set_hand_configuration(body, hand, q, client)
    if color_rgba is not None:
        paint(body, color_rgba, client)
    return body


def paint(body: int, rgba, client: int) -> None:
    """Give every link of `body` the colour `rgba` (visual only: no physics changes)."""
    for link in range(-1, p.getNumJoints(body, physicsClientId=client)):
        p.changeVisualShape(body, link, rgbaColor=list(rgba), physicsClientId=client)


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
    pos, quat = _pose(T_world_obj)
    return object_body(client, obj.shape, obj.size, obj.mesh_path, pos, quat, mass_kg, rgba)


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


MOVING_RGBA = (0.90, 0.0, 0.49, 1.0)
CONTACT_RGBA = (0.10, 0.75, 0.20, 1.0)
#: finger colours (RGB), in hand.yaml finger order: the palette of `regrasp view` too
FINGER_RGB = ((31, 119, 180), (44, 160, 44), (148, 103, 189), (140, 86, 75), (23, 190, 207), (188, 189, 34))


def finger_links(body: int, hand, finger: str, client: int) -> list[int]:
    """pybullet link indices of `finger`: the children of its joints and everything below them."""
    joints = set(hand.finger(finger).joints)
    info = [p.getJointInfo(body, j, physicsClientId=client) for j in range(p.getNumJoints(body, physicsClientId=client))]
    links = {j for j, ji in enumerate(info) if ji[1].decode() in joints}
    grew = True
    while grew:
        extra = {j for j, ji in enumerate(info) if ji[16] in links and j not in links}
        links |= extra
        grew = bool(extra)
    return sorted(links)


def contact_camera(hand, T_root_palm: np.ndarray, points_palm=None, target_palm=None, reach_m: float = 0.1):
    """Camera that sees the contacts, not through the palm: it looks at the contact centroid
    (or `target_palm`) from the grasping side, along the hand's ``palm_normal`` tilted
    towards the thumb side (-y) and the fingertips (+x), with the palm normal up.

    Returns:
        (eye, target, up) in the frame of `T_root_palm` (the pybullet world).
    """
    n = np.asarray(getattr(hand, "palm_normal", (0.0, 0.0, 1.0)), float)
    pts = None if points_palm is None else np.asarray(points_palm, float).reshape(-1, 3)
    c = pts.mean(axis=0) if pts is not None and len(pts) else np.asarray(target_palm, float)
    side = np.array([0.35, -0.55, 0.0])
    side -= n * (side @ n)
    d = (n + side) / np.linalg.norm(n + side)
    eye = c + max(0.12, 3.2 * reach_m) * d
    R, t = T_root_palm[:3, :3], T_root_palm[:3, 3]
    return R @ eye + t, R @ c + t, R @ n


def _project(points_world, view, proj, width: int, height: int) -> np.ndarray:
    """Pixel coordinates (k, 2) of world points through pybullet's (column-major) matrices."""
    V = np.asarray(view, float).reshape(4, 4).T
    P = np.asarray(proj, float).reshape(4, 4).T
    X = np.c_[np.asarray(points_world, float).reshape(-1, 3), np.ones(len(points_world))]
    clip = (P @ V @ X.T).T
    ndc = clip[:, :2] / clip[:, 3:4]
    return np.c_[(ndc[:, 0] + 1) * 0.5 * width, (1 - ndc[:, 1]) * 0.5 * height]


def _font(size: int):
    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1: fixed bitmap font
        return ImageFont.load_default()


def annotate(img: np.ndarray, caption: str | None = None, markers_px=(), arrow=None, legend=()) -> np.ndarray:
    """Draw contact markers, a caption banner and a direction arrow on an RGB image.

    Args:
        img: (h, w, 3) uint8.
        caption: text of the banner at the top (lines split on newlines); None: no banner.
        markers_px: [(point_px (2,), tip_px (2,) or None, rgb)]: a dot at the point and a line
            from the tip to it (e.g. the inward contact normal).
        arrow: (dx, dy, label): an arrow along the image direction (dx, dy) (pixels, y down;
            length 1 = in the image plane, shorter = partly along the view), drawn with its
            label in the bottom-right corner (e.g. gravity); None: no arrow.
        legend: [(label, rgb, filled)]: a row of dots (filled, or rings) and labels along the
            bottom-left (e.g. each finger's colour, filled when it touches).
    """
    im = Image.fromarray(img)
    draw = ImageDraw.Draw(im)
    r = max(3, img.shape[1] // 160)
    for pt, tip, rgb in markers_px:
        rgb = tuple(int(v) for v in rgb[:3])
        if tip is not None:
            draw.line([tuple(tip), tuple(pt)], fill=rgb, width=max(2, r // 2))
        draw.ellipse([pt[0] - r, pt[1] - r, pt[0] + r, pt[1] + r], fill=rgb, outline=(0, 0, 0))
    if caption:
        size = max(12, img.shape[0] // 30)
        font = _font(size)
        lines = caption.split("\n")
        h = (size + 6) * len(lines) + 6
        banner = Image.new("RGBA", (im.width, h), (255, 255, 255, 215))
        im.paste(banner, (0, 0), banner)
        for i, line in enumerate(lines):
            draw.text((8, 4 + i * (size + 6)), line, fill=(20, 24, 32), font=font)
    if arrow is not None:
        _draw_arrow(draw, im.width, im.height, *arrow)
    if legend:
        size = max(12, img.shape[0] // 30)
        font, x, y = _font(size), 8, im.height - size - 10
        for label, rgb, filled in legend:
            rgb = tuple(int(v) for v in rgb[:3])
            box = [x, y + size // 2 - r - 1, x + 2 * r + 2, y + size // 2 + r + 1]
            draw.ellipse(box, fill=rgb if filled else (255, 255, 255), outline=rgb, width=max(2, r // 2))
            draw.text((x + 2 * r + 6, y), label, fill=(20, 24, 32), font=font)
            x += 2 * r + 16 + int(draw.textlength(label, font=font))
    return np.asarray(im)


def _draw_arrow(draw, width: int, height: int, dx: float, dy: float, label: str) -> None:
    """A dark arrow in a white disc in the bottom-right corner, labelled below it."""
    size = max(12, height // 30)
    r = max(18, height // 14)
    cx, cy = width - r - 10, height - r - size - 14
    draw.ellipse([cx - r, cy - r, cx + r, cy + r], fill=(255, 255, 255), outline=(20, 24, 32), width=2)
    ink = (20, 24, 32)
    d = np.array([dx, dy], float)
    if np.linalg.norm(d) < 0.2:  # along the view: a dot (the label says which way)
        draw.ellipse([cx - 4, cy - 4, cx + 4, cy + 4], fill=ink)
    else:
        tip = np.array([cx, cy]) + 0.8 * r * d
        tail = np.array([cx, cy]) - 0.8 * r * d
        draw.line([tuple(tail), tuple(tip)], fill=ink, width=3)
        u = d / np.linalg.norm(d)
        side = np.array([-u[1], u[0]])
        head = [tuple(tip), tuple(tip - 9 * u + 6 * side), tuple(tip - 9 * u - 6 * side)]
        draw.polygon(head, fill=ink)
    font = _font(size)
    w = draw.textlength(label, font=font)
    draw.text((max(2, min(cx - w / 2, width - w - 4)), cy + r + 3), label, fill=ink, font=font)


def rgb255(rgba) -> tuple[int, int, int]:
    return tuple(int(round(255 * float(v))) if float(v) <= 1.0 else int(v) for v in rgba[:3])


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
    yaw_deg: float | None = None,
    pitch_deg: float | None = None,
    markers=None,
    caption: str | None = None,
    moving_finger: str | None = None,
) -> Path:
    """Save a picture of `hand` at configuration q holding `obj` (palm frame poses).

    The hand's URDF root is put at the world origin; the object at
    ``T_root_obj = inv(T_palm_root) @ obj.T_palm_obj``. Without ``yaw_deg``/``pitch_deg`` the
    camera sees the contacts from the grasping side of the palm (`contact_camera`: along
    the hand's ``palm_normal``, aimed at the markers' centroid or the object), with the
    palm normal up; with them it orbits the point between palm and object as before.

    Args:
        hand: `planner.hand.Hand`.
        q: (nq,) joint values in `hand.joint_names` order.
        obj: `planner.objects.GraspObject`.
        path: PNG file to write.
        width, height: image size in pixels.
        client: pybullet client to draw into (bodies are added to it and removed
            afterwards); None opens a private DIRECT client and closes it.
        distance_m: camera distance; None picks one from the hand and object size.
        yaw_deg, pitch_deg: camera orbit angles (both or neither).
        markers: contacts to draw, [(point_palm (3,), tip_palm (3,) or None, rgba)]: a dot at
            the point and a line from the tip (e.g. the normal's tail) to it.
        caption: text drawn in a banner at the top of the picture.
        moving_finger: a finger drawn in `MOVING_RGBA`.

    Returns:
        The written path.
    """
    img = render_image(hand, q, obj, width=width, height=height, client=client, distance_m=distance_m,
                       yaw_deg=yaw_deg, pitch_deg=pitch_deg, markers=markers, caption=caption,
                       moving_finger=moving_finger)
    path = Path(path)
    # the one atomic writer (an interrupted or failed save leaves the old file or none);
    # the format from the name, as Image.save(path) chose it
    fmt = Image.registered_extensions().get(path.suffix.lower(), "PNG")
    return write_atomic(path, write=lambda tmp: Image.fromarray(img).save(tmp, format=fmt))


class HandScene:
    """A hand and an object in a pybullet client, drawn from a contact-seeing camera.

    Use as a context manager; `image(q, ...)` renders one annotated frame. The bodies are
    removed (or the private client closed) on exit.

    `HandScene.adopt` draws bodies that already exist (e.g. the replay's simulation): it
    only reads their state and changes colours, and leaves the bodies in place on exit.
    """

    def __init__(self, hand, q, obj, client: int | None = None, width: int = 640, height: int = 480):
        self.hand, self.obj, self.width, self.height = hand, obj, int(width), int(height)
        self.own = client is None
        if self.own:
            client = p.connect(p.DIRECT)
            if client < 0:
                raise SimulationError("cannot start a pybullet DIRECT client")
        self.client, self.bodies = client, []
        try:
            self.body = load_hand(hand, q, client)
            self.bodies.append(self.body)
            T_palm_root = np.asarray(hand.state(np.asarray(q, float)).link_pose(root_link_name(self.body, client)))
            self.T_root_palm = np.linalg.inv(T_palm_root)
            T_root_obj = np.linalg.solve(T_palm_root, np.asarray(obj.T_palm_obj))
            self.bodies.append(add_object(obj, T_root_obj, client))
        except BaseException:
            self.close()
            raise
        self.q = np.asarray(q, float)
        self.colored: list[int] = []

    @classmethod
    def adopt(cls, hand, hand_body: int, object_body: int, client: int, T_root_palm=None, width: int = 640,
              height: int = 480) -> "HandScene":
        """A scene of existing bodies: the hand and the object are painted in the colours of
        every other picture (visual shapes only) and never moved; pass ``camera=`` to
        `image`. ``T_root_palm``: pose of the palm frame in the client's world (identity when
        the world is the palm frame, as in the replay)."""
        self = cls.__new__(cls)
        self.hand, self.obj, self.width, self.height = hand, None, int(width), int(height)
        self.own, self.client, self.bodies, self.body = False, int(client), [], int(hand_body)
        self.T_root_palm = np.eye(4) if T_root_palm is None else np.asarray(T_root_palm, float)
        self.q, self.colored = None, []
        paint(self.body, HAND_RGBA, self.client)
        p.changeVisualShape(int(object_body), -1, rgbaColor=list(OBJECT_RGBA), physicsClientId=self.client)
        return self

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self):
        if self.own:
            with contextlib.suppress(Exception):
                p.disconnect(physicsClientId=self.client)
        else:
            for b in self.bodies:
                with contextlib.suppress(Exception):
                    p.removeBody(b, physicsClientId=self.client)
        self.bodies = []

    def reach_m(self) -> float:
        """Radius around the object centre that holds the hand's links (camera distance)."""
        return hand_reach_m(self.hand, self.q, np.asarray(self.obj.T_palm_obj)[:3, 3], self.obj.size)

    def image(self, q=None, *, markers=None, caption=None, moving_finger=None, distance_m=None,
              yaw_deg=None, pitch_deg=None, camera=None, gravity=None, gravity_label="g",
              touching=None) -> np.ndarray:
        """(h, w, 3) uint8 picture at q (default: the configuration given at construction;
        an adopted scene is drawn as it is). ``gravity``: (3,) palm-frame vector drawn as an
        arrow in the bottom-right corner with ``gravity_label``; None or zero: no arrow.
        ``touching``: fingers (or other links, e.g. "palm") in contact: a legend of every
        finger's colour, filled when it touches; None: no legend."""
        if self.obj is None and camera is None:
            raise ValueError("a scene of existing bodies is drawn with camera=")
        if q is not None:
            self.q = np.asarray(q, float)
            set_hand_configuration(self.body, self.hand, self.q, self.client)
        for link in self.colored:
            p.changeVisualShape(self.body, link, rgbaColor=list(HAND_RGBA), physicsClientId=self.client)
        self.colored = finger_links(self.body, self.hand, moving_finger, self.client) if moving_finger else []
        for link in self.colored:
            p.changeVisualShape(self.body, link, rgbaColor=list(MOVING_RGBA), physicsClientId=self.client)
        markers = list(markers or [])
        R, t = self.T_root_palm[:3, :3], self.T_root_palm[:3, 3]
        if yaw_deg is not None or pitch_deg is not None:
            T_root_obj = self.T_root_palm @ np.asarray(self.obj.T_palm_obj)
            target = 0.5 * (T_root_obj[:3, 3] + t)
            if distance_m is None:
                reach = np.linalg.norm(T_root_obj[:3, 3] - t)
                distance_m = max(0.16, 1.5 * reach + 2.0 * float(max(self.obj.size)))
            view = p.computeViewMatrixFromYawPitchRoll(
                cameraTargetPosition=[float(v) for v in target], distance=float(distance_m),
                yaw=float(yaw_deg if yaw_deg is not None else 200.0),
                pitch=float(pitch_deg if pitch_deg is not None else -30.0), roll=0.0, upAxisIndex=2,
                physicsClientId=self.client)
        else:
            if camera is None:
                pts = np.array([m[0] for m in markers]) if markers else None
                camera = contact_camera(self.hand, self.T_root_palm, pts, np.asarray(self.obj.T_palm_obj)[:3, 3],
                                        self.reach_m())
            eye, target, up = camera
            if distance_m is not None:
                eye = target + distance_m * (eye - target) / np.linalg.norm(eye - target)
            view = p.computeViewMatrix([float(v) for v in eye], [float(v) for v in target], [float(v) for v in up],
                                       physicsClientId=self.client)
        proj = p.computeProjectionMatrixFOV(fov=40.0, aspect=self.width / self.height, nearVal=0.01, farVal=2.0,
                                            physicsClientId=self.client)
        _, _, rgba, _, _ = p.getCameraImage(self.width, self.height, viewMatrix=view, projectionMatrix=proj,
                                            renderer=p.ER_TINY_RENDERER, lightDirection=[0.4, -0.6, 1.0], shadow=0,
                                            physicsClientId=self.client)
        img = np.asarray(rgba, dtype=np.uint8).reshape(self.height, self.width, 4)[:, :, :3].copy()
        px = []
        if markers:
            P = np.array([R @ np.asarray(m[0], float) + t for m in markers])
            uv = _project(P, view, proj, self.width, self.height)
            tips = [m[1] for m in markers]
            tip_uv = [None if tp is None else _project([R @ np.asarray(tp, float) + t], view, proj, self.width,
                                                       self.height)[0] for tp in tips]
            px = [(uv[i], tip_uv[i], rgb255(m[2])) for i, m in enumerate(markers)]
        arrow = None
        if gravity is not None and np.linalg.norm(gravity) > 0:
            # camera coordinates (x right, y up, looking along -z) of the gravity direction
            d = np.asarray(view, float).reshape(4, 4).T[:3, :3] @ (R @ np.asarray(gravity, float))
            d /= np.linalg.norm(d)
            if np.hypot(d[0], d[1]) < 0.2:
                gravity_label += " (into view)" if d[2] < 0 else " (out of view)"
            elif abs(d[2]) >= 0.5:  # more than 30 deg out of the picture: the arrow is its shadow
                gravity_label += " (mostly away from you)" if d[2] < 0 else " (mostly toward you)"
            arrow = (float(d[0]), float(-d[1]), gravity_label)
        legend = () if touching is None else [
            (f + (" (moving)" if f == moving_finger else ""), finger_rgb(self.hand, f), f in touching)
            for f in [*self.hand.fingers, *sorted(set(touching) - set(self.hand.fingers))]]
        return annotate(img, caption, px, arrow, legend)


def hand_reach_m(hand, q, centre, size) -> float:
    """Radius around `centre` (palm frame) that holds the hand's links at q and an object
    of `size` (the distance `contact_camera` keeps)."""
    c = np.asarray(centre, float)
    state = hand.state(np.asarray(q, float))
    pts = [np.asarray(state.link_pose(link))[:3, 3] for link in hand.links]
    return float(max([np.linalg.norm(x - c) for x in pts] + [0.5 * max(float(v) for v in size)]))


def render_image(hand, q, obj, *, width=640, height=480, client=None, **kwargs) -> np.ndarray:
    """One annotated picture (see `render_png` for the arguments) as an (h, w, 3) uint8 array."""
    with HandScene(hand, q, obj, client=client, width=width, height=height) as scene:
        return scene.image(**kwargs)


def finger_rgb(hand, finger: str) -> tuple[int, int, int]:
    """The colour a finger's contacts are drawn in (the same palette as `regrasp view`)."""
    names = list(hand.fingers)
    return FINGER_RGB[names.index(finger) % len(FINGER_RGB)] if finger in names else (90, 90, 90)


def patch_markers(hand, obj, patches, normal_len_m: float = 0.015, T_palm_obj=None) -> list:
    """Markers of contact patches (finger -> (p_obj (n,3), n_in_obj (n,3))): one per point,
    with its inward normal ending at the point, in the finger's colour (grey for a link that
    is no finger, e.g. "palm"). ``T_palm_obj``: the object's pose (default ``obj.T_palm_obj``;
    the replay passes where the object is now)."""
    T = np.asarray(obj.T_palm_obj if T_palm_obj is None else T_palm_obj, float)
    R, t = T[:3, :3], T[:3, 3]
    out = []
    for f, (P, N) in patches.items():
        rgb = finger_rgb(hand, f)
        for pt, n in zip(np.asarray(P, float).reshape(-1, 3), np.asarray(N, float).reshape(-1, 3)):
            pp = R @ pt + t
            out.append((pp, pp - normal_len_m * (R @ n) / np.linalg.norm(n), rgb))
    return out
