"""Films: a plan's pictures step by step, a replay's frames as it runs, GIF and MP4 files.

`plan_frames` draws a plan (``regrasp view --gif``); `ReplayRecorder` draws a running replay
(``regrasp replay --gif/--mp4``) in the same way, reading the simulation only; both use the
pictures of `planner.sim.render` (pybullet's TinyRenderer, CPU only). A replay in pybullet is
drawn from its own bodies; a replay in another engine (MuJoCo) from a mirror: the hand and the
object loaded once in a private pybullet client and put, at every frame, where the engine has
them (its joint positions and object pose), so both engines' films look alike and need no
OpenGL context. `write_gif` encodes frames with one palette for the whole
film (`gif_palette`), at a given clock (`gif_durations_ms`); `write_mp4` goes through ffmpeg.
"""

from __future__ import annotations

import os
import subprocess
import tempfile
import weakref
from pathlib import Path

import numpy as np
from PIL import Image

from planner.errors import SimulationError
from planner.fileio import write_atomic
from planner.frames import resample
from planner.gravity import gravity_directions
from planner.plan_data import Plan
from planner.sim.inputs import HandInfo
from planner.sim.render import (FINGER_RGB, HAND_RGBA, MOVING_RGBA, OBJECT_RGBA, HandScene, contact_camera,
                                hand_reach_m, patch_markers, rgb255, set_hand_configuration)
from planner.sim.render import _pose as _pose_of
from planner.sim.scene import p  # pybullet (render checked it is installed)


def plan_frames(plan, hand, obj, *, frames_per_step: int = 8, width: int = 640, height: int = 480,
                client: int | None = None) -> list[np.ndarray]:
    """Pictures of a plan (`planner.plan.read_plan` data), step by step along the finger paths,
    each with a caption (step, finger, action, the state's metric and removable fingers), the
    state's contacts drawn and the moving finger coloured; one fixed camera for the film."""
    index = {j: i for i, j in enumerate(hand.joint_names)}

    def q_of(st):
        q = np.array(hand.q_open, dtype=float)
        for j, v in st["q"].items():
            if j in index:
                q[index[j]] = float(v)
        return q

    def markers(i):
        pts = {f: (pa["points"], pa["normals"]) for f, pa in plan["states"][i]["patches"].items()}
        return patch_markers(hand, obj, pts, normal_len_m=0.2 * max(float(s) for s in obj.size))

    def caption(i, head):
        st = plan["states"][i]
        c = st["closure"]
        return (f"{head}\nstate {i}: {'force closure' if c['is_force_closure'] else 'NO closure'}, metric "
                f"{float(c['metric']):.4g}, removable: {', '.join(st.get('removable') or []) or '-'}")

    states, steps = plan["states"], plan["steps"]
    frames = []
    with HandScene(hand, q_of(states[0]), obj, client=client, width=width, height=height) as scene:
        all_pts = np.array([m[0] for i in range(len(states)) for m in markers(i)])
        camera = contact_camera(hand, scene.T_root_palm, all_pts if len(all_pts) else None,
                                np.asarray(obj.T_palm_obj)[:3, 3], scene.reach_m())
        frames.append(scene.image(q_of(states[0]), markers=markers(0), camera=camera,
                                  caption=caption(0, f"initial grasp, {len(steps)} steps"),
                                  touching=set(states[0]["patches"])))
        for k, sp in enumerate(steps):
            a, b = int(sp["from_state"]), int(sp["to_state"])
            q = q_of(states[a])
            cols = [index[j] for j in sp["joints"]]
            path = np.asarray(sp["path"], float).reshape(-1, len(cols)) if sp["path"] else q[cols][None]
            for j, qf in enumerate(resample(path, frames_per_step)):
                q[cols] = qf
                i = a if j < frames_per_step / 2 else b
                head = f"step {k + 1}/{len(steps)}: {sp['finger']} {sp['action']} (state {a} -> {b})"
                frames.append(scene.image(q, markers=markers(i), camera=camera, moving_finger=sp["finger"],
                                          caption=caption(i, head), touching=set(states[i]["patches"])))
    return frames


