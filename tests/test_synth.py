"""Grasp synthesis (`regrasp synth`): written files pass `check` unchanged, their force closure
holds under an independent LP, seeded runs are byte-identical, nothing is overwritten."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.optimize import linprog

from planner.cli import main
from planner.closure import min_grip_force
from planner.grasp import load_grasp
from planner.realization import execution_verdict, realize

ROOT = Path(__file__).resolve().parent.parent
BALL = {"shape": "sphere", "size": [0.015], "mass_kg": 0.03}


def _object_file(tmp_path, block, name="ball.yaml", wrap=False) -> Path:
    path = tmp_path / name
    path.write_text(yaml.safe_dump({"object": block} if wrap else block))
    return path


def _synth(args) -> int:
    return main(["synth", *map(str, args), "--quiet"])


def _independent_force_closure(patches, mu, gamma, sides=8) -> bool:
    """Force closure by the classic LP, not closure.py: the contact wrenches (inscribed
    friction pyramid of ``sides`` edges at every patch point, plus +/- gamma torsion about the
    normal) span R^6 and some strictly positive combination of them is zero
    (exists lambda >= 1 with W^T lambda = 0) - then the origin is interior to their hull."""
    rows = []
    for p, n in patches.values():
        for pi, ni in zip(np.asarray(p), np.asarray(n)):
            ni = ni / np.linalg.norm(ni)
            a = np.array([1.0, 0.0, 0.0]) if abs(ni[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
            t1 = np.cross(ni, a)
            t1 /= np.linalg.norm(t1)
            t2 = np.cross(ni, t1)
            for k in range(sides):
                th = 2 * np.pi * k / sides
                f = ni + mu * (np.cos(th) * t1 + np.sin(th) * t2)
                rows.append(np.r_[f, np.cross(pi, f)])
            for s in (1.0, -1.0):
                rows.append(np.r_[ni, np.cross(pi, ni) + s * gamma * ni])
    W = np.array(rows)
    if np.linalg.matrix_rank(W, tol=1e-9) < 6:
        return False
    res = linprog(np.zeros(len(W)), A_eq=W.T, b_eq=np.zeros(6), bounds=[(1.0, None)] * len(W), method="highs")
    return res.status == 0


def test_synth_writes_grasps_that_check_accepts_and_are_force_closure(tmp_path, capsys):
    """Each written file passes `regrasp check` (exit 0) on its own, every chosen finger touches
    and nothing else does, and an independent LP on the re-realized contacts says force closure."""
    obj = _object_file(tmp_path, BALL)
    out = tmp_path / "out"
    assert _synth(["icub_right", obj, "--fingers", "thumb,index,middle", "-n", 3, "-o", out]) == 0
    files = sorted(out.glob("*.yaml"))
    assert [f.name for f in files] == [f"icub_right_sphere_0{i}.yaml" for i in (1, 2, 3)]
    capsys.readouterr()
    keys = []
    for f in files:
        assert main(["check", str(f)]) == 0, capsys.readouterr().out
        g = realize(load_grasp(f))
        assert g.ok and set(g.patches) == {"thumb", "index", "middle"}
        assert _independent_force_closure(g.patches, g.friction.mu, g.friction.gamma)
        assert not _independent_force_closure({"index": g.patches["index"]}, g.friction.mu, g.friction.gamma)
        desc = " ".join(yaml.safe_load(f.read_text())["description"].split())
        ready = "plan --execution accepts it (held in " in desc
        # accepted: by the static test and then held in a physics engine; refused by either, saying which
        assert ready == (execution_verdict(g).ok and "does not hold in the simulator" not in desc), desc
        keys.append((not ready, -g.metric))
    assert keys == sorted(keys)  # execution-accepted first, then by the closure metric
    assert obj.read_text() == yaml.safe_dump(BALL)  # the input is untouched


def test_synth_is_deterministic_and_refuses_to_overwrite(tmp_path, capsys):
    """Same seed, byte-identical files; a second run into a used folder exits 2 and leaves it alone;
    another seed gives other grasps."""
    obj = _object_file(tmp_path, BALL)
    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    for d, seed in ((a, 5), (b, 5), (c, 6)):
        assert _synth(["icub_right", obj, "--fingers", "thumb,index", "-n", 2, "-o", d, "--seed", seed]) == 0
    read = lambda d: [p.read_bytes() for p in sorted(d.glob("*.yaml"))]  # noqa: E731
    assert read(a) == read(b) and read(a) != read(c)
    before = read(a)
    capsys.readouterr()
    assert _synth(["icub_right", obj, "--fingers", "thumb,index", "-n", 2, "-o", a, "--seed", 7]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "refusing to overwrite" in err
    assert read(a) == before


def test_synth_with_gravity_keeps_grasps_holding_the_weight(tmp_path):
    """With --gravity every written grasp holds the object's weight within the force budget
    (min_grip_force re-computed from the re-realized grasp)."""
    obj = _object_file(tmp_path, BALL)
    out = tmp_path / "out"
    g_palm = np.array([0.0, 0.0, 9.81])
    assert _synth(["icub_right", obj, "--fingers", "thumb,index,middle", "-n", 2, "-o", out, "--gravity", *g_palm,
                   "--max-finger-force", 0.5]) == 0
    for f in sorted(out.glob("*.yaml")):
        g = realize(load_grasp(f))
        R = np.asarray(g.obj.T_palm_obj)[:3, :3]
        load = np.r_[0.03 * (R.T @ g_palm), np.zeros(3)]
        assert min_grip_force(dict(g.patches), g.friction, load) <= 0.5 + 1e-9
        assert "grip force" in yaml.safe_load(f.read_text())["description"]


def test_synth_keeps_a_given_object_pose_and_reads_a_grasp_file(tmp_path):
    """An object file with a position (here a whole grasp file: its object: block and friction)
    keeps the pose: every grasp shares it, so any two are a regrasp pair (Allegro hand)."""
    src = ROOT / "grasps/allegro/sphere_four_finger.yaml"
    out = tmp_path / "out"
    assert _synth(["allegro_right", src, "--fingers", "thumb,index,middle", "-n", 2, "-o", out]) == 0
    want = yaml.safe_load(src.read_text())["object"]
    for f in sorted(out.glob("*.yaml")):
        spec = load_grasp(f)
        np.testing.assert_allclose(spec.object.position, want["position"])
        np.testing.assert_allclose(spec.object.quat_xyzw, want["quat_xyzw"])
        assert main(["check", str(f)]) == 0


@pytest.mark.parametrize("args,words", [
    (["icub_right", "OBJ", "--fingers", "thumb,pinky", "-n", 1, "-o", "OUT"], ["pinky", "thumb"]),
    (["icub_right", "BAD", "--fingers", "thumb", "-n", 1, "-o", "OUT"], ["expected an object block"]),
    (["icub_right", "OBJ", "--fingers", "thumb", "-n", 0, "-o", "OUT"], ["-n must be in 1.."]),
    (["icub_right", "OBJ", "--fingers", "thumb", "-n", 1, "-o", "OUT", "--workers", 0], ["--workers", "out of range"]),
])
def test_synth_bad_input_is_one_line_exit_2(tmp_path, capsys, args, words):
    obj = _object_file(tmp_path, BALL)
    bad = tmp_path / "bad.yaml"
    bad.write_text("size: [0.01]\n")
    subst = {"OBJ": obj, "BAD": bad, "OUT": tmp_path / "out"}
    assert _synth([subst.get(a, a) if isinstance(a, str) else a for a in args]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and all(w in err for w in words)
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_synth_empty_output_name_is_refused(tmp_path, monkeypatch, capsys):
    """`synth -o ''` (an empty shell variable): one line, exit 2; the grasp files were written
    into the current folder."""
    obj = _object_file(tmp_path, BALL)
    work = tmp_path / "cwd"
    work.mkdir()
    monkeypatch.chdir(work)
    assert _synth(["icub_right", str(obj), "--fingers", "thumb,index,middle", "-n", 1, "-o", ""]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "-o: an empty name; name a folder" in err[0], err
    assert list(work.iterdir()) == []


def test_synth_for_execution_keeps_grasps_holding_in_every_direction_with_mean_contacts():
    """With several gravity directions, the mean contact model and a friction reserve, every kept
    grasp is force closure with one contact per finger and holds the weight in each direction
    twice over within the joint limits and a 1 N cap per finger, using 3/4 of mu and gamma (the
    weight alone needs at most 0.5 N per finger, independently recomputed); a grasp over the
    limits in one direction only is refused."""
    from planner.model import Friction
    from planner.closure import apply_contact_model
    from planner.gravity import gravity_directions
    from planner.synthesis import synthesize

    dirs = np.array([g for _, g in gravity_directions((0.0, 0.0, 1.0), 6)])
    r = synthesize("icub_right", dict(BALL), ["thumb", "index", "middle"], 1, fixed=False, seed=1,
                   gravity=dirs, max_finger_force_n=1.0, contact_model="mean", friction_margin=0.75,
                   max_attempts=80)
    assert r.grasps
    # both new filters refused candidates that the plain check accepted
    assert r.rejected["weight beyond the hand's limits"] > 0 and r.rejected["not force closure with mean contacts"] > 0
    for sg in r.grasps:
        g = sg.grasp
        assert g.closure_under("mean").is_force_closure
        mean = apply_contact_model(dict(g.patches), "mean")
        R = np.asarray(g.obj.T_palm_obj)[:3, :3]
        fr = Friction(g.friction.mu * 0.75, g.friction.gamma * 0.75, g.friction.edges)
        grips = [min_grip_force(mean, fr, np.r_[g.obj.mass_kg * (R.T @ d), np.zeros(3)]) for d in dirs]
        assert max(grips) == pytest.approx(sg.grip_force_n) and sg.grip_force_n <= 0.5 + 1e-9
    with pytest.raises(Exception, match="contact model"):
        synthesize("icub_right", dict(BALL), ["thumb", "index"], 1, fixed=False, contact_model="soft")


def test_synth_says_why_when_it_finds_too_few_and_has_a_tripod_default(tmp_path, capsys):
    """An object out of every finger's reach: exit 1, a table of the rejection reasons whose
    counts add up to the attempts, and what to try; without --fingers: the thumb and the
    hand's next two fingers."""
    from planner.cli import main
    from planner.hand import Hand
    from planner.synthesis import default_fingers

    far = tmp_path / "far.yaml"
    far.write_text("shape: sphere\nsize: [0.02]\nposition: [0.3, 0.3, 0.3]\n")
    assert main(["synth", "icub_right", str(far), "-n", "2", "--max-attempts", "20", "-o", str(tmp_path / "o"), "-q"]) == 1
    out = capsys.readouterr().out
    assert "rejected because" in out and "try:" in out and "(thumb,index,middle)" in out
    counts = [int(line.split()[-1]) for line in out.splitlines() if line.startswith("  ") and line.split()[-1].isdigit()]
    assert sum(counts) == 20
    assert default_fingers(Hand.load("icub_right")) == ["thumb", "index", "middle"]
    assert default_fingers(Hand.load("allegro_right")) == ["thumb", "index", "middle"]


