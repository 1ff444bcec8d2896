"""pybullet replay of hand-built plans: a stable grasp holds, lifting the thumb drops the object.

The plans are built here from the iCub hand (`Hand.close_finger`, thesis eqs. 8-9) and the
planner's own contact and closure code, in the plan file schema of docs/INTERFACES.md.
"""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from planner.model import Friction
from planner.closure import grasp_closure, removable_fingers
from planner.contacts import contact_patches
from planner.errors import SpecError
from planner.hand import Hand
from planner.objects import make_object
from planner.sim.replay import replay_plan
from planner.sim.report import ReplayReport

BOX_SIZE = (0.03, 0.03, 0.03)
BOX_POS = (0.02, -0.02, 0.025)  # palm frame: between the opposed thumb and index/middle pads
FRICTION = Friction(mu=0.8, gamma=0.002, edges=5)
GRASP_FINGERS = ("thumb", "index", "middle")


@pytest.fixture(scope="module")
def hand():
    return Hand.load("icub_right")


@pytest.fixture(scope="module")
def grasp(hand):
    """A thumb-opposing three-finger grasp of a 3 cm box: (q, obj)."""
    T = np.eye(4)
    T[:3, 3] = BOX_POS
    obj = make_object("box", BOX_SIZE, T, mass_kg=0.03)
    names = list(hand.joint_names)
    q = hand.q_open.copy()
    q[names.index("thumb_0")] = 1.2  # opposition: thumb pad over the grasping face
    for finger in GRASP_FINGERS:
        q = hand.close_finger(finger, q, obj)
    return q, obj


@pytest.fixture(scope="module")
def held(hand, grasp):
    """The replay of the grasp alone (default parameters), shared by the tests that only read it."""
    return replay_plan(_plan(hand, grasp))


@pytest.fixture(scope="module")
def index_lifted(hand, grasp):
    """The replay of the grasp then a lift of the index (removable): shared, it is read only."""
    return replay_plan(_plan(hand, grasp, lift="index"))


@pytest.fixture(scope="module")
def thumb_lifted(hand, grasp):
    """The replay of the grasp then a lift of the opposing thumb (drops the box): shared."""
    return replay_plan(_plan(hand, grasp, lift="thumb"))


def _state(hand, q, obj, fingers):
    patches = {f: v for f, v in contact_patches(hand, q, obj).items() if f in fingers}
    closure = grasp_closure(patches, FRICTION)
    return {
        "fingers": {f: ("initial" if f in fingers else "lifted") for f in hand.fingers},
        "patches": {f: {"points": p.tolist(), "normals": n.tolist()} for f, (p, n) in patches.items()},
        "closure": {"is_force_closure": bool(closure.is_force_closure), "metric": float(closure.metric)},
        "removable": sorted(removable_fingers(patches, FRICTION)),
        "q": {j: float(v) for j, v in zip(hand.joint_names, q)},
    }


def _lifted(hand, q, finger, amount=0.35):
    """q with the finger's flexion joints opened by `amount` rad (a lift away from the box)."""
    names = list(hand.joint_names)
    q = q.copy()
    for j in hand.fingers[finger].close_joints:
        i = names.index(j)
        q[i] = max(hand.lower[i], q[i] - amount)
    return q


def _plan(hand, grasp, lift=None):
    """Plan data: the grasp alone, or the grasp then one lift of `lift`."""
    q, obj = grasp
    states = [_state(hand, q, obj, GRASP_FINGERS)]
    steps = []
    if lift is not None:
        q1 = _lifted(hand, q, lift)
        states.append(_state(hand, q1, obj, tuple(f for f in GRASP_FINGERS if f != lift)))
        joints = list(hand.fingers[lift].joints)
        idx = [list(hand.joint_names).index(j) for j in joints]
        path = [[float(v) for v in qq[idx]] for qq in (q, 0.5 * (q + q1), q1)]
        steps.append({"finger": lift, "action": "lift", "from_state": 0, "to_state": 1, "joints": joints, "path": path})
    return {
        "schema_version": 1,
        "kind": "regrasp-plan",
        "hand": {"name": "icub_right", "spec": "robots/icub_right/hand.yaml"},
        "object": {"shape": "box", "size": list(BOX_SIZE), "position": list(BOX_POS), "quat_xyzw": [0, 0, 0, 1],
                   "mesh": None, "mass_kg": 0.03},
        "friction": {"mu": FRICTION.mu, "gamma": FRICTION.gamma, "edges": FRICTION.edges},
        "inputs": {},
        "parameters": {},
        "summary": {},
        "joints": list(hand.joint_names),
        "states": states,
        "steps": steps,
        "alternatives": [],
    }


