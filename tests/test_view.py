"""`regrasp view`: the interactive 3D page of a plan or a grasp, checked as a person would
(opened in headless Chromium: the scene renders, the timeline has every state) and by its
data (frames move only the stepping finger, cones have the friction half-angle)."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from planner.cli import main
from planner.errors import InputError, SpecError
from planner.view import FRAMES_PER_STEP, _rot_to_z, cone_mesh, write_view

REPO = Path(__file__).resolve().parents[1]
INITIAL = REPO / "grasps/icub/cylinder_parallel_extension.yaml"
FINAL = REPO / "grasps/icub/cylinder_ir2m.yaml"
CHROMIUM = next((c for c in ("/usr/bin/chromium", shutil.which("chromium") or "", shutil.which("chromium-browser") or "")
                 if c and Path(c).exists()), None)
needs_chromium = pytest.mark.skipif(
    CHROMIUM is None, reason="chromium is not installed (apt-get install chromium; .ci/run installs it): "
                             "the page is not opened in a browser")
BACKGROUND = np.array([0xEE, 0xF1, 0xF5])
MOVING = np.array([0xE6, 0x00, 0x7E])
PANEL_PX = 410  # the page's left panel; the 3D view is right of it


@pytest.fixture(scope="module")
def plan_path(tmp_path_factory):
    """The demo's cylinder pair planned for execution (as `make demo`)."""
    path = tmp_path_factory.mktemp("view") / "plan.yaml"
    assert main(["plan", str(INITIAL), str(FINAL), "-o", str(path), "--execution"]) == 0
    return path


@pytest.fixture(scope="module")
def page(plan_path):
    out = plan_path.with_name("plan.html")
    info = write_view(plan_path, out)
    return out, info


def _counts(plan_path) -> tuple[int, int]:
    """(states, steps) of the plan file."""
    from planner.plan import read_plan

    plan = read_plan(plan_path)
    return len(plan.states), len(plan.steps)


def _data(html: str) -> dict:
    m = re.search(r"const DATA = (\{.*?\});\nconst CMDS", html, re.S)
    assert m, "the page holds its data"
    return json.loads(m.group(1))


def test_plan_page_is_one_offline_file_under_5_mb(page, plan_path):
    out, info = page
    html = out.read_text()
    assert (info["states"], info["steps"]) == _counts(plan_path) and info["kind"] == "plan"
    assert out.stat().st_size < 5_000_000
    # nothing to fetch at view time: no external script, stylesheet, image or request
    assert not re.search(r"<(script|link|img|iframe)[^>]+(src|href)=", html)
    assert not re.search(r"fetch\(\s*['\"]https?:", html)
    assert "MeshCat.Viewer" in html


def test_frames_move_only_the_stepping_finger_and_end_at_the_next_state(page, plan_path):
    data = _data(page[0].read_text())
    assert (len(data["states"]), len(data["steps"])) == _counts(plan_path)
    for step in data["steps"]:
        frames = step["frames"]
        assert len(frames) == FRAMES_PER_STEP
        moved = {int(g) for f in frames for g in f}
        assert moved, f"step {step['index']} moves nothing"
        assert {data["geom_finger"][g] for g in moved} == {step["finger"]}
        # the last frame is the next state: every geometry where that state has it
        last, to = frames[-1], data["states"][step["to"]]["T"]
        base = data["states"][step["from"]]["T"]
        for g in range(len(base)):
            np.testing.assert_allclose(last.get(str(g), base[g]), to[g], atol=2e-5)
    # per state: closure, metric, removable fingers and contact sets for every touching finger
    for st in data["states"]:
        assert st["force_closure"] is True and st["metric"] > 0
        assert len(st["sets"]) == len(st["contacts"]) >= 3