@pytest.mark.parametrize("args, kwargs, words", [
    (("icub_right", None, "thumb,index"), {}, "^object_block: expected a grasp file's object mapping .*got nothing"),
    (("icub_right", "ball.yaml", "thumb,index"), {}, "^object_block: expected .*got str 'ball.yaml'"),
    (("icub_right", BALL, None), {}, r"^fingers: expected finger names \(a list or 'thumb,index,middle'\), got nothing"),
    (("icub_right", BALL, "thumb,index"), {"n": "2"}, r"^synth: n must be an integer in 1\.\.10000, got '2'"),
    (("icub_right", BALL, "thumb,index"), {"workers": "two"}, r"^synth: workers must be an integer in 1\.\.256, got 'two'"),
    (("icub_right", BALL, "thumb,index"), {"seed": -1}, r"^synth: seed must be an integer in 0\.\.4294967295, got -1"),
    (("icub_right", BALL, "thumb,index"), {"max_attempts": 0}, r"^synth: max_attempts must be an integer in 1\.\.10000000"),
    (("icub_right", BALL, "thumb,index"), {"bogus": 1}, "^unknown synth option 'bogus'; synth options are base_dir"),
], ids=["object-None", "object-path", "fingers-None", "n-str", "workers-str", "seed-negative", "attempts-0", "bogus"])
def test_synth_api_bad_arguments_are_planner_errors(args, kwargs, words):
    """`planner.synth` refuses what the CLI refuses, in one PlannerError naming the argument and
    what it takes: before, a str count was a TypeError, a negative seed numpy's ValueError, no
    object mapping or fingers a TypeError, a misspelt keyword a TypeError, and max_attempts=0 ran
    no attempt and returned no grasp."""
    import planner

    with pytest.raises(planner.PlannerError, match=words):
        planner.synth(*args, **kwargs)