def _write(tmp_path, plan, name="plan.yaml"):
    path = tmp_path / name
    path.write_text(yaml.safe_dump(plan, sort_keys=False))
    return path


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "planner", "replay", *map(str, args)],
                          capture_output=True, text=True, cwd=Path(__file__).resolve().parent.parent)


def test_stable_grasp_holds_with_small_drift(held):
    """Holding the thumb-opposing grasp under gravity (palm down) passes with < 5 mm / 5 deg drift,
    and the simulator finds force closure with the same three fingers."""
    report = held
    assert report.passed, report.verdict
    assert not report.dropped
    assert report.max_drift_mm < 5.0 and report.max_drift_deg < 5.0
    s0 = report.states[0]
    assert s0.reached and s0.sim_force_closure
    assert set(s0.sim_fingers) == set(GRASP_FINGERS)


def test_safe_lift_of_index_passes(hand, grasp, index_lifted):
    """Lifting the index (removable in the simulator's and the plan's contacts) keeps the box."""
    plan = _plan(hand, grasp, lift="index")
    assert "index" in plan["states"][0]["removable"]
    report = index_lifted
    assert report.passed, report.verdict
    s1 = report.states[1]
    assert s1.reached and "index" not in s1.sim_fingers and s1.sim_force_closure


def test_lifting_the_thumb_drops_the_object(hand, grasp, thumb_lifted, tmp_path):
    """Lifting the opposing thumb leaves nothing against gravity: the replay fails, and the CLI
    exits 1 with a FAIL verdict."""
    plan = _plan(hand, grasp, lift="thumb")
    report = thumb_lifted
    assert not report.passed
    assert report.dropped or report.max_drift_mm > 5.0
    assert "lift thumb" in report.verdict  # where: the step that lifted it
    out = _cli(_write(tmp_path, plan))
    assert out.returncode == 1, out.stderr
    assert "FAIL" in out.stdout.splitlines()[-1]


def _lift_thumb_then_index(hand, grasp) -> dict:
    """The grasp, the thumb lifted (drops the box palm down), then the index lifted and landed again."""
    plan = _plan(hand, grasp, lift="thumb")
    q, obj = grasp
    q1 = _lifted(hand, q, "thumb")
    q2 = _lifted(hand, q1, "index")
    plan["states"].append(_state(hand, q2, obj, ("middle",)))
    plan["states"].append(_state(hand, q1, obj, ("index", "middle")))
    joints = list(hand.fingers["index"].joints)
    idx = [list(hand.joint_names).index(j) for j in joints]
    for k, (a, b, action) in enumerate(((q1, q2, "lift"), (q2, q1, "land"))):
        plan["steps"].append({"finger": "index", "action": action, "from_state": k + 1, "to_state": k + 2,
                              "joints": joints, "path": [[float(v) for v in qq[idx]] for qq in (a, b)]})
    return plan


def test_a_replay_asked_to_stop_at_its_failure_gives_the_same_verdict_sooner(hand, grasp):
    """stop_at_failure (the planner's verification): the thumb's lift drops the box, and the
    steps after it (the index lifted and landed again) are not simulated: the same failed step
    and state flag as the whole replay, the later states not reached, less simulated time; a
    replay that passes is the same replay with or without it."""
    plan = _lift_thumb_then_index(hand, grasp)
    # (the box falling far is not a drop here, so the whole replay goes on to the end)
    whole, short = (replay_plan(plan, stop_at_failure=stop, drop_mm=1e4) for stop in (False, True))
    assert not whole.passed and not short.passed
    assert (short.failed_step, short.failed_at_state) == (whole.failed_step, whole.failed_at_state) == (0, whole.failed_at_state)
    assert all(s.reached for s in whole.states) and not any(s.reached for s in short.states[2:])
    assert short.sim_time_s < whole.sim_time_s
    assert "lift thumb" in short.verdict
    passing = _plan(hand, grasp, lift="index")
    a, b = (replay_plan(passing, stop_at_failure=stop) for stop in (False, True))
    assert a.passed and b.passed and a.verdict == b.verdict and a.sim_steps == b.sim_steps
    assert [s.sim_fingers for s in a.states] == [s.sim_fingers for s in b.states]