def gif_palette(frame: np.ndarray, colors: int = 128):
    """A palette for a whole film, from its first frame: the frame's own colours (median
    cut), every shade of the finger, moving-finger and object colours (they appear later),
    and the exact marker and text colours. One palette for every frame: no flicker between
    frames, and quantizing a frame to it costs ~1 ms instead of a median cut's ~30 ms."""
    exact = [*FINGER_RGB, rgb255(MOVING_RGBA), (90, 90, 90), (20, 24, 32), (0, 0, 0), (255, 255, 255)]
    bases = [np.array(c, float) for c in (*FINGER_RGB, rgb255(MOVING_RGBA), rgb255(OBJECT_RGBA),
                                          rgb255(HAND_RGBA))]
    shades = [b * k for b in bases for k in np.linspace(0.3, 1.0, 8)]
    shades += [b + (255 - b) * a for b in bases for a in (0.25, 0.5)]
    h, w = frame.shape[:2]
    block = max(1, (h * w) // (4 * len(shades)))  # the shades weigh a fifth of the sample
    swatch = np.repeat(np.clip(np.round(shades), 0, 255).astype(np.uint8), block, axis=0)
    sample = np.concatenate([frame.reshape(-1, 3), swatch])[None]
    cut = Image.fromarray(sample).quantize(colors=colors - len(exact), method=Image.Quantize.MEDIANCUT)
    rgb = list(cut.getpalette()[: 3 * (colors - len(exact))]) + [int(v) for c in exact for v in c]
    pal = Image.new("P", (1, 1))
    pal.putpalette(rgb)
    return pal


def gif_frame(frame: np.ndarray, palette=None):
    """An RGB frame as a GIF palette image (a third of the memory), quantized to `palette`
    (`gif_palette`; None: the frame's own)."""
    im = Image.fromarray(frame)
    return im.quantize(palette=palette if palette is not None else gif_palette(frame), dither=Image.Dither.NONE)


def gif_durations_ms(times_s, hold_ms: int = 1000) -> list[int]:
    """Display time of each frame shot at `times_s` (seconds, increasing) so the film runs
    at the clock's speed: GIF delays are whole centiseconds, so each frame ends at its
    successor's time rounded to 10 ms (no drift over the film); the last frame is held
    `hold_ms` (the pause before the loop restarts)."""
    t = np.asarray(times_s, float)
    ends = np.round((t - t[0]) * 100.0).astype(int) * 10
    return [int(v) for v in np.diff(ends)] + [int(hold_ms)]


def write_gif(frames: list, path, frame_ms: int = 120, hold_ms: int = 900, durations_ms=None) -> Path:
    """An animated GIF of RGB frames (arrays, or `gif_frame` images), written atomically.

    Without ``durations_ms`` every frame shows `frame_ms`, the first and last `hold_ms`;
    with it (one per frame, e.g. `gif_durations_ms`) those times."""
    if not frames:
        raise SimulationError("no frames to write")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    palette = None
    images = []
    for f in frames:
        if not isinstance(f, Image.Image):
            palette = gif_palette(f) if palette is None else palette
            f = gif_frame(f, palette)
        images.append(f)
    if durations_ms is None:
        durations = [frame_ms] * len(images)
        durations[0] = durations[-1] = hold_ms
    else:
        durations = [int(d) for d in durations_ms]
        if len(durations) != len(images):
            raise SimulationError(f"{len(durations)} frame durations for {len(images)} frames")
    write_atomic(path, write=lambda tmp: images[0].save(tmp, format="GIF", save_all=True, append_images=images[1:],
                                                      duration=durations, loop=0))
    return path


class ReplayRecorder:
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

    def __init__(self, sim, rd: Plan, info: HandInfo, width: int, height: int, keep_rgb: bool):
        self.sim, self.rd, self.keep_rgb = sim, rd, keep_rgb
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
        if hasattr(sim.engine, "render_bodies"):  # pybullet: its own bodies
            self.scene, self.mirror = HandScene.adopt(hand, *sim.engine.render_bodies(), width=width, height=height), None
        else:  # another engine: a mirror scene the engine's state is copied into at every frame
            self.scene = HandScene(hand, q0, sim.rd.object, width=width, height=height)
            self.mirror = self.scene.bodies[1]  # (HandScene's bodies: the hand, the object)
            weakref.finalize(self, self.scene.close)
        self.camera = contact_camera(hand, np.eye(4), pts if len(pts) else None, T[:3, 3],
                                     hand_reach_m(hand, q0, T[:3, 3], (extent,)))
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
        if st.action == "repose":  # every touching finger moves the object; none lifts
            palm = float(getattr(ctl, "palm_share", 1.0))
            if 0.0 < palm < 1.0:  # the palm's load handed to the fingers before the object moves, back after
                if self._moved:
                    return f"{head}: the palm takes its load back ({100 * palm:.0f}%)", st.to_state, None
                return (f"{head}: the fingers take the load off the palm ({100 * (1.0 - palm):.0f}%)", st.from_state,
                        None)
            if sim.reposing and getattr(sim, "palm_holds", False):  # still waypoints: the object rests on the palm
                return f"{head}: the fingers re-posture, the object on the palm", st.from_state, None
            if sim.reposing:
                self._moved = True
                return f"{head}: the fingers move the object", st.from_state, None
            return f"{head}: dwell at state {st.to_state}", st.to_state, None
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
                   f"t {t:.2f} s in {sim.engine.name}")
        T = sim.obj_pose()
        if self.mirror is not None:  # the engine's state into the mirror (hand joints in the hand's order)
            self.scene.q = np.asarray(sim.ctl.q(), float)
            set_hand_configuration(self.scene.body, self.scene.hand, self.scene.q, self.scene.client)
            pos, quat = _pose_of(self.scene.T_root_palm @ T)
            p.resetBasePositionAndOrientation(self.mirror, pos, quat, physicsClientId=self.scene.client)
        patches: dict[str, tuple[list, list]] = {}
        for link, pt, n in sim.contact_sample(T):
            P, N = patches.setdefault(sim.link_finger.get(link, "palm"), ([], []))
            P.append(pt[0])
            N.append(n[0])
        markers = patch_markers(self.scene.hand, None, patches, self.normal_len_m, T_palm_obj=T)
        img = self.scene.image(markers=markers, caption=caption, moving_finger=finger, camera=self.camera,
                               gravity=self.g, gravity_label=f"g {self.g_name}", touching=set(patches))
        if not self.keep_rgb:  # a GIF alone: palette frames, one palette for the film
            if self.palette is None:
                self.palette = gif_palette(img)
            img = gif_frame(img, self.palette)
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
        write_gif(frames, path, durations_ms=gif_durations_ms([self.times[k] for k in keep]))
        return len(frames)


def write_mp4(frames: list[np.ndarray], path: str, fps: float, ffmpeg: str) -> None:
    """An MP4 of RGB frames at ``fps`` through the ``ffmpeg`` executable (PNG frames in a
    temporary folder)."""
    with tempfile.TemporaryDirectory(prefix="regrasp-mp4-") as tmp:
        for i, f in enumerate(frames):
            Image.fromarray(f).save(os.path.join(tmp, f"{i:05d}.png"))
        def encode(target):
            cmd = [ffmpeg, "-y", "-loglevel", "error", "-framerate", f"{fps:.3f}", "-i", os.path.join(tmp, "%05d.png"),
                   "-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2", "-pix_fmt", "yuv420p", "-f", "mp4", str(target)]
            out = subprocess.run(cmd, capture_output=True, text=True)
            if out.returncode != 0:
                raise SimulationError(f"ffmpeg failed writing {path}: {out.stderr.strip().splitlines()[-1:]}")

        write_atomic(path, write=encode)