def test_synth_with_one_gravity_names_it_in_its_verdicts(tmp_path, capsys):
    """With one --gravity synth judges execution in that direction alone, so a file's verdict
    names it (`plan --execution --gravity palm_down accepts it`) and `check --execution
    --gravity palm_down` agrees; it said `plan --execution accepts it` for this four-finger grasp
    of a 15 mm ball, which holds 0.89x its weight palm up: plan --execution and check --execution
    (six directions) refuse it."""
    obj = _object_file(tmp_path, {"shape": "sphere", "size": [0.015], "mass_kg": 0.016,
                                  "position": [0.007417530893595576, -0.01244876006653533, 0.019988998172736173],
                                  "quat_xyzw": [0.0, 0.0, 0.0, 1.0]})
    out = tmp_path / "out"
    # the static verdicts (--no-verify): which grasps a physics engine then holds is the engine's
    assert _synth(["icub_right", obj, "--fingers", "thumb,index,middle,ring", "-n", 3, "--seed", 7,
                   "--gravity", "palm_down", "-o", out, "--no-verify"]) == 0
    printed = capsys.readouterr().out
    assert printed.count("(--gravity palm_down only)") == 3, printed
    six_refuse_accepted = 0
    for f in sorted(out.glob("*.yaml")):
        desc = " ".join(yaml.safe_load(f.read_text())["description"].split())
        assert "plan --execution accepts it" not in desc and "plan --execution refuses it" not in desc, desc
        accepted = "plan --execution --gravity palm_down accepts it" in desc
        assert accepted or "plan --execution --gravity palm_down refuses it" in desc, desc
        assert main(["check", "--execution", "--gravity", "palm_down", str(f), "--no-verify", "-q"]) == \
            (0 if accepted else 1)
        six_refuse_accepted += accepted and not execution_verdict(realize(load_grasp(f))).ok
    capsys.readouterr()
    assert six_refuse_accepted >= 1  # the case: held palm down, refused by the six directions