def test_cones_have_the_friction_half_angle():
    rng = np.random.default_rng(0)
    P = rng.normal(size=(3, 3))
    N = rng.normal(size=(3, 3))
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    mu, h, sides = 0.6, 0.01, 12
    V, F = cone_mesh(P, N, mu, h, sides)
    assert V.shape == (3 * (sides + 1), 3) and F.shape == (3 * sides, 3) and F.max() == len(V) - 1
    for i, (p, n) in enumerate(zip(P, N)):
        apex, rim = V[i * (sides + 1)], V[i * (sides + 1) + 1:(i + 1) * (sides + 1)]
        np.testing.assert_allclose(apex, p)
        d = rim - p
        cos = (d @ -n) / np.linalg.norm(d, axis=1)   # opens out of the object: against the inward normal
        np.testing.assert_allclose(np.arccos(cos), np.arctan(mu), atol=1e-9)


@pytest.mark.parametrize("n", [(0, 0, 1), (1, 0, 0), (0, 0, -1), (0.6, -0.8, 0)])
def test_palm_normal_is_page_up(n):
    R = _rot_to_z(n)
    np.testing.assert_allclose(R @ np.asarray(n, float), [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)


def test_report_of_another_plan_and_bad_outputs_are_clear_errors(plan_path, tmp_path, capsys):
    report = tmp_path / "r.json"
    report.write_text(json.dumps({"passed": True, "verdict": "PASS", "states": [{"reached": True}] * 3}))
    with pytest.raises(SpecError, match=f"3 states, the plan {_counts(plan_path)[0]}"):
        write_view(plan_path, tmp_path / "p.html", report=report)
    assert not (tmp_path / "p.html").exists()
    with pytest.raises(SpecError, match="use .html"):
        write_view(plan_path, tmp_path / "p.png")
    with pytest.raises(InputError, match="goes with a plan"):
        write_view(INITIAL, tmp_path / "g.html", report=report)
    assert main(["view", str(plan_path), "-o", str(tmp_path / "p.html"), "--report", str(tmp_path / "none.json")]) == 2
    err = capsys.readouterr().err
    assert "none.json" in err and "Traceback" not in err and not list(tmp_path.glob(".view-*"))


def test_report_contacts_and_drift_are_on_the_page(plan_path, tmp_path):
    states = [{"reached": True, "sim_fingers": ["thumb", "index"], "sim_force_closure": True, "sim_metric": 0.01,
               "drift_mm": 0.1 * i, "drift_deg": 0.2, "sim_points": 1,
               "sim_patches": {"thumb": {"points": [[0.0, 0.0, 0.01 * i]], "normals": [[0.0, 0.0, -1.0]]}}}
              for i in range(_counts(plan_path)[0])]
    report = tmp_path / "r.json"
    report.write_text(json.dumps({"passed": True, "verdict": "PASS", "directions": [
        {"name": "palm_down", "report": {"passed": True, "verdict": "PASS: x", "states": states}}]}))
    out = tmp_path / "p.html"
    write_view(plan_path, out, report=report)
    data = _data(out.read_text())
    (run,) = data["runs"]
    n = _counts(plan_path)[0]
    assert run["name"] == "palm_down" and [s["drift_mm"] for s in run["states"]] == pytest.approx([0.1 * i for i in range(n)])
    assert len({s["sets"][0] for s in run["states"]}) == n   # one simulator contact set per distinct position


# ------------------------------------------------------------------ in a browser

def _chromium(url: str, tmp_path: Path, *args: str) -> subprocess.CompletedProcess:
    cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
           "--disable-background-networking", "--disable-component-update", "--disable-sync",
           f"--user-data-dir={tmp_path / 'chromium-profile'}", *args, url]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=120)


def _screenshot(url: str, tmp_path: Path, name: str) -> np.ndarray:
    from PIL import Image

    shot = tmp_path / name
    r = _chromium(url, tmp_path, "--window-size=1280,800", "--virtual-time-budget=4000", f"--screenshot={shot}")
    assert shot.exists(), r.stderr[-2000:]
    return np.asarray(Image.open(shot).convert("RGB"), dtype=int)


def _scene_pixels(img: np.ndarray) -> np.ndarray:
    return img[:, PANEL_PX + 5:, :]