def test_a_stop_line_stops_the_replays_after_the_first_failing_one_in_its_order(hand, grasp):
    """A StopLine shared by the replays of one plan in an order: the failing replay marks its
    place; a replay after it stops unfailed at its next measured state (stopped_after, not
    passed, no failed step, the later states not reached); one before it, or on a line no
    replay failed on, runs to its end."""
    from planner.sim.replay import StopLine

    line = StopLine()
    assert line.first() == StopLine.NONE and not line.at(5).stopped()
    failing = replay_plan(_lift_thumb_then_index(hand, grasp), stop_at_failure=line.at(1))
    assert failing.failed_step == 0 and failing.stopped_after is None and line.first() == 1
    assert line.at(2).stopped() and not line.at(1).stopped() and not line.at(0).stopped()
    plan = _plan(hand, grasp, lift="index")
    plan["states"].append(plan["states"][0])  # the index landed again where it was
    step = dict(plan["steps"][0], action="land", from_state=1, to_state=2, path=plan["steps"][0]["path"][::-1])
    plan["steps"].append(step)
    free = replay_plan(plan, stop_at_failure=StopLine())
    assert free.passed, free.verdict
    before = replay_plan(plan, stop_at_failure=line.at(0))
    assert before.passed and before.verdict == free.verdict
    stopped = replay_plan(plan, stop_at_failure=line.at(2))
    assert stopped.stopped_after == -1 and not stopped.passed and stopped.failed_step is None
    assert stopped.verdict.startswith("STOPPED after step -1") and not stopped.states[1].reached
    assert stopped.states[0].reached and line.first() == 1


def test_sim_normals_point_into_the_object(held):
    """Filtered sim contacts are in the object frame on the box surface, normals pointing inward."""
    s0 = held.states[0]
    assert s0.sim_patches
    for points, normals in s0.sim_patches.values():
        assert np.all(np.max(np.abs(points), axis=1) < BOX_SIZE[0] / 2 + 2e-3)  # on the box surface
        np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-6)
        assert np.all(np.einsum("ij,ij->i", points, normals) < 0.0)  # inward: against the position


def test_replay_is_deterministic(hand, grasp, index_lifted):
    """The same plan and parameters give the same drift to the last digit (a second replay
    against the shared one, in the same process)."""
    a = index_lifted
    b = replay_plan(_plan(hand, grasp, lift="index"))
    assert (a.max_drift_mm, a.max_drift_deg, a.sim_steps) == (b.max_drift_mm, b.max_drift_deg, b.sim_steps)


@pytest.mark.needs_pybullet("pictures (replay --gif)")
def test_gif_and_report_written_by_cli(hand, grasp, tmp_path):
    """`regrasp replay --gif --report` writes a multi-frame GIF and a JSON report, exit 0."""
    from PIL import Image

    path = _write(tmp_path, _plan(hand, grasp, lift="index"))
    gif, rep = tmp_path / "replay.gif", tmp_path / "report.json"
    out = _cli(path, "--gif", gif, "--report", rep)
    assert out.returncode == 0, out.stdout + out.stderr
    assert out.stdout.splitlines()[-1].startswith("PASS")
    with Image.open(gif) as im:
        assert im.n_frames >= 5
        assert im.size == (640, 480)
    data = json.loads(rep.read_text())
    assert data["passed"] is True and len(data["states"]) == 2 and data["gif_frames"] >= 5


@pytest.mark.needs_pybullet("pictures (replay --gif)")
def test_replay_gif_reads_like_the_plan_film(hand, grasp, index_lifted, tmp_path):
    """The replay's GIF is drawn like `regrasp view --gif`: 640x480, a caption band, the
    simulator's contacts in the fingers' colours, the lifting finger in magenta while it
    unloads and moves, frames timed by the simulated clock; filming only reads the
    simulation (the same drifts, closures, contact forces and steps as without a GIF)."""
    from PIL import Image

    from planner.sim.render import MOVING_RGBA, finger_rgb

    plan = _plan(hand, grasp, lift="index")
    gif = tmp_path / "r.gif"
    filmed = replay_plan(plan, gif=gif, gif_every=24)  # one frame per 0.1 s of simulated time
    plain = index_lifted  # the same plan replayed without a film
    assert (filmed.max_drift_mm, filmed.max_drift_deg, filmed.final_drift_mm, filmed.sim_steps) == \
        (plain.max_drift_mm, plain.max_drift_deg, plain.final_drift_mm, plain.sim_steps)
    assert [(s.sim_fingers, s.sim_metric, s.drift_mm, s.carried_n, s.carriers) for s in filmed.states] == \
        [(s.sim_fingers, s.sim_metric, s.drift_mm, s.carried_n, s.carriers) for s in plain.states]
    frames, durations = [], []
    with Image.open(gif) as im:
        assert im.size == (640, 480) and im.n_frames == filmed.gif_frames == filmed.sim_steps // 24
        for i in range(im.n_frames):
            im.seek(i)
            frames.append(np.asarray(im.convert("RGB")).astype(int))
            durations.append(im.info["duration"])
    assert durations[:-1] == [100] * (len(frames) - 1)  # 24 steps of 1/240 s

    def count(img, rgb, tol=30):
        return int((np.abs(img - np.array(rgb)).sum(axis=2) < tol).sum())

    moving = [count(f, [255 * v for v in MOVING_RGBA[:3]], 60) for f in frames]
    t = 0.1 * (1 + np.arange(len(frames)))  # the time of each frame
    settled = frames[int(np.flatnonzero(t > 0.9)[0])]  # state 0 held under gravity, before the lift
    assert (settled[:60].sum(axis=2) < 200).sum() > 300  # dark caption text in the top band
    assert moving[0] < 20 and count(settled, [255 * v for v in MOVING_RGBA[:3]], 60) < 20
    for finger in GRASP_FINGERS:  # contact dots and normals in each touching finger's colour
        assert count(settled, finger_rgb(hand, finger)) > 40, finger
    lift = [m for m, ti in zip(moving, t) if 1.1 <= ti <= 1.4]
    assert lift and min(lift) > 300  # the index finger while it unloads and lifts
    assert moving[-1] < 20  # dwell at state 1: nothing moves