#: A 248 g box at a fixed pose where seed 7's three Allegro tripods all pass execution mode's
#: static test and pybullet holds only one of them (a sweep's case).
BOX_FIXED = {"shape": "box", "size": [0.045, 0.05, 0.04], "mass_kg": 0.248,
             "position": [0.04325045989462611, 0.0243281458090534, 1.3673054006738822e-05],
             "quat_xyzw": [0.5857513261918361, -0.6187787272205458, 0.49416079461293716, 0.17266551384493967]}


def test_synth_holds_its_grasps_in_a_physics_engine_and_ranks_those_that_drop_last(tmp_path, capsys):
    """synth's verdict is plan --execution's: the static test, then the grasp held in a physics
    engine as plan --execution holds an end grasp. Grasps that drop are ranked after those held,
    with the engine's verdict; check --execution agrees with each file; --no-verify says it
    judged by the static test alone."""
    from planner.sim.engine import default_engine

    obj = _object_file(tmp_path, BOX_FIXED, "box.yaml")
    args = ["allegro_right", obj, "--fingers", "thumb,index,middle", "-n", 3, "--seed", 7]
    assert _synth([*args, "-o", tmp_path / "static", "--no-verify"]) == 0
    static = capsys.readouterr().out.splitlines()
    assert all(line.endswith("execution-ready by the static test") for line in static[:3]), static
    assert _synth([*args, "-o", tmp_path / "held"]) == 0
    out = capsys.readouterr().out.splitlines()
    held = [" execution-ready, held in " in line for line in out[:3]]
    dropped = [" not for --execution as an initial grasp: does not hold in the simulator (" in line for line in out[:3]]
    assert all(h or d for h, d in zip(held, dropped)) and held == sorted(held, reverse=True), out
    assert out[3].endswith(f"held in a physics engine: {sum(held)} of the 3 the static test accepts")
    if default_engine() == "pybullet":
        assert sum(held) == 1, out  # (two drop palm down)
    for f, ok in zip(sorted((tmp_path / "held").glob("*.yaml")), held):
        desc = " ".join(yaml.safe_load(f.read_text())["description"].split())
        assert ("plan --execution accepts it (held in " in desc) == ok, desc
        assert main(["check", str(f), "--execution"]) == (0 if ok else 1)
        capsys.readouterr()
    static_desc = yaml.safe_load(sorted((tmp_path / "static").glob("*.yaml"))[0].read_text())["description"]
    assert "the static test of plan --execution accepts it" in " ".join(static_desc.split())