@needs_chromium
def test_plan_page_renders_in_chromium_with_every_state(page, plan_path, tmp_path):
    out, _ = page
    n_states, n_steps = _counts(plan_path)
    r = _chromium(out.as_uri(), tmp_path, "--dump-dom", "--virtual-time-budget=4000")
    dom = r.stdout
    body = re.search(r"<body([^>]*)>", dom)
    assert body and 'data-ready="1"' in body.group(1), r.stderr[-2000:]
    assert len(re.findall(r'<li class="state[^"]*" data-state="\d+"', dom)) == n_states
    assert len(re.findall(r'<li class="step[^"]*" data-step="\d+"', dom)) == n_steps
    assert f'id="regrasp-timeline" data-states="{n_states}" data-steps="{n_steps}"' in dom
    ready_ms = int(re.search(r'data-ready-ms="(\d+)"', body.group(1)).group(1))
    assert ready_ms < 2000, f"the page took {ready_ms} ms to build its scene"
    # mid-step 2 (the ring finger moving): the scene is drawn, with the moving finger's colour
    scene = _scene_pixels(_screenshot(out.as_uri() + f"#frame={FRAMES_PER_STEP + FRAMES_PER_STEP // 2}", tmp_path, "s.png"))
    drawn = np.abs(scene - BACKGROUND).sum(axis=2) > 40
    assert drawn.mean() > 0.05, f"only {drawn.mean():.1%} of the 3D view differs from the background"
    assert scene.std() > 20
    moving = (np.abs(scene - MOVING).sum(axis=2) < 90).sum()
    assert moving > 200, f"{moving} pixels of the moving finger's colour"


@needs_chromium
def test_grasp_page_renders_without_a_moving_finger(tmp_path):
    out = tmp_path / "grasp.html"
    info = write_view(INITIAL, out)
    assert info["kind"] == "grasp" and info["states"] == 1 and info["steps"] == 0
    scene = _scene_pixels(_screenshot(out.as_uri(), tmp_path, "g.png"))
    assert (np.abs(scene - BACKGROUND).sum(axis=2) > 40).mean() > 0.05
    assert (np.abs(scene - MOVING).sum(axis=2) < 90).sum() < 20


def test_cli_view_writes_the_page(plan_path, tmp_path, capsys):
    out = tmp_path / "cli.html"
    assert main(["view", str(plan_path), "-o", str(out)]) == 0
    n_states, n_steps = _counts(plan_path)
    assert f"{n_states} states, {n_steps} steps" in capsys.readouterr().out and out.stat().st_size > 100_000


@pytest.mark.needs_pybullet("pictures (view --gif films)")
def test_film_frames_are_readable(plan_path):
    """640x480 frames with a caption banner, contacts in the fingers' colours and the moving
    finger coloured only while a step runs; one fixed camera along the palm normal."""
    from planner.plan import read_plan
    from planner.frames import hand_of_plan, object_of_plan, plain_plan
    from planner.sim.film import plan_frames
    from planner.sim.render import finger_rgb

    plan = plain_plan(read_plan(plan_path))
    hand = hand_of_plan(plan, plan_path)
    frames = plan_frames(plan, hand, object_of_plan(plan, plan_path), frames_per_step=2)
    assert len(frames) == 1 + 2 * len(plan["steps"])
    assert all(f.shape == (480, 640, 3) for f in frames)

    def count(img, rgb, tol=60):
        return int((np.abs(img.astype(int) - np.array(rgb)).sum(axis=2) < tol).sum())

    assert count(frames[0], MOVING) < 20
    for f in frames[1:]:
        assert count(f, MOVING) > 300
    first = frames[0]
    assert (first[:40].astype(int).sum(axis=2) < 200).sum() > 300   # dark caption text in the top banner
    for finger in plan["states"][0]["patches"]:
        assert count(first, finger_rgb(hand, finger), 30) > 10, finger