@pytest.mark.needs_pybullet("pictures (replay films)")
def test_gif_frames_keep_the_simulated_clock():
    """Frame delays are whole centiseconds adding up to the simulated time (no drift): 30 fps
    of simulation gives 30/40 ms delays; the last frame is held before the loop restarts."""
    from planner.sim.film import gif_durations_ms

    d = gif_durations_ms(np.arange(31) * 8 / 240.0, hold_ms=1000)
    assert set(d[:-1]) == {30, 40} and sum(d[:-1]) == 1000 and d[-1] == 1000
    assert gif_durations_ms([0.0, 0.05, 0.13], hold_ms=500) == [50, 80, 500]


def test_report_to_dict_is_strict_json(thumb_lifted):
    """ReplayReport.to_dict() round-trips through strict JSON (no NaN) for a failed replay too."""
    report = thumb_lifted
    assert isinstance(report, ReplayReport)
    text = json.dumps(report.to_dict(), allow_nan=False)
    assert json.loads(text)["passed"] is False


def test_missing_key_is_a_spec_error_naming_file_and_key(hand, grasp, tmp_path):
    """A plan without object.size raises SpecError(file, key); the CLI prints one line, exit 2."""
    plan = _plan(hand, grasp)
    del plan["object"]["size"]
    with pytest.raises(SpecError) as err:
        replay_plan(plan)
    assert err.value.key == "object.size"
    path = _write(tmp_path, plan, "broken.yaml")
    out = _cli(path)
    assert out.returncode == 2
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and "broken.yaml" in lines[0] and "object.size" in lines[0]


def test_missing_file_and_mp4_without_ffmpeg_exit_2(tmp_path, hand, grasp, monkeypatch):
    """A missing plan file exits 2; --mp4 without ffmpeg on PATH is a clear SimulationError."""
    out = _cli(tmp_path / "nope.yaml")
    assert out.returncode == 2 and len(out.stderr.strip().splitlines()) == 1
    monkeypatch.setenv("PATH", str(tmp_path))  # no ffmpeg here
    from planner.errors import SimulationError

    with pytest.raises(SimulationError, match="ffmpeg"):
        replay_plan(_plan(hand, grasp), mp4=tmp_path / "x.mp4")


_LIBRARY_PLANS: dict = {}


#: Bundled pairs: name -> (initial, final) under grasps/.
LIBRARY_PAIRS = {
    "box": ("icub/box_parallel_extension.yaml", "icub/box_ir2m.yaml"),
    "cylinder": ("icub/cylinder_parallel_extension.yaml", "icub/cylinder_ir2m.yaml"),
    "pen": ("icub/pen_palmar_pinch.yaml", "icub/pen_writing_tripod.yaml"),
    "mesh": ("icub/mesh_rounded_box_parallel_extension.yaml", "icub/mesh_rounded_box_ir2m.yaml"),
    "allegro_box": ("allegro/box_four_finger.yaml", "allegro/box_tripod.yaml"),
}


def _library_plan(pair: str) -> dict:
    """A bundled pair planned in execution mode (mean contacts, six gravity directions,
    grip ranking) with finger paths, once per test session."""
    from planner.grasp import load_grasp
    from planner.options import PlanOptions
    from planner.realization import realize
    from planner.regrasp import plan_regrasp

    if pair not in _LIBRARY_PLANS:
        root = Path(__file__).resolve().parent.parent / "grasps"
        initial, final = (realize(load_grasp(root / f)) for f in LIBRARY_PAIRS[pair])
        _LIBRARY_PLANS[pair] = plan_regrasp(initial, final, PlanOptions.for_execution()).plan.to_dict()
    return _LIBRARY_PLANS[pair]