@pytest.mark.needs_pybullet("--engine both replays in pybullet and MuJoCo")
def test_synth_engine_both_names_each_engine_that_held(tmp_path, capsys):
    obj = _object_file(tmp_path, BOX_FIXED, "box.yaml")
    assert _synth(["allegro_right", obj, "--fingers", "thumb,index,middle", "-n", 3, "--seed", 7, "--engine", "both",
                   "-o", tmp_path / "out"]) == 0
    line = capsys.readouterr().out.splitlines()[0]
    assert line.endswith("execution-ready, held in pybullet and mujoco"), line


def test_synth_refuses_an_engine_it_cannot_replay_in_before_it_synthesizes(tmp_path, capsys, monkeypatch):
    """`synth --engine pybullet` where pybullet is not installed (Python 3.12+), or an engine
    name the API does not know: the whole synthesis ran (minutes), then the replay failed and
    nothing was written. Refused at once, as plan --execution refuses it before its search; the
    API's ``verify`` must be True or False ("no" replayed)."""
    import planner
    import planner.sim.engine as engine
    import planner.synthesis as synthesis

    def no_attempt(*_a, **_k):
        raise AssertionError("synthesized before the engine was checked")

    monkeypatch.setattr(synthesis, "_outcomes", no_attempt)
    monkeypatch.setattr(engine, "engine_installed", lambda name: name == "mujoco")
    obj = _object_file(tmp_path, BALL)
    assert _synth(["icub_right", obj, "--fingers", "thumb,index,middle", "--engine", "pybullet", "-o", tmp_path / "g"]) == 2
    err = capsys.readouterr().err
    assert "physics engine 'pybullet' is not installed" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "g").exists()
    with pytest.raises(planner.PlannerError, match="unknown physics engine 'pybulet'"):
        planner.synth("icub_right", BALL, "thumb,index,middle", engine="pybulet")
    with pytest.raises(planner.PlannerError, match="verify must be True or False"):
        planner.synth("icub_right", BALL, "thumb,index,middle", verify="no")


@pytest.mark.needs_pybullet("which of the grasps pybullet drops")
def test_synth_gravity_name_is_said_in_a_replays_verdict(tmp_path, capsys):
    """synth --gravity palm_down: a grasp the simulator drops names the direction as given, not
    "gravity"; its file says plan --execution refuses it as an initial grasp (the replay is that
    test; a plan arriving at it may still end in it)."""
    obj = _object_file(tmp_path, BOX_FIXED, "box.yaml")
    assert _synth(["allegro_right", obj, "--fingers", "thumb,index,middle", "-n", 3, "--seed", 7,
                   "--gravity", "palm_down", "-o", tmp_path / "out"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert " not for --execution as an initial grasp: does not hold in the simulator (palm_down: pybullet: " in out[1]
    desc = " ".join(yaml.safe_load(sorted((tmp_path / "out").glob("*.yaml"))[1].read_text())["description"].split())
    assert "plan --execution --gravity palm_down refuses it as an initial grasp: does not hold in the simulator " \
           "(palm_down: " in desc and desc.endswith("; a plan arriving at it may still end in it")


def test_synth_help_says_the_replay_is_how_a_plan_tests_an_initial_grasp(capsys):
    """synth --no-verify's help said the grasps are held 'as plan --execution holds its end
    grasps', the wording this session took back from check (a plan arriving at a grasp that
    drops when held alone may still end in it: the iCub pen pose); it says as check's does."""
    with pytest.raises(SystemExit):
        main(["synth", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "holds its end grasps" not in text
    assert "as plan --execution replays an initial grasp" in text