@pytest.mark.needs_pybullet("pictures (render_png)")
def test_check_png_markers_are_drawn(tmp_path):
    """`render_png` keeps its signature and draws markers and a caption; the default camera
    looks at the markers from the grasping side (it sees them: they are inside the image)."""
    from planner.grasp import load_grasp
    from planner.realization import realize
    from planner.sim.render import patch_markers, render_png

    g = realize(load_grasp(INITIAL))
    plain = np.asarray(__import__("PIL.Image", fromlist=["Image"]).open(
        render_png(g.hand, g.q, g.obj, tmp_path / "a.png", 640, 480)).convert("RGB"))
    marked = np.asarray(__import__("PIL.Image", fromlist=["Image"]).open(
        render_png(g.hand, g.q, g.obj, tmp_path / "b.png", markers=patch_markers(g.hand, g.obj, g.patches),
                   caption="caption")).convert("RGB"))
    assert plain.shape == marked.shape == (480, 640, 3)
    assert (np.abs(plain.astype(int) - marked).sum(axis=2) > 60).sum() > 200


def test_a_failing_grasp_page_lists_every_problem(tmp_path):
    """A grasp that fails check (a placed finger that closes to its limits without touching):
    the page's state carries every problem check finds, joint limits included, and the page
    shows them under "fails regrasp check"."""
    import yaml

    from planner.grasp import load_grasp
    from planner.realization import realize
    from planner.view import grasp_page_data

    data = {"schema_version": 1, "name": "cube", "hand": "icub_right",
            "object": {"shape": "box", "size": [0.04, 0.04, 0.04], "position": [0.03, -0.01, 0.035],
                       "quat_xyzw": [0, 0, 0, 1], "mass_kg": 0.05},
            "friction": {"mu": 0.9, "gamma": 0.004},
            "fingers": {"thumb": {"contact": {"point": [0.0, -0.02, 0.0]}},
                        "index": {"contact": {"point": [0.02, -0.0137, 0.0015]}}, "middle": "free",
                        "ring": {"posture": [0.349, 0.0, 0.0, 0.0]},
                        "little": {"posture": [0.349, 0.0, 0.0, 0.0]}}}  # little abducted away: never touches
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(data))
    grasp = realize(load_grasp(path))
    assert grasp.problems
    _, page = grasp_page_data(grasp, path)
    assert page["states"][0]["problems"] == list(grasp.problems)
    assert any("upper limit" in p for p in page["states"][0]["problems"])
    out = tmp_path / "bad.html"
    write_view(path, out)
    assert "fails regrasp check" in out.read_text()


def test_the_page_plays_what_the_simulator_did(plan_path, tmp_path):
    """replay --report records the hand's joints and the object's pose (30 Hz); the page holds
    them as frames (object pose per frame, the hand's geometry where it moved) and a button
    plays them; the object of the last frame is where the replay's trajectory ends."""
    import json

    from scipy.spatial.transform import Rotation

    from planner.sim.replay import TRAJECTORY_DT_S, replay_plan

    rep = replay_plan(plan_path)
    traj = rep.trajectory
    assert len(traj["t"]) == len(traj["q"]) == len(traj["object_position"]) >= rep.sim_time_s / TRAJECTORY_DT_S - 2
    assert np.all(np.diff(traj["t"]) > 0) and len(traj["q"][0]) == len(traj["joints"])
    report = tmp_path / "report.json"
    report.write_text(json.dumps(rep.to_dict()))
    out = tmp_path / "sim.html"
    write_view(plan_path, out, report=report)
    html = out.read_text()
    assert 'id="btn-sim"' in html
    run = _data(html)["runs"][0]
    frames = run["traj"]["frames"]
    assert 1 < len(frames) <= len(traj["t"]) and frames[-1]["t"] == pytest.approx(traj["t"][-1], abs=1e-4)
    T = np.asarray(frames[-1]["obj"], float).reshape(4, 4).T  # meshcat's column-major pose
    np.testing.assert_allclose(T[:3, 3], traj["object_position"][-1], atol=1e-5)  # (the page rounds to 10 um)
    R = Rotation.from_quat(traj["object_quat_xyzw"][-1]).as_matrix()
    np.testing.assert_allclose(T[:3, :3], R, atol=1e-5)
    assert len(frames[0]["hand"]) == len(_data(html)["states"][0]["T"])  # the first frame poses every geometry