@pytest.mark.parametrize("pair", ["pen", "mesh", "allegro_box"])
@pytest.mark.parametrize("direction", ["palm_down", "palm_up", "off"])
def test_other_bundled_pairs_hold_in_execution_mode(pair, direction):
    """Issue acceptance on the pen (a 5 mm rod), the rounded-box mesh and the Allegro box:
    planned in execution mode, the replay keeps the object within 5 mm / 5 deg with gravity
    off, palm down and palm up (the hand's palm normal), and the closures agree."""
    from planner.gravity import gravity_directions
    from planner.hand import Hand

    plan = _library_plan(pair)
    hand = Hand.load(plan["hand"]["name"])
    g = dict(gravity_directions(hand.palm_normal, 7))[direction]
    report = replay_plan(plan, gravity=g, hand=hand)
    assert report.passed, report.verdict
    assert report.closure_agreement == (len(plan["states"]), len(plan["states"]))


@pytest.mark.parametrize("pair,gravity", [
    ("box", (0.0, 0.0, 9.81)), ("box", (0.0, 0.0, 0.0)), ("box", (0.0, 0.0, -9.81)),
    ("cylinder", (0.0, 0.0, 9.81)), ("cylinder", (0.0, 0.0, -9.81)), ("cylinder", (0.0, 0.0, 0.0)),
    ("cylinder", (0.0, 9.81, 0.0)), ("cylinder", (-9.81, 0.0, 0.0))],
    ids=["box_palm_down", "box_no_gravity", "box_palm_up", "cylinder_palm_down", "cylinder_palm_up",
         "cylinder_no_gravity", "cylinder_side_+y", "cylinder_side_-x"])
def test_library_plan_holds_and_agrees_at_every_state(pair, gravity):
    """Issue acceptance on the bundled PE -> IR2M pairs: planned in execution mode with
    finger paths, the replay keeps the object within 5 mm / 5 deg, and the simulator's
    closure agrees with the plan's at every state of the gait."""
    plan = _library_plan(pair)
    assert plan["parameters"]["contact_model"] == "link"
    assert {s["finger"] for s in plan["steps"]} >= {"index", "ring", "little"}
    report = replay_plan(plan, gravity=gravity)
    assert report.passed, report.verdict
    assert all(s.reached for s in report.states)
    assert report.closure_agreement == (len(plan["states"]), len(plan["states"]))
    assert report.max_drift_mm < 5.0 and report.max_drift_deg < 5.0


def test_squeeze_follows_the_load_and_the_hand():
    """The squeeze is derived, not tuned: twice the normal force that holds the weight by
    friction alone, shared by the holding fingers, never below the heaviest finger's weight."""
    from planner.sim.controller import SAFETY, squeeze_force_n

    assert squeeze_force_n(0.1, 9.81, 2, 0.5, 0.2) == pytest.approx(SAFETY * 0.1 * 9.81 / (2 * 0.5))
    assert squeeze_force_n(0.001, 9.81, 4, 0.9, 0.3) == 0.3
    assert squeeze_force_n(0.1, 9.81, 4, 0.5, 0.0) == pytest.approx(squeeze_force_n(0.1, 9.81, 2, 0.5, 0.0) / 2)


def test_force_optimization_uses_torsional_friction_only_within_its_limit():
    """Two antipodal contacts 40 mm apart cannot resist a moment about their common axis with
    point forces; with soft-finger torsion |t| <= gamma fn they can, at the smallest normal
    force that reaches the moment: fn = moment / (2 gamma)."""
    from planner.sim.controller import balance_forces

    P = np.array([[0.02, 0.0, 0.0], [-0.02, 0.0, 0.0]])
    N = np.array([[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    gamma = 0.01
    fr = Friction(mu=1.0, gamma=gamma, edges=5)
    for moment, fn in ((0.01, 1.0), (0.05, 2.5)):
        load = np.array([0, 0, 0, -moment, 0, 0], float)  # the fingers must supply +moment about x
        kw = dict(targets=1.0 * N, load=load, centre=np.zeros(3), friction=fr, fn_min=0.1, f_max=100.0)
        assert balance_forces(P, N, margins=((0.5, 0.0),), **kw) is None
        f = balance_forces(P, N, margins=((0.5, 1.0),), **kw)
        assert np.allclose(np.einsum("ij,ij->i", f, N), fn, atol=1e-7)
        assert np.allclose(f.sum(axis=0), 0.0, atol=1e-9)


def test_balanced_forces_hold_the_load_inside_the_shrunk_cones():
    """Property (seeded): for random three- and four-contact grasps of a sphere the forces
    balance the weight (force and moment about the centre) and stay inside the friction cone
    of the margin that was used; an unbalanceable set (all normals alike) gives None."""
    from planner.grip import CONE_MARGINS, balance_forces

    rng = np.random.default_rng(7)
    fr = Friction(mu=0.8, gamma=0.0, edges=5)
    solved = 0
    for _ in range(30):
        k = int(rng.integers(3, 5))
        d = rng.normal(size=(k, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        P, N = 0.02 * d, -d
        load = np.r_[0.03 * 9.81 * rng.normal(size=3) / np.sqrt(3), np.zeros(3)]
        f = balance_forces(P, N, 0.5 * N, load, np.zeros(3), fr, 0.05, 10.0, margins=CONE_MARGINS[:1])
        if f is None:
            continue
        solved += 1
        np.testing.assert_allclose(f.sum(axis=0) + load[:3], 0.0, atol=1e-8)
        np.testing.assert_allclose(np.cross(P, f).sum(axis=0), 0.0, atol=1e-9)
        fn = np.einsum("ij,ij->i", f, N)
        ft = np.linalg.norm(f - fn[:, None] * N, axis=1)
        assert np.all(fn >= 0.05 - 1e-9) and np.all(ft <= 0.5 * fr.mu * fn + 1e-9)
    assert solved >= 10
    same = np.tile([[0.0, 0.0, -1.0]], (3, 1))
    assert balance_forces(0.02 * -same + [[0.01, 0, 0], [0, 0.01, 0], [0, 0, 0]], same, same, [0, 0, 9.81 * 0.03, 0, 0, 0],
                          np.zeros(3), fr, 0.05, 10.0) is None


def test_closure_disagreement_is_never_a_pass(hand, grasp):
    """A plan whose state claims the opposite of what the simulator measures fails, and the
    verdict names the state, although the object stays put."""
    plan = _plan(hand, grasp)
    plan["states"][0]["closure"]["is_force_closure"] = False
    report = replay_plan(plan)
    assert not report.dropped and report.max_drift_mm < 5.0
    assert not report.passed
    assert "disagrees" in report.verdict and "state 0" in report.verdict


def test_gravity_set_replays_every_direction_with_its_own_verdict(hand, grasp, tmp_path):
    """--gravity-set 2 replays palm down and palm up (the hand's palm normal) and prints one
    line per direction; the lift of the thumb fails in the set, naming the thumb."""
    from planner.sim.verify import replay_gravity_set

    result = replay_gravity_set(_plan(hand, grasp, lift="thumb"), 2, hand=hand)
    names = [n for n, _, _ in result.directions]
    assert names == ["palm_down", "palm_up"]
    np.testing.assert_allclose(result.directions[0][1], 9.81 * np.asarray(hand.palm_normal))
    assert not result.passed and "palm_down" in result.verdict and "thumb" in result.verdict
    out = _cli(_write(tmp_path, _plan(hand, grasp, lift="thumb")), "--gravity-set", "2")
    assert out.returncode == 1
    rows = [l for l in out.stdout.splitlines() if l.startswith(("palm_down", "palm_up"))]
    assert len(rows) == 2 and "FAIL" in rows[0]


@pytest.mark.needs_pybullet("pictures (replay --gif)")
def test_interrupted_gravity_set_stops_its_workers_and_writes_no_film(hand, grasp, tmp_path):
    """Ctrl-C (a KeyboardInterrupt in this process) while directions replay in worker processes:
    the running replay is stopped and the queued ones do not start, so no film is written (the
    pool used to wait for every queued direction, minutes, and write their films)."""
    from planner.gravity import gravity_directions
    from planner.sim.inputs import typed_plan
    from planner.sim.verify import replay_directions

    directions = gravity_directions(hand.palm_normal, 7)
    films = [tmp_path / f"{name}.gif" for name, _ in directions]

    def ctrl_c():  # runs in this process once the first direction was handed to a worker
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        replay_directions(typed_plan(_plan(hand, grasp), False), hand, directions, workers=2, meanwhile=ctrl_c,
                          gif=films, gif_every=48)
    assert sorted(p.name for p in tmp_path.iterdir()) == []


@pytest.mark.needs_pybullet("pictures (replay --gif --film)")
def test_gravity_set_films_only_the_directions_asked_for(hand, grasp, tmp_path):
    """--film palm_down with --gravity-set 2 and --gif writes the palm-down film only; a
    direction outside the set, or --film without --gravity-set, is refused naming the choices."""
    path = _write(tmp_path, _plan(hand, grasp))
    out = _cli(path, "--gravity-set", "2", "--gif", tmp_path / "g.gif", "--gif-every", "48", "--film", "palm_down")
    assert out.returncode == 0, out.stderr
    assert sorted(p.name for p in tmp_path.glob("*.gif")) == ["g_palm_down.gif"]
    bad = _cli(path, "--gravity-set", "2", "--gif", tmp_path / "h.gif", "--film", "side_+x")
    assert bad.returncode == 2 and "side_+x" in bad.stderr and "palm_down, palm_up" in bad.stderr
    lone = _cli(path, "--gif", tmp_path / "i.gif", "--film", "palm_down")
    assert lone.returncode == 2 and "--gravity-set" in lone.stderr
    assert not list(tmp_path.glob("[hi]*.gif"))


@pytest.mark.parametrize("n", [1, 2, 6, 7])
def test_gravity_sets_have_n_named_directions_of_one_magnitude(n):
    """Each set size gives exactly n directions: palm down first (along the palm normal),
    distinct names, magnitude g (0 for "off"), and the sideways ones orthogonal to the normal."""
    from planner.gravity import gravity_directions

    for normal in ((0.0, 0.0, 1.0), (1.0, 0.0, 0.0)):
        dirs = gravity_directions(normal, n)
        assert len(dirs) == n and len({name for name, _ in dirs}) == n
        assert dirs[0][0] == "palm_down"
        np.testing.assert_allclose(dirs[0][1], 9.81 * np.asarray(normal))
        for name, g in dirs:
            assert np.linalg.norm(g) == pytest.approx(0.0 if name == "off" else 9.81)
            if name.startswith("side_"):
                assert abs(np.dot(g, normal)) < 1e-12


@pytest.mark.needs_pybullet("pybullet's engine (PybulletEngine)")
def test_armature_floor_keeps_the_stiffest_spring_stable_with_margin():
    """The armature floor puts the stiffest posture spring at omega dt = ARMATURE_OMEGA_DT:
    Bullet's semi-implicit Euler step of a critically damped spring has spectral radius < 1
    there and still for 2.5x the stiffness (contacts add some), and the floor is no larger
    than that (every joint's spring sits at that omega dt when a free finger squeezes alone)."""
    from planner.sim import controller as C
    from planner.sim import inputs as inp
    from planner.sim import replay as R
    from planner.sim.engine_pybullet import PybulletEngine

    def radius(w):  # state (x, v dt): v+ = v - w^2 x - 2 w v, x+ = x + v+
        return max(abs(np.linalg.eigvals(np.array([[1 - w * w, 1 - 2 * w], [-w * w, 1 - 2 * w]]))))

    assert radius(C.ARMATURE_OMEGA_DT) < 0.8
    assert radius(2.5 ** 0.5 * C.ARMATURE_OMEGA_DT) < 1.0  # 2.5x the stiffness still converges
    assert radius(0.9) > 1.0  # the model is not vacuous: too little inertia diverges

    rd = inp.typed_plan(_library_plan("box"))
    params = dict(dt=1 / 240, contact_model="mean", gravity=[0, 0, 9.81], finger_force_n=None,
                  solver_iterations=150, filter_k=12)
    info = inp.load_hand_info(rd, list(rd.joints))
    mass, radius_m = inp.object_mass(rd.object, 500)
    engine = PybulletEngine(inp.replay_world(info, rd.object, mass, rd.friction, 1 / 240, 150))
    try:
        sim = R._Sim(engine, rd, info, list(rd.joints), rd.object, rd.friction, params, mass, radius_m)
        ctl = sim.ctl
        ctl.command(dict(zip(rd.joints, rd.states[0].q)), (), moving=None)  # every finger free
        F1 = C.squeeze_force_n(ctl.mass, ctl.g_max, 1, ctl.friction.mu, ctl.floor_n)
        scale = max(C.FREE_SHARE, C.POSTURE_SHARE) / C.FREE_SHARE * F1 / ctl.force_n
        fingers = [ctl.hand_pos[j] for f in ctl.hand.fingers.values() for j in f.joints]
        w = np.sqrt(scale * ctl.kp[fingers] / ctl.armature[fingers]) * sim.dt
        assert np.all(w <= C.ARMATURE_OMEGA_DT * (1 + 1e-9))
        assert np.max(w) == pytest.approx(C.ARMATURE_OMEGA_DT, rel=0.02)
    finally:
        engine.close()


def test_pose_drift_matches_the_rotation_matrix_angle():
    """The replay's per-step drift (quaternions) equals the translation distance and the
    angle of R_ref^T R from its trace, on seeded random poses (q and -q alike)."""
    from scipy.spatial.transform import Rotation

    from planner.sim.replay import pose_drift

    rng = np.random.default_rng(3)
    for _ in range(50):
        Ra, Rb = Rotation.random(random_state=rng), Rotation.random(random_state=rng)
        pa, pb = rng.normal(size=3) * 0.01, rng.normal(size=3) * 0.01
        qb = Rb.as_quat() * (1 if rng.random() < 0.5 else -1)
        mm, deg = pose_drift(tuple(pa), tuple(Ra.as_quat()), tuple(pb), tuple(qb))
        R = Ra.as_matrix().T @ Rb.as_matrix()
        expected = np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1)))
        assert mm == pytest.approx(1000 * np.linalg.norm(pb - pa), rel=1e-12)
        assert deg == pytest.approx(expected, abs=1e-6)
    assert pose_drift((0, 0, 0), (0, 0, 0, 1), (0, 0, 0.002), (0, 0, np.sin(np.radians(5)), np.cos(np.radians(5)))) == \
        pytest.approx((2.0, 10.0))


def test_a_lift_retreats_from_where_the_finger_touches_and_ends_where_planned():
    """`lift_path`: starts at the finger's current configuration (twice: the start, then the
    shifted first waypoint), ends at the planned lift end, and every step is the planned step
    plus an equal share of the offset, so the retreat keeps its direction."""
    from planner.sim.replay import lift_path

    rng = np.random.default_rng(5)
    planned = np.cumsum(rng.normal(scale=0.01, size=(12, 4)), axis=0)
    start = planned[0] + np.array([0.08, -0.03, 0.0, 0.02])
    out = lift_path(start, planned)
    assert out.shape == (13, 4)
    assert np.allclose(out[0], start) and np.allclose(out[1], start)
    assert np.allclose(out[-1], planned[-1])
    share = (start - planned[0]) / (len(planned) - 1)
    assert np.allclose(np.diff(out[1:], axis=0), np.diff(planned, axis=0) - share)
    assert np.allclose(lift_path(planned[0], planned)[1:], planned)  # no offset: the plan itself


def _pen_turn_plan_holds(hand_dir: str, hand_name: str, min_deg: float, moved_fingers: tuple[str, ...]):
    """The bundled pen pair of ``grasps/<hand_dir>/`` (pinch -> writing pose, the object turned
    more than ``min_deg``) planned in execution mode: the middle finger lands at the pinch's
    pose, then a reposing move of at least ``moved_fingers``' joints turns the pen along the
    whole angle; the plan passes the physics check `regrasp replay` runs first, was verified
    in all six directions before it was returned, and an independent replay palm down follows
    the planned object path."""
    from planner.audit import audit_plan
    from planner.gravity import gravity_directions
    from planner.grasp import load_grasp
    from planner.options import PlanOptions
    from planner.realization import realize
    from planner.regrasp import plan_regrasp
    from planner.repose import pose_distance

    root = Path(__file__).resolve().parent.parent / "grasps" / hand_dir
    pinch, pose = (realize(load_grasp(root / f)) for f in ("pen_palmar_pinch.yaml", "pen_writing_pose.yaml"))
    mm, deg = pose_distance(pinch.obj.T_palm_obj, pose.obj.T_palm_obj)
    assert deg > min_deg
    plan = plan_regrasp(pinch, pose, PlanOptions.for_execution()).plan
    assert [(s.finger, s.action) for s in plan.steps][-2:] == [("middle", "land"), ("object", "repose")]
    moved = plan.steps[-1]
    assert set(moved.joints) >= {j for f in moved_fingers for j in pose.hand.fingers[f].joints}
    rep = plan.summary["reposing"]
    assert rep["moves"] == 1 and rep["object_path_deg"] == pytest.approx(deg, abs=0.01)
    audit = audit_plan(plan)
    assert audit.ok, audit.problems
    ver = plan.summary["verification"]
    assert ver["passed"] and len(ver["directions"]) == 6 and all(d["passed"] for d in ver["directions"].values())
    hand = Hand.load(hand_name)
    report = replay_plan(plan.to_dict(), gravity=dict(gravity_directions(hand.palm_normal, 7))["palm_down"], hand=hand)
    assert report.passed, report.verdict
    assert report.max_drift_mm < 5.0 and report.max_drift_deg < 5.0
    return plan


@pytest.mark.needs_pybullet("the iCub pen example is verified in pybullet; MuJoCo refuses its tripod turn (side_-y: "
                            "5.1 deg of drift against the 5 deg limit)")
def test_pen_pinch_to_writing_pose_turns_the_pen_in_a_tripod_and_holds():
    """Issue 39 item 5, the thesis's motivating case: the pen picked with a palmar pinch ends
    in a writing tripod with the pen turned 10 deg (`_pen_turn_plan_holds`; thumb and index
    re-postured at the start of the turn, their pads rolling on their points)."""
    _pen_turn_plan_holds("icub", "icub_right", 10.0, ("middle", "thumb"))


def test_allegro_pen_pinch_to_writing_pose_turns_the_pen_in_a_tripod_and_holds():
    """Issue 39 item 5 on the Allegro: the 10 mm pen picked with a tip-to-tip palmar pinch ends
    in a writing tripod with the pen turned 21 deg, its axis tilted 9 deg
    (`_pen_turn_plan_holds`); the last state holds with thumb, index and middle."""
    plan = _pen_turn_plan_holds("allegro", "allegro_right", 20.0, ("thumb", "index", "middle"))
    assert set(plan.states[-1].patches) >= {"thumb", "index", "middle"}
