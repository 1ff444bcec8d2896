"""Hardening (issue 17): no input loses data, hangs or ends in a traceback; plans prove
their integrity. Every case is a small generated input: the command exits 2 (bad input),
1 or 130 with exactly one stderr line naming the key, and no input file changes."""

import contextlib
import errno
import hashlib
import json
import math
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from planner.cli import main
from planner.model import Friction
from planner.closure import closure_from_wrenches, contact_wrenches, grasp_closure
from planner.errors import InputError, OutputError, PlannerWarning, SpecError
from planner.plan import plan_from_data, read_plan
from planner.plan_data import dumps_plan, write_plan

ROOT = Path(__file__).resolve().parent.parent
BOX_PE = ROOT / "grasps/icub/box_parallel_extension.yaml"
BOX_IR2M = ROOT / "grasps/icub/box_ir2m.yaml"


def _sha(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _run(capsys, *argv) -> tuple[int, list[str]]:
    """main(argv) in-process: (exit code, stderr lines)."""
    try:
        code = main([str(a) for a in argv])
    except SystemExit as stop:  # argparse
        code = stop.code
    return code, capsys.readouterr().err.strip().splitlines()


@pytest.fixture()
def grasps(tmp_path):
    """Copies of the box pair in tmp_path: (initial, final)."""
    a, b = tmp_path / "a.yaml", tmp_path / "b.yaml"
    shutil.copy(BOX_PE, a)
    shutil.copy(BOX_IR2M, b)
    return a, b


# ------------------------------------------------------------------ 1. data loss


def test_output_onto_an_input_is_refused_before_any_work(tmp_path, grasps, capsys):
    """-o naming an input, a symlink or a hard link to it: exit 2, one line, input unchanged."""
    a, b = grasps
    before = _sha(b)
    (tmp_path / "link.yaml").symlink_to(b)
    os.link(b, tmp_path / "hard.yaml")
    for out in (b, tmp_path / "link.yaml", tmp_path / "hard.yaml", tmp_path / "sub" / ".." / "b.yaml"):
        code, err = _run(capsys, "plan", a, b, "-o", out, "--no-motion")
        assert code == 2 and len(err) == 1 and "refusing to overwrite an input" in err[0], err
    assert _sha(b) == before


def test_bad_output_locations_are_one_line(tmp_path, grasps, capsys):
    """-o onto a directory or under a regular file: exit 2, one line naming -o; nothing written."""
    a, b = grasps
    (tmp_path / "file").write_text("x")
    for out, why in ((tmp_path, "is a directory"), (tmp_path / "file" / "p.yaml", "is not a directory")):
        code, err = _run(capsys, "plan", a, b, "-o", out, "--no-motion")
        assert code == 2 and len(err) == 1 and "-o" in err[0] and why in err[0], err
    code, err = _run(capsys, "replay", tmp_path / "p.yaml", "--report", tmp_path / "p.yaml")
    assert code == 2 and len(err) == 1 and "--report" in err[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.yaml", "b.yaml", "file"]


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only directories")
def test_read_only_directory_is_refused(tmp_path, grasps, capsys):
    """-o into a read-only directory: exit 2 before any work."""
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        code, err = _run(capsys, "plan", *grasps, "-o", ro / "p.yaml", "--no-motion")
    finally:
        ro.chmod(0o755)
    assert code == 2 and len(err) == 1 and "not writable" in err[0]


def test_full_disk_leaves_the_old_file_and_no_temp(tmp_path, monkeypatch):
    """A write that fails (ENOSPC) is an OutputError; the old plan is untouched, no temp file."""
    from planner.plan_data import Plan  # noqa: F401 - the tiny plan of test_plan

    sys.path.insert(0, str(Path(__file__).parent))
    from test_plan import tiny_plan

    target = write_plan(tiny_plan(), tmp_path / "plan.yaml")
    before = target.read_bytes()

    def full(_fd):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "fsync", full)
    with pytest.raises(OutputError, match="No space left"):
        write_plan(tiny_plan(), target)
    assert target.read_bytes() == before and [p.name for p in tmp_path.iterdir()] == ["plan.yaml"]


# ------------------------------------------------------------------ 2. plan integrity


def _tiny(tmp_path, name="plan.yaml"):
    sys.path.insert(0, str(Path(__file__).parent))
    from test_plan import tiny_plan

    return write_plan(tiny_plan(), tmp_path / name)


def test_plan_truncated_at_any_line_is_refused(tmp_path):
    """Cut after every line (still valid YAML for most cuts): read_plan always refuses."""
    path = _tiny(tmp_path)
    lines = path.read_text().splitlines(keepends=True)
    cut = tmp_path / "cut.yaml"
    for n in range(len(lines)):
        cut.write_text("".join(lines[:n]))
        with pytest.raises(SpecError):
            read_plan(cut)
    read_plan(path)  # the whole file reads


@pytest.mark.parametrize("edit, key", [
    (lambda d: d["states"][0]["closure"].update(is_force_closure=not d["states"][0]["closure"]["is_force_closure"]),
     "states[0].closure"),
    (lambda d: d["states"][0]["patches"]["a"]["normals"][0].__setitem__(2, 1.0), "states[0].closure"),
    (lambda d: d["states"][1]["patches"].update(b=d["states"][0]["patches"]["b"]), "steps[0].action"),
    (lambda d: d["steps"][0].update(from_state=1, to_state=0), "steps[0].from_state"),
    (lambda d: d["states"].pop(), "steps"),
    (lambda d: d["inputs"].update(x={"path": "x.yaml", "sha256": "1" * 64}), "integrity.sha256"),
    (lambda d: d["object"].update(mass_kg=1.0), "integrity.sha256"),
    (lambda d: d["integrity"].update(states=5), "states"),
])
def test_altered_plan_is_refused_naming_what_does_not_match(tmp_path, edit, key):
    """A flipped closure or normal, a finger put back, steps out of order, a state dropped, an
    edited input or mass, a wrong count: IntegrityError/SpecError naming the key."""
    data = yaml.safe_load(_tiny(tmp_path).read_text())
    edit(data)
    path = tmp_path / "edited.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    with pytest.raises(SpecError) as err:
        read_plan(path)
    assert err.value.key == key, str(err.value)


def test_replay_refuses_an_altered_plan_with_one_line(tmp_path, capsys):
    """regrasp replay on an edited plan: exit 2, one line, before pybullet starts."""
    path = _tiny(tmp_path)
    text = path.read_text()
    assert "gait_steps: 1" in text
    path.write_text(text.replace("gait_steps: 1", "gait_steps: 2", 1))
    code, err = _run(capsys, "replay", path)
    assert code == 2 and len(err) == 1 and "sha256" in err[0] and str(path) in err[0]


def test_inputs_are_relative_changed_or_missing_inputs_warn(tmp_path, grasps):
    """Inputs are written relative to the plan (a moved folder gives the same bytes); a changed
    input is a warning, or an IntegrityError-free SpecError with strict."""
    sys.path.insert(0, str(Path(__file__).parent))
    from test_plan import tiny_plan

    a, b = grasps
    plan = tiny_plan()
    plan = type(plan)(**{**plan.__dict__, "inputs": {"initial": {"path": str(a), "sha256": _sha(a)}}})
    path = write_plan(plan, tmp_path / "out" / "plan.yaml")
    assert "path: ../a.yaml" in path.read_text() and str(tmp_path) not in path.read_text()
    with __import__("warnings").catch_warnings():
        __import__("warnings").simplefilter("error")
        read_plan(path)  # unchanged input: no warning
    moved = tmp_path.parent / (tmp_path.name + "_moved")
    shutil.copytree(tmp_path, moved)
    assert (moved / "out" / "plan.yaml").read_bytes() == path.read_bytes()
    a.write_text(a.read_text() + "\n# edited\n")
    with pytest.warns(PlannerWarning, match="inputs.initial: .*changed"):
        read_plan(path)
    with pytest.raises(SpecError, match="changed since planning"):
        read_plan(path, strict=True)
    a.unlink()
    with pytest.warns(PlannerWarning, match="is gone"):
        read_plan(path)
    shutil.rmtree(moved)


def test_mesh_mass_is_recorded_as_the_planner_used_it(tmp_path):
    """A mesh object without mass_kg is recorded with volume x 500 kg/m^3 (what make_object
    uses), not left null for the replay to guess."""
    from planner.objects import DEFAULT_DENSITY_KG_M3, make_object

    sys.path.insert(0, str(Path(__file__).parent))
    from test_plan import tiny_plan

    mesh = ROOT / "grasps/meshes/rounded_box.obj"
    plan = tiny_plan()
    obj = {"shape": "mesh", "size": [1.0], "position": [0, 0, 0.05], "quat_xyzw": [0, 0, 0, 1], "mesh": str(mesh)}
    plan = type(plan)(**{**plan.__dict__, "object": obj})
    expect = DEFAULT_DENSITY_KG_M3 * make_object("mesh", [1.0], mesh_path=mesh).volume_m3
    assert plan.object.mass_kg == pytest.approx(expect) and expect > 0
    written = write_plan(plan, tmp_path / "p.json")
    back = read_plan(written)
    assert back.object.mass_kg == pytest.approx(expect, rel=1e-9)
    assert json.loads(written.read_text())["object"]["mesh"] == os.path.relpath(mesh, tmp_path)  # relative in the file
    assert back.object.mesh_path == str(mesh)


# ------------------------------------------------------------------ 3/4. bounds and bad values


@pytest.mark.parametrize("where, bad", [
    ("q", float("nan")), ("q", float("inf")), ("q", "x"), ("q", None), ("q", 1e6),
    ("path", float("nan")), ("path", "x"), ("path", None), ("path", 1e6),
])
def test_bad_joint_values_are_refused_naming_the_key(where, bad):
    """NaN, inf, strings, null and out-of-range joint values in states or paths: SpecError
    naming the exact key."""
    sys.path.insert(0, str(Path(__file__).parent))
    from test_plan import tiny_plan

    data = tiny_plan().to_dict()
    if where == "q":
        data["states"][1]["q"]["ja"], key = bad, "states[1].q.ja"
    else:
        data["steps"][0]["path"][1][0], key = bad, "steps[0].path[1][0]"
    with pytest.raises(SpecError) as err:
        plan_from_data(data, "p.yaml")
    assert err.value.key == key


def test_huge_plans_and_nan_object_are_refused():
    """200 000 waypoints, a NaN object position or a zero size: refused, naming the key (timings
    of such refusals belong to benchmarks, not tests)."""
    sys.path.insert(0, str(Path(__file__).parent))
    from test_plan import tiny_plan

    data = tiny_plan().to_dict()
    data["steps"][0]["path"] = [[0.2]] * 200_000
    with pytest.raises(SpecError, match=r"steps\[0\]\.path: expected 0 to 10000"):
        plan_from_data(data)
    for key, value in (("position", [float("nan"), 0, 0]), ("size", [0.0, 0.04, 0.05])):
        data = tiny_plan().to_dict()
        data["object"][key] = value
        with pytest.raises(SpecError, match=f"object.{key}"):
            plan_from_data(data)


def test_nan_object_position_never_replays():
    """A plan whose object position is NaN is a bad-input error, never a PASS."""
    from planner.sim.replay import replay_plan

    sys.path.insert(0, str(Path(__file__).parent))
    from test_plan import tiny_plan

    data = tiny_plan().to_dict()
    data["object"]["position"] = [float("nan"), 0.0, 0.0]
    with pytest.raises(SpecError, match=r"object.position\[0\]"):
        replay_plan(data)


def test_closure_is_scale_invariant_and_rejects_bad_wrenches():
    """A force-closure set scaled by 1e-300..1e300 gives the same answer (metric scaled) at
    once; complex, NaN and inf wrenches and out-of-range friction are InputErrors."""
    rng = np.random.default_rng(3)
    p = 0.02 * rng.normal(size=(4, 3))
    W = contact_wrenches(p, -p, Friction(0.8, 0.002))
    ref = closure_from_wrenches(W)
    assert ref.is_force_closure
    for scale in (1e-300, 1e-150, 1e150, 1e300):
        c = closure_from_wrenches(W * scale)
        assert c.is_force_closure and c.rank == 6 and c.metric / scale == pytest.approx(ref.metric, rel=1e-9)
    for bad in (W.astype(complex) + 1e-3j, W * np.nan, np.where(W > 0, np.inf, W)):
        with pytest.raises(InputError):
            closure_from_wrenches(bad)
    for kw in (dict(mu=1e154, gamma=0.0), dict(mu=1.0, gamma=1e30), dict(mu=1.0, gamma=0.0, edges=10**10)):
        with pytest.raises(InputError, match=r"in \["):
            Friction(**kw)
    huge = grasp_closure({"a": (p, -p * 1e200)}, Friction(0.8, 0.002))  # normals are directions
    unit = grasp_closure({"a": (p, -p)}, Friction(0.8, 0.002))
    assert huge.is_force_closure == unit.is_force_closure and huge.metric == pytest.approx(unit.metric, rel=1e-12)


@pytest.mark.parametrize("argv, option", [
    (["--seed", "-1"], "--seed"), (["--alternatives", "1000000"], "--alternatives"),
    (["--intermediate", "1000"], "--intermediate"), (["--max-lifted", "-1"], "--max-lifted"),
    (["--motion-checks", "0"], "--motion-checks"),
])
def test_option_ranges_are_one_line(grasps, capsys, argv, option):
    """Out-of-range options: exit 2, one line naming the option and its valid range."""
    code, err = _run(capsys, "plan", *grasps, "--no-motion", *argv)
    assert code == 2 and len(err) == 1 and option in err[0] and "valid: " in err[0], err


def test_plan_options_api_checks_the_cli_ranges():
    """PlanOptions refuses what the CLI refuses, from the same table (PLAN_OPTION_LIMITS):
    each field just outside its range, the wrong type (a bool, a fraction for an integer, a
    string, NaN) is one InputError line naming the field and its valid range; each end of
    every range is accepted; the CLI's table holds every field under its option name."""
    from planner.cli import option_limits
    from planner.options import PLAN_OPTION_FLAGS, PLAN_OPTION_LIMITS, PlanOptions

    assert {PLAN_OPTION_FLAGS.get(k, k): v for k, v in PLAN_OPTION_LIMITS.items()}.items() <= option_limits().items()
    for name, (low, high, open_low) in PLAN_OPTION_LIMITS.items():
        step = 1 if isinstance(low, int) else 1e-9 * max(1.0, abs(high))
        wrap = (lambda v: (0.0, 0.0, v)) if name == "gravity" else (lambda v: v)
        ends = [high] + ([] if open_low else [low])
        for v in ends:
            assert getattr(PlanOptions(**{name: wrap(v)}), name) == wrap(v)
        bad = [high + step, low if open_low else low - step, True, float("nan"), "1"]
        bad += [0.5] if isinstance(low, int) else []
        for v in bad:
            with pytest.raises(InputError) as err:
                PlanOptions(**{name: wrap(v)})
            text = str(err.value)
            assert "\n" not in text and f"PlanOptions.{name} must be" in text, text
            assert f"{'(' if open_low else '['}{low}, {high}]" in text and repr(v) in text, text
    assert PlanOptions(max_lifted=None, gravity=None).max_lifted is None  # optional fields
    with pytest.raises(InputError, match="seed must be an integer"):
        PlanOptions(seed=None)


@pytest.mark.parametrize("name", ["motion", "execution", "verify", "repose"])
@pytest.mark.parametrize("value", ["no", 0, None], ids=["str", "int", "None"])
def test_plan_options_switches_must_be_bools(name, value):
    """PlanOptions' switches take True or False: ``motion="no"`` planned OMPL paths ("no" is
    truthy) and ``repose=None`` was taken as False; now one InputError naming the field."""
    from planner.options import PlanOptions

    with pytest.raises(InputError, match=f"^PlanOptions.{name} must be True or False, got {value!r}$"):
        PlanOptions(**{name: value})


@pytest.mark.parametrize("argv, words", [
    (["--no-verify"], "--no-verify: only with --execution"),
    (["--verify-attempts", "3"], "--verify-attempts: only with --execution"),
    (["--engine", "mujoco"], "--engine: only with --execution"),
    (["--execution", "--no-verify", "--verify-attempts", "3"], "--verify-attempts and --no-verify exclude each other"),
    (["--execution", "--no-verify", "--engine", "mujoco"], "--engine and --no-verify exclude each other"),
], ids=["no-verify", "attempts", "engine", "attempts-no-verify", "engine-no-verify"])
def test_plan_verification_options_without_a_verification_are_refused(tmp_path, grasps, capsys, argv, words):
    """The options of the verification in a physics engine without one (no --execution, or
    --no-verify): one line, exit 2, nothing written; they were ignored and e.g. `--engine mujoco`
    returned a plan verified in no engine."""
    code, err = _run(capsys, "plan", *grasps, "--no-motion", "-o", tmp_path / "p.yaml", *argv)
    assert code == 2 and len(err) == 1 and words in err[0], err
    assert not (tmp_path / "p.yaml").exists()


def test_replay_workers_without_a_gravity_set_is_refused(tmp_path, capsys):
    """`replay --workers N` without --gravity-set (one replay, in this process) is refused as
    --film is; it was ignored."""
    code, err = _run(capsys, "replay", _tiny(tmp_path), "--workers", "2")
    assert code == 2 and err == ["regrasp replay: error: --workers runs the directions of --gravity-set in parallel: "
                                 "give --gravity-set N too"]


def test_unknown_name_messages_say_the_plural():
    """"unknown strategy 'foo'; strategies are graph, greedy" (it said "strategys"; "finger with
    collision geometrys"), and `plan --gravity-set 3` names the option and its choices."""
    from planner.errors import UnknownNameError
    from planner.options import PlanOptions

    with pytest.raises(UnknownNameError, match="^unknown strategy 'foo'; strategies are graph, greedy$"):
        PlanOptions(strategy="foo")
    assert str(UnknownNameError("finger with collision geometry", "x", ["index"])) == (
        "unknown finger with collision geometry 'x'; fingers with collision geometry are index")
    assert str(UnknownNameError("hand", "x", ["a"])) == "unknown hand 'x'; hands are a"
    assert str(UnknownNameError("physics engine", "x", ["a"])).endswith("; physics engines are a")


def test_plan_gravity_set_names_the_option_and_choices(grasps, capsys):
    """`plan --gravity-set 3`: the option and its choices, as replay's (it was "gravity set size
    must be one of ..." without the option)."""
    code, err = _run(capsys, "plan", *grasps, "--gravity-set", "3")
    assert code == 2 and len(err) == 1 and "--gravity-set: invalid choice: 3 (choose from 1, 2, 6, 7)" in err[0], err


@pytest.mark.parametrize("option, words", [("--contact-model", "unknown contact model ''; contact models are link, mean, patch"),
                                           ("--rank", "unknown rank ''; ranks are grip, metric")])
def test_an_empty_choice_is_not_the_default(grasps, capsys, option, words):
    """`plan --contact-model ''` and `--rank ''` (an empty shell variable) are unknown names,
    listed with the choices; they planned with the defaults (patch, metric), silently."""
    code, err = _run(capsys, "plan", *grasps, "--no-motion", option, "")
    assert code == 2 and len(err) == 1 and err[0].endswith(words), err


def test_view_an_empty_report_name_is_refused(tmp_path, grasps, capsys):
    """`view --report ''`: one line naming --report and the empty name (it said
    '.: cannot read replay report: not a regular file')."""
    import planner

    plan = tmp_path / "plan.yaml"
    planner.plan(str(grasps[0]), str(grasps[1]), motion=False, output=plan)
    code, err = _run(capsys, "view", plan, "-o", tmp_path / "v.html", "--report", "")
    assert code == 2 and len(err) == 1 and "--report: expected a replay report" in err[0] and "empty file name" in err[0], err
    assert not (tmp_path / "v.html").exists()


def test_argparse_errors_are_one_line(capsys):
    """A missing argument or unknown option: exit 2 and one line, no usage block."""
    for argv in (["plan"], ["plan", "a.yaml", "b.yaml", "--bogus"], ["nope"]):
        code, err = _run(capsys, *argv)
        assert code == 2 and len(err) == 1 and "usage" not in err[0], err


def _malformed_grasps(tmp_path) -> dict:
    """Malformed variants of a bundled grasp written to tmp_path: name -> (path, expected
    words of the error). ``secret.txt`` is a non-YAML file a ``hand:`` path points at."""
    base = BOX_IR2M.read_text()
    bomb = "".join(f"l{i}: &l{i} [" + ",".join([f"*l{i - 1}" if i else "x"] * 9) + "]\n" for i in range(14))
    secret = tmp_path / "secret.txt"
    secret.write_text("root:hunter2:0:0\n: : [\n")
    cases = {
        "deep.yaml": (base + "extra: " + "[" * 1000 + "]" * 1000 + "\n", "nested deeper"),
        "int.yaml": (base.replace("edges: 5", "edges: " + "9" * 500), "integer longer"),
        "bomb.yaml": (base + bomb, "aliases"),
        "dup.yaml": (base.replace("friction: {mu: 0.9", "friction: {mu: -1, mu: 0.9"), "duplicate key 'mu'"),
        "big.yaml": (base + "#" * 2_000_000 + "\n", "at most 1000000 bytes"),
        "hand.yaml": (base.replace("hand: icub_right", f"hand: {secret}"), "hand spec"),
        "mu.yaml": (base.replace("mu: 0.9", "mu: 200.0"), "friction.mu: expected a number in (0, 100]"),
        "edges.yaml": (base.replace("edges: 5", "edges: 1000"), "friction.edges: expected an integer in [3, 256]"),
    }
    out = {}
    for name, (text, expect) in cases.items():
        assert text != base, name
        out[name] = (tmp_path / name, expect)
        out[name][0].write_text(text)
    return out


def test_malformed_grasp_files_are_one_line_without_content(tmp_path, capsys):
    """Deep nesting, a 1 MB integer, an alias bomb, duplicate keys, a 2 MB file, a hand: path
    pointing at a non-YAML secret, friction out of range: exit 2, one line, never the
    secret's content."""
    for name, (path, expect) in _malformed_grasps(tmp_path).items():
        code, err = _run(capsys, "check", path)
        assert code == 2 and len(err) == 1 and expect in err[0] and name in err[0], (name, err)
        assert "hunter2" not in err[0] and "root:" not in err[0]


def test_load_grasp_api_reads_within_the_same_bounds(tmp_path):
    """planner.grasp.load_grasp (no CLI in front) refuses the same malformed files with a
    SpecError naming the file; a friction value out of Friction's range names the
    file, the key and the range."""
    from planner.grasp import load_grasp

    for name, (path, expect) in _malformed_grasps(tmp_path).items():
        with pytest.raises(SpecError) as err:
            load_grasp(path)
        msg = str(err.value)
        assert msg.startswith(str(path)) and expect in msg and "\n" not in msg, (name, msg)
        assert "hunter2" not in msg
        if name in ("mu.yaml", "edges.yaml"):
            assert err.value.key == "friction." + name.removesuffix(".yaml")


@pytest.mark.parametrize("name, content, expect", [
    ("empty.stl", b"", "84-byte header"),
    ("tiny.stl", b"\0" * 40, "84-byte header"),
    ("short.stl", b"\0" * 80 + (1000).to_bytes(4, "little") + b"\0" * 50, "announces 1000"),
    ("range.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n", "not defined"),
    ("noface.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf\n", "at least 3"),
    ("none.obj", b"v 0 0 0\n", "no triangles"),
])
def test_malformed_meshes_are_input_errors(tmp_path, name, content, expect):
    """Empty, tiny and inconsistent STL/OBJ meshes: one InputError, no IndexError/struct.error."""
    from planner.objects import load_mesh

    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(InputError, match=expect):
        load_mesh(path)


# ------------------------------------------------------------------ interrupts, pipes, noise


def test_ctrl_c_is_one_line_and_exit_130(monkeypatch, grasps, capsys):
    """KeyboardInterrupt during a command: 'interrupted', exit 130, no traceback."""
    import planner.commands as commands

    def interrupted(_args):
        raise KeyboardInterrupt

    monkeypatch.setattr(commands, "cmd_check", interrupted)
    code, err = _run(capsys, "check", grasps[0])
    assert code == 130 and err == ["regrasp check: interrupted"]


def _state_and_parent(pid) -> tuple[str, int] | None:
    """A process's state letter and parent from /proc, None when it is gone."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except (OSError, ValueError):
        return None
    fields = stat[stat.rindex(")") + 2:].split()
    return fields[0], int(fields[1])


def _children(pid: int) -> list[int]:
    """The running processes whose parent is ``pid`` (zombies left out: they have exited)."""
    out = []
    for entry in Path("/proc").iterdir():
        info = _state_and_parent(entry.name) if entry.name.isdigit() else None
        if info is not None and info[1] == pid and info[0] != "Z":
            out.append(int(entry.name))
    return out


def _still_running(pids: list[int], within_s: float = 30.0) -> list[int]:
    """Those of ``pids`` still running (not ended, nor ended and awaiting their reaping) after
    up to ``within_s`` seconds: a process on its way out takes a moment on a loaded machine."""
    import time

    deadline = time.monotonic() + within_s
    while True:
        running = [p for p in pids if (_state_and_parent(p) or ("Z",))[0] != "Z"]
        if not running or time.monotonic() > deadline:
            return running
        time.sleep(0.05)


def _signal_a_plan(tmp_path, sig, ignore: bool = False) -> tuple[int, list[str]]:
    """Run `plan --execution -o p.yaml` until it has forked a process, send it ``sig``: (its exit
    code, its stderr lines), once every process it forked has ended. ``ignore``: the planner
    starts with ``sig`` ignored (as under ``nohup``)."""
    import signal
    import time

    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "PYTHONPATH": str(ROOT)}  # this checkout, from tmp_path
    proc = subprocess.Popen([sys.executable, "-m", "planner", "plan", str(ROOT / "grasps/icub/cylinder_parallel_extension.yaml"),
                             str(ROOT / "grasps/icub/cylinder_ir2m.yaml"), "--execution", "-o", "p.yaml"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=tmp_path, env=env,
                            start_new_session=True,
                            # (the test's own disposition is not inherited: a CI under nohup ignores SIGHUP)
                            preexec_fn=lambda: signal.signal(sig, signal.SIG_IGN if ignore else signal.SIG_DFL))
    try:
        deadline = time.monotonic() + 120
        while not _children(proc.pid) and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert _children(proc.pid), "the planner forked no process to check"
        forked = _children(proc.pid)
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=300)  # the pipes close: no forked process holds them
    finally:  # whatever is left of the session (the forked processes too, before the fix)
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    assert _still_running(forked) == []
    return proc.returncode, err.decode().strip().splitlines()


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads the process table in /proc")
def test_sigterm_is_one_line_exit_143_and_stops_the_forked_processes(tmp_path):
    """`kill PID` (SIGTERM, as `timeout` sends) during `plan --execution -o`: the processes it
    forked (the search's helper, the replays' workers) end with it instead of running on with
    the caller's pipes open, one line 'terminated', exit 143, no plan and no temporary file."""
    import signal

    code, lines = _signal_a_plan(tmp_path, signal.SIGTERM)
    assert code == 143 and lines == ["regrasp plan: terminated"]
    assert sorted(p.name for p in tmp_path.iterdir()) == []


@pytest.mark.skipif(not Path("/proc/self/stat").exists() or not hasattr(os, "register_at_fork"),
                    reason="reads the process table in /proc")
def test_a_hangup_unwinds_as_sigterm_and_nohup_runs_on(tmp_path):
    """SIGHUP (the terminal or ssh session closed) during `plan --execution -o`: the command
    unwinds as on SIGTERM (its forked processes end, no plan, no temporary file), exit 129; it
    died of the signal at once, saying nothing. Started with SIGHUP ignored (``nohup``) it runs
    on and writes its plan."""
    import signal

    hup, nohup = tmp_path / "hup", tmp_path / "nohup"
    hup.mkdir()
    nohup.mkdir()
    code, lines = _signal_a_plan(hup, signal.SIGHUP)
    assert code == 129 and lines == ["regrasp plan: hung up (the terminal closed)"]
    assert list(hup.iterdir()) == []
    code, lines = _signal_a_plan(nohup, signal.SIGHUP, ignore=True)
    assert code == 0 and lines == [] and [p.name for p in nohup.iterdir()] == ["p.yaml"]


def _workers_end_with_their_command(tmp_path, argv) -> None:
    """Run ``regrasp ARGV`` until it has two worker processes, SIGKILL it: its workers end too
    and the caller's pipes close (`communicate` returns)."""
    import signal
    import time

    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-m", "planner", *map(str, argv)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, cwd=tmp_path, env=env, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while len(_children(proc.pid)) < 2 and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        workers = _children(proc.pid)
        assert len(workers) >= 2, "the command started no worker processes to check"
        proc.kill()
        proc.communicate(timeout=60)  # returns once no worker holds the pipes
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    assert _still_running(workers) == []


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads the process table in /proc")
def test_replay_and_synth_workers_end_when_their_command_is_killed(tmp_path):
    """SIGKILL (or the OOM killer) of `replay --gravity-set 7` or `synth --workers 2`: their
    worker processes end too (Linux's parent-death signal) and the caller's pipes close; they
    waited for ever, each on a pipe its siblings kept open."""
    import planner

    plan = tmp_path / "plan.yaml"
    planner.plan(str(BOX_PE), str(BOX_IR2M), motion=False, output=plan)
    _workers_end_with_their_command(tmp_path, ["replay", plan, "--gravity-set", "7", "--workers", "2"])
    (tmp_path / "ball.yaml").write_text("shape: sphere\nsize: [0.015]\nmass_kg: 0.03\n")
    _workers_end_with_their_command(tmp_path, ["synth", "icub_right", "ball.yaml", "-n", "200", "-o", "out",
                                               "--workers", "2", "-q"])


def test_closed_stdout_is_quiet():
    """`regrasp check --json | head -1`: no BrokenPipeError traceback, exit 141 like Unix tools."""
    proc = subprocess.Popen([sys.executable, "-m", "planner", "check", str(BOX_IR2M), "--json"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=ROOT)
    proc.stdout.readline()
    proc.stdout.close()
    err = proc.stderr.read().decode()
    proc.wait(timeout=60)
    assert proc.returncode in (0, 141) and "Traceback" not in err and err == ""


@pytest.mark.parametrize("argv", [
    ["check", str(BOX_IR2M), "--json"],
    ["plan", str(ROOT / "grasps/icub/cylinder_parallel_extension.yaml"), str(ROOT / "grasps/icub/cylinder_ir2m.yaml"),
     "--no-motion"],
], ids=["check-json", "plan"])
def test_stdout_closed_before_the_first_line_is_quiet(argv):
    """`regrasp check --json | head -1` and `regrasp plan ... | head -1` when the reader is gone
    before the command prints (the worst case, whatever the buffering): exit 141 (128 +
    SIGPIPE), nothing on stderr."""
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        proc = subprocess.run([sys.executable, "-m", "planner", *argv], stdout=write_end, stderr=subprocess.PIPE,
                              cwd=ROOT, timeout=120)
    finally:
        os.close(write_end)
    assert proc.returncode == 141 and proc.stderr.decode() == ""


def test_plan_is_written_even_when_the_reader_is_gone(tmp_path):
    """`regrasp plan A B -o p.yaml | head -1`: the plan is on disk (and whole) although the
    table could not be printed."""
    from planner.plan import read_plan

    read_end, write_end = os.pipe()
    os.close(read_end)
    out = tmp_path / "p.yaml"
    try:
        proc = subprocess.run([sys.executable, "-m", "planner", "plan", str(ROOT / "grasps/icub/cylinder_parallel_extension.yaml"),
                               str(ROOT / "grasps/icub/cylinder_ir2m.yaml"), "--no-motion", "-o", str(out)],
                              stdout=write_end, stderr=subprocess.PIPE, cwd=ROOT, timeout=120)
    finally:
        os.close(write_end)
    assert proc.returncode == 141 and proc.stderr.decode() == ""
    assert len(read_plan(out).states) > 1


@pytest.mark.needs_pybullet("pictures (planner.sim.film loads the pybullet renderer)")
def test_gif_is_written_atomically(tmp_path, monkeypatch):
    """`film.write_gif` (`regrasp view --gif`, `regrasp replay --gif`): a save that fails
    half-way (disk full) leaves the old GIF and no temporary file."""
    from PIL import Image

    from planner.sim.film import write_gif

    frames = [np.full((8, 8, 3), v, np.uint8) for v in (0, 128, 255)]
    gif = write_gif(frames, tmp_path / "film.gif")
    before = gif.read_bytes()
    assert before[:6] == b"GIF89a"

    def full(self, fp, *args, **kwargs):
        Path(fp).write_bytes(b"GIF89a half")
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(Image.Image, "save", full)
    with pytest.raises(OutputError, match="No space left"):
        write_gif(frames[::-1], gif)
    assert gif.read_bytes() == before and [p.name for p in tmp_path.iterdir()] == ["film.gif"]


def test_library_chatter_and_warnings_stay_off_stderr(capsys, grasps, monkeypatch):
    """C-level writes to fd 2 and numpy RuntimeWarnings during a command are dropped; a
    PlannerWarning is one 'warning:' line."""
    import warnings

    import planner.commands as commands

    def noisy(_args):
        os.write(2, b"urdfdom: some chatter\n")
        np.log(np.zeros(1))  # RuntimeWarning: divide by zero
        warnings.warn("input changed", PlannerWarning)
        raise InputError("bad thing")

    monkeypatch.setattr(commands, "cmd_check", noisy)
    code, err = _run(capsys, "check", grasps[0])
    assert code == 2 and err == ["regrasp check: warning: input changed", "regrasp check: error: bad thing"]


def test_plan_export_stays_byte_deterministic(tmp_path):
    """The integrity record is part of the deterministic bytes: same plan, same file."""
    a, b = _tiny(tmp_path, "a.yaml"), _tiny(tmp_path, "b.yaml")
    assert a.read_bytes() == b.read_bytes()
    assert dumps_plan(yaml.safe_load(a.read_text())) == a.read_text()
    assert math.isfinite(read_plan(a).states[0].metric)


# ------------------------------------------------------------------ replay --strict, setup, names


def test_replay_strict_refuses_changed_or_missing_inputs(tmp_path, grasps, capsys):
    """`regrasp replay --strict` (alone and with --gravity-set): a plan whose recorded input
    changed or is gone is exit 2 and one line naming inputs.<name>, before pybullet starts;
    the plan file is untouched."""
    sys.path.insert(0, str(Path(__file__).parent))
    from test_plan import tiny_plan

    a, _ = grasps
    plan = tiny_plan()
    plan = type(plan)(**{**plan.__dict__, "inputs": {"initial": {"path": str(a), "sha256": _sha(a)}}})
    path = write_plan(plan, tmp_path / "plan.yaml")
    before = _sha(path)
    a.write_text(a.read_text() + "# edited\n")
    for problem in ("changed since planning", "is gone"):
        for extra in ([], ["--gravity-set", "2"]):
            code, err = _run(capsys, "replay", path, "--strict", *extra)
            assert code == 2 and len(err) == 1, err
            assert "inputs.initial" in err[0] and problem in err[0] and "error:" in err[0], err
        a.unlink(missing_ok=True)
    assert _sha(path) == before


def test_final_grasp_with_another_mass_is_refused(grasps, capsys):
    """A final grasp whose object.mass_kg differs from the initial's (another number, or none:
    volume x density) is exit 2, one line naming object.mass_kg and both values; it was
    silently planned with the first. The unchanged pair passes check_same_setup."""
    from planner.grasp import load_grasp
    from planner.regrasp import check_same_setup

    a, b = grasps
    check_same_setup(load_grasp(a), load_grasp(b))
    text = b.read_text()
    assert "mass_kg: 0.04" in text
    for edited, shown in ((text.replace("mass_kg: 0.04", "mass_kg: 0.05"), "0.04 vs 0.05"),
                          (text.replace("mass_kg: 0.04", ""), "0.04 vs None")):
        b.write_text(edited)
        code, err = _run(capsys, "plan", a, b, "--no-motion")
        assert code == 2 and len(err) == 1 and "object.mass_kg" in err[0] and shown in err[0], err
        with pytest.raises(SpecError) as info:
            check_same_setup(load_grasp(b), load_grasp(a))  # either order
        assert info.value.key == "object.mass_kg"


def test_a_final_grasp_writing_the_same_orientation_with_the_other_quaternion_sign_shares_the_pose():
    """q and -q are one orientation: a final grasp whose object quaternion is the initial's
    negated shares the initial's pose (it was refused as another pose, naming
    object.quat_xyzw); another orientation does not."""
    from dataclasses import replace

    from planner.grasp import load_grasp
    from planner.regrasp import check_same_setup
    from planner.resources import bundled_grasp

    a, b = (load_grasp(bundled_grasp(n)) for n in ("icub/box_parallel_extension.yaml", "icub/box_ir2m.yaml"))
    x, y, z, w = 0.0, 0.0, math.sin(0.2), math.cos(0.2)
    a, b = (replace(g, object=g.object.replaced(quat_xyzw=(x, y, z, w))) for g in (a, b))
    check_same_setup(a, b, pose=True)
    check_same_setup(a, replace(b, object=b.object.replaced(quat_xyzw=(-x, -y, -z, -w))), pose=True)
    with pytest.raises(SpecError) as info:
        check_same_setup(a, replace(b, object=b.object.replaced(quat_xyzw=(x, y, -z, w))), pose=True)
    assert info.value.key == "object.quat_xyzw"


@pytest.mark.parametrize("old, new, expect", [
    ('<sphere radius="0.0065"/>', '<sphere radius="-0.0065"/>', "collision sphere radius must be > 0, got -0.0065"),
    ('<cylinder radius="0.0065" length="0.0103"/>', '<cylinder radius="0.0065" length="0"/>',
     "collision cylinder length must be > 0, got 0"),
    ('<box size="0.079 0.067 0.03"/>', '<box size="0.079 -0.067 0.03"/>', "collision box size must be > 0, got 0.079 -0.067"),
    ('<cylinder radius="0.0065" length="0.022"/>', '<cylinder radius="0.0065" length="-0.022"/>', "length must be > 0, got -0.022"),
])
def test_urdf_with_a_non_positive_size_is_refused_when_the_hand_loads(tmp_path, grasps, capsys, old, new, expect):
    """A negative or zero radius/length/size in a URDF collision shape (pinocchio and coal
    accept them): the hand does not load; the message names the URDF, the link and the
    attribute; `regrasp check` on a grasp of that hand is exit 2 and one line."""
    from planner.hand import Hand

    src = ROOT / "robots/icub_right"
    urdf = (src / "icub_right.urdf").read_text()
    assert old in urdf
    hand_dir = tmp_path / "hand"
    hand_dir.mkdir()
    shutil.copy(src / "hand.yaml", hand_dir / "hand.yaml")
    (hand_dir / "icub_right.urdf").write_text(urdf.replace(old, new, 1))
    with pytest.raises(SpecError) as err:
        Hand.load(hand_dir)
    msg = str(err.value)
    assert err.value.key == "urdf" and str(hand_dir / "icub_right.urdf") in msg and "link '" in msg and expect in msg, msg
    a = grasps[0]
    a.write_text(a.read_text().replace("hand: icub_right", f"hand: {hand_dir}"))
    code, lines = _run(capsys, "check", a)
    assert code == 2 and len(lines) == 1 and expect in lines[0], lines


@pytest.mark.parametrize("bad", ["\n", "\r", "\x0b", "\x0c", "\x1c", "\x85", "\u2028", "\x1b[2J", "\t", "\0"])
def test_control_characters_in_names_do_not_split_the_line(tmp_path, capsys, bad):
    """A file name, a YAML key or a command-line value holding a line break or another
    control character (form feed, escape, U+2028...) is shown escaped: the error stays one
    line (also by str.splitlines, which splits at more than newline) and holds no control
    character."""
    base = BOX_IR2M.read_text()
    key = f"in{bad}dex"
    cases = [
        (["check", tmp_path / "key.yaml"], base.replace("  index:  {posture", f'  "{key.encode("unicode_escape").decode()}":  {{posture')),
        (["plan", BOX_IR2M, BOX_IR2M, f"--bo{bad}gus"], None),
    ]
    if bad != "\0":  # never in a file name
        cases.append((["check", tmp_path / f"no{bad}such.yaml"], None))
        cases.append((["check", tmp_path / f"bad{bad}name.yaml"], base.replace("mu: 0.9", "mu: -1")))
    for argv, text in cases:
        if text is not None:
            argv[1].write_text(text)
        code, err = _run(capsys, *argv)
        assert code == 2 and len(err) == 1, (argv, err)
        assert all(ch == " " or ch.isprintable() for ch in err[0]), (argv, err)
        assert "\\" in err[0], (argv, err)  # the character is shown, escaped


# ------------------------------------------------------------------ the malformed-input corpus

MALFORMED = ROOT / "tests/data/malformed"
#: Every file of tests/data/malformed and words its one error line must hold (the cases built
#: in code above are not repeated there: deep nesting, long integers, alias bombs and
#: duplicate keys in grasps, 2 MB files, a hand: path at a secret, bad friction, altered plans).
MALFORMED_EXPECT = {
    "grasp_empty.yaml": "expected a YAML mapping",
    "grasp_hand_missing.yaml": "no_such_hand/hand.yaml",
    "grasp_inf_size.yaml": "object.size[1]: expected a finite number",
    "grasp_latin1.yaml": "not UTF-8",
    "grasp_nan_position.yaml": "object.position[0]: expected a finite number",
    "grasp_posture_length.yaml": "fingers.index.posture: expected 4 numbers",
    "grasp_string_mu.yaml": "friction.mu: expected a number",
    "grasp_syntax.yaml": "malformed YAML at line 14",
    "grasp_unknown_finger.yaml": "unknown finger 'pinky'",
    "grasp_unknown_shape.yaml": "unknown shape 'torus'",
    "grasp_zero_quat.yaml": "object.quat_xyzw",
    "plan_alias_bomb.yaml": "aliases",
    "grasp_alias_72.yaml": "aliases expand to more than",
    "plan_deep_100k.json": "nesting",
    "plan_bad.json": "not valid JSON",
    "plan_binary.yaml": "not UTF-8",
    "plan_deep.json": "nesting",
    "plan_empty.yaml": "expected a mapping",
    "plan_inf_metric.yaml": "states[0].closure.metric",
    "plan_list.yaml": "expected a mapping",
    "plan_nan_position.yaml": "object.position[0]",
    "plan_schema_99.yaml": "unsupported plan version 99",
    "plan_step_out_of_range.yaml": "steps[0].to_state",
    "plan_truncated.yaml": "missing key",
    "plan_truncated_steps.yaml": "integrity",
}


def test_the_malformed_corpus_is_listed_whole():
    """Every corpus file has its expectation (a file added without one would not be run)."""
    assert sorted(p.name for p in MALFORMED.iterdir()) == sorted(MALFORMED_EXPECT)


@pytest.mark.parametrize("name", sorted(MALFORMED_EXPECT))
def test_malformed_corpus_file_is_one_line_exit_2(name, capsys):
    """`regrasp check` on each malformed grasp and `regrasp replay` on each malformed plan of
    tests/data/malformed: exit 2, exactly one stderr line naming the file and the problem,
    no traceback, the file's bytes unchanged."""
    path = MALFORMED / name
    before = _sha(path)
    code, err = _run(capsys, "check" if name.startswith("grasp_") else "replay", path)
    assert code == 2 and len(err) == 1, err
    assert name in err[0] and MALFORMED_EXPECT[name] in err[0] and "Traceback" not in err[0], err
    assert _sha(path) == before


def test_replay_gravity_set_gif_names_may_not_be_inputs(tmp_path, capsys):
    """With --gravity-set the GIF is one file per direction (FILE_<direction>.gif): a plan
    named like one of them is refused before any simulation (exit 2, one line), and stays a plan."""
    from planner.cli import main

    plan = tmp_path / "q_palm_down.json"
    shutil.copy(ROOT / "tests" / "data" / "plans" / "schema2_cylinder_execution.json", plan)
    before = plan.read_bytes()
    assert main(["replay", str(plan), "--gravity-set", "1", "--gif", str(tmp_path / "q.json")]) == 2
    err = [line for line in capsys.readouterr().err.strip().splitlines() if "warning:" not in line]
    assert len(err) == 1 and "--gif" in err[0] and "input" in err[0], err
    assert plan.read_bytes() == before


def test_synth_never_overwrites_a_file_named_like_its_temporary(tmp_path):
    """synth writes through a temporary file of its own: a user's FILE.yaml.tmp next to the
    output is left as it was, and no temporary file remains."""
    from planner.synthesis import output_names, synthesize, write_grasps

    r = synthesize("icub_right", {"shape": "sphere", "size": [0.02], "mass_kg": 0.03}, ["thumb", "index", "middle"], 1,
                   fixed=False, seed=0, max_attempts=60)
    assert r.grasps
    out = tmp_path / "out"
    out.mkdir()
    (first,) = output_names(out, "icub_right", "sphere", 1)
    mine = first.with_name(first.name + ".tmp")  # the name the temporary file used to have
    mine.write_text("mine\n")
    paths = write_grasps(r, out, "icub_right", seed=0, fingers=["thumb", "index", "middle"])
    assert mine.read_text() == "mine\n" and all(p.exists() for p in paths)
    assert sorted(p.name for p in out.iterdir()) == sorted([mine.name] + [p.name for p in paths])


def test_an_output_in_a_folder_that_does_not_exist_is_refused(tmp_path, capsys):
    """-o into a missing folder (a typo) is one line, exit 2, and no folder is made."""
    from planner.cli import main
    from planner.resources import bundled_grasp

    a, b = (bundled_grasp(n) for n in ("icub/box_parallel_extension.yaml", "icub/box_ir2m.yaml"))
    out = tmp_path / "nonexistent" / "dir" / "p.yaml"
    assert main(["plan", str(a), str(b), "--no-motion", "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "does not exist" in err and "-o" in err
    assert not (tmp_path / "nonexistent").exists()


def test_replay_of_a_gravity_set_warns_once_about_a_changed_input(tmp_path, capsys):
    """A plan whose input grasp changed since planning replays with one warning line naming
    the input, also with --gravity-set (the plan file is read once)."""
    import shutil

    from planner.cli import main
    from planner.resources import bundled_grasp

    for name, new in (("icub/box_parallel_extension.yaml", "a.yaml"), ("icub/box_ir2m.yaml", "b.yaml")):
        shutil.copy(bundled_grasp(name), tmp_path / new)
    plan = tmp_path / "p.json"
    assert main(["plan", str(tmp_path / "a.yaml"), str(tmp_path / "b.yaml"), "--execution", "--no-verify", "--no-motion",
                 "--gravity-set", "1", "-o", str(plan)]) == 0
    with open(tmp_path / "a.yaml", "a") as fh:
        fh.write("# edited\n")
    capsys.readouterr()
    main(["replay", str(plan), "--gravity-set", "1"])
    warned = [line for line in capsys.readouterr().err.splitlines() if "warning:" in line]
    assert len(warned) == 1 and "inputs.initial" in warned[0] and "changed since planning" in warned[0]


# ------------------------------------------------------------------ synth, view, hand (issue 28)


def test_synth_bad_inputs_are_one_line_before_any_work(tmp_path, capsys):
    """Each: exit 2, one line naming the problem, nothing written, inputs unchanged."""
    ball = tmp_path / "ball.yaml"
    ball.write_text("shape: sphere\nsize: [0.02]\n")
    (tmp_path / "deep.yaml").write_text("shape: sphere\nsize: " + "[" * 1000 + "]" * 1000 + "\n")
    (tmp_path / "bigint.yaml").write_text("shape: sphere\nsize: [" + "9" * 5000 + "]\n")
    (tmp_path / "flat.stl").write_text("solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n"
                                       "vertex 0 1 0\nendloop\nendfacet\nendsolid x\n")
    (tmp_path / "flat.yaml").write_text("shape: mesh\nsize: [1, 1, 1]\nmesh: flat.stl\n")
    (tmp_path / "regular").write_text("a user's file\n")
    (tmp_path / "loop1").symlink_to("loop2")
    (tmp_path / "loop2").symlink_to("loop1")
    fingers = ["--fingers", "thumb,index", "-n", "1"]
    cases = {
        "deep": (["icub_right", "deep.yaml", *fingers, "-o", "o"], "nested deeper"),
        "bigint": (["icub_right", "bigint.yaml", *fingers, "-o", "o"], "integer longer"),
        "flat mesh": (["icub_right", "flat.yaml", *fingers, "-o", "o"], "flat"),
        "-o a file": (["icub_right", "ball.yaml", *fingers, "-o", "regular"], "not a folder"),
        "-o under a file": (["icub_right", "ball.yaml", *fingers, "-o", "regular/sub"], "is a file"),
        "-o in no folder": (["icub_right", "ball.yaml", *fingers, "-o", "nodir/sub"], "does not exist"),
        "symlink loop hand": (["./loop1", "ball.yaml", *fingers, "-o", "o"], "loop"),
        "finger twice": (["icub_right", "ball.yaml", "--fingers", "thumb,thumb,index", "-n", "1", "-o", "o"], "twice"),
        "attempts 0": (["icub_right", "ball.yaml", *fingers, "--max-attempts", "0", "-o", "o"], "--max-attempts"),
        "attempts -5": (["icub_right", "ball.yaml", *fingers, "--max-attempts", "-5", "-o", "o"], "--max-attempts"),
        "n huge": (["icub_right", "ball.yaml", "--fingers", "thumb,index", "-n", "1000000000", "-o", "o"], "-n must"),
        "object /dev/zero": (["icub_right", "/dev/zero", *fingers, "-o", "o"], "not a regular file"),
    }
    cwd = os.getcwd()
    os.chdir(tmp_path)
    try:
        for name, (argv, words) in cases.items():
            before = {p.name: _sha(p) for p in tmp_path.iterdir() if p.is_file() and not p.is_symlink()}
            code, err = _run(capsys, "synth", *argv)
            assert code == 2 and len(err) == 1 and words in err[0], (name, err)
            assert not (tmp_path / "o").exists(), name
            assert {p.name: _sha(p) for p in tmp_path.iterdir() if p.is_file() and not p.is_symlink()} == before, name
    finally:
        os.chdir(cwd)


def test_hand_yaml_with_an_integer_finger_key_or_a_fifo_is_one_line(tmp_path, capsys):
    import shutil

    src = ROOT / "robots/icub_right"
    (tmp_path / "h").mkdir()
    shutil.copy(src / "icub_right.urdf", tmp_path / "h")
    (tmp_path / "h/hand.yaml").write_text((src / "hand.yaml").read_text().replace("\n  index:", "\n  7:", 1))
    grasp = (ROOT / "grasps/icub/box_ir2m.yaml").read_text()
    g = tmp_path / "g.yaml"
    g.write_text(re.sub(r"(?m)^hand:.*$", "hand: h/hand.yaml", grasp))
    code, err = _run(capsys, "check", g)
    assert code == 2 and len(err) == 1 and "fingers.7" in err[0], err
    os.mkfifo(tmp_path / "fifo.yaml")
    g.write_text(re.sub(r"(?m)^hand:.*$", "hand: fifo.yaml", grasp))
    code, err = _run(capsys, "check", g)
    assert code == 2 and len(err) == 1 and "not a regular file" in err[0], err


def test_view_of_a_fifo_or_a_deep_plan_is_one_line_and_writes_nothing(tmp_path, capsys):
    os.mkfifo(tmp_path / "fifo.yaml")
    (tmp_path / "deep.json").write_text('{"a":' * 100000 + "1" + "}" * 100000)
    for name, words in (("fifo.yaml", "not a regular file"), ("deep.json", "nesting")):
        code, err = _run(capsys, "view", tmp_path / name, "-o", tmp_path / "v.html")
        assert code == 2 and len(err) == 1 and words in err[0], err
        assert not (tmp_path / "v.html").exists()
    # a replay report that is a FIFO: refused before the page is drawn
    plan = tmp_path / "p.yaml"
    assert main(["plan", str(ROOT / "grasps/icub/pen_palmar_pinch.yaml"), str(ROOT / "grasps/icub/pen_writing_tripod.yaml"),
                 "--no-motion", "-o", str(plan), "-q"]) == 0
    capsys.readouterr()
    code, err = _run(capsys, "view", plan, "-o", tmp_path / "v.html", "--report", tmp_path / "fifo.yaml")
    assert code == 2 and len(err) == 1 and "not a regular file" in err[0], err
    assert not (tmp_path / "v.html").exists()


def _burn(stop):
    while not stop.is_set():
        sum(i * i for i in range(10_000))


def test_a_failing_pair_is_explained_the_same_under_cpu_load():
    """The anytime rounds are bounded by work (--max-rounds, expanded states), not by the
    clock: an exp8 pair that execution mode cannot plan gets the same explanation, word for
    word but the seconds, with both cores busy as without."""
    import multiprocessing as mp
    import re

    from planner.errors import NoSequenceError
    from planner.grasp import load_grasp
    from planner.options import PlanOptions
    from planner.realization import realize
    from planner.regrasp import plan_regrasp as plan

    data = Path(__file__).parent / "data" / "grasps"
    gi, gf = (realize(load_grasp(data / f"allegro_cylinder_{k}.yaml")) for k in "if")
    # the gait search alone (since b030f6d a reposing move onto the palm joins this pair)
    options = PlanOptions.for_execution(verify=False, max_rounds=1, motion=False, repose=False)

    def explanation() -> str:
        with pytest.raises(NoSequenceError) as err:
            plan(gi, gf, options)
        return re.sub(r"[0-9.]+ s\b", "<t> s", str(err.value))

    quiet = explanation()
    stop = mp.get_context("spawn").Event()
    burners = [mp.get_context("spawn").Process(target=_burn, args=(stop,)) for _ in range(2)]
    for p in burners:
        p.start()
    try:
        loaded = explanation()
    finally:
        stop.set()
        for p in burners:
            p.join(10)
    assert loaded == quiet
    assert "the round limit was reached (--max-rounds 1)" in quiet and "time limit" not in quiet


_DROPPED_SIGNAL = """
import os, signal, sys, time
from planner import cli

def kill_self_in_the_callback():  # the handler runs inside a fork's callback, where Python drops what it raises
    os.kill(os.getpid(), signal.{sig})
    for _ in range(100):
        pass

signal.signal(signal.SIGINT, signal.default_int_handler)  # (a test runner's worker may ignore Ctrl-C: inherited)
os.register_at_fork(after_in_parent=kill_self_in_the_callback)
try:
    with cli._sigterm_unwinds():
        pid = os.fork()
        if pid == 0:
            os._exit(0)
        os.waitpid(pid, 0)
        for _ in range(200):
            time.sleep(0.001)  # the command goes on
        print("ran on")
except KeyboardInterrupt as stop:
    print(type(stop).__name__)
"""


@pytest.mark.skipif(not hasattr(os, "register_at_fork"), reason="forks")
@pytest.mark.parametrize("sig, raised", [("SIGTERM", "Terminated"), ("SIGINT", "KeyboardInterrupt")])
def test_a_signal_whose_exception_python_dropped_is_delivered_again(sig, raised):
    """SIGTERM or Ctrl-C arriving while a fork's callback runs (logging's lock release after each
    fork of a worker): the exception its handler raises there is dropped by Python ("Exception
    ignored in") and the command ran on to exit 0 with its plan written (a CI run of the SIGTERM
    test above). It is delivered again and stops the command, nothing printed."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    got = subprocess.run([sys.executable, "-c", _DROPPED_SIGNAL.replace("{sig}", sig)], capture_output=True,
                         text=True, env=env, timeout=60)
    assert (got.stdout.strip(), got.stderr.strip()) == (raised, "")


_REPEATED_SIGNAL = """
import os, signal, sys, time, types
from planner import cli

signal.signal(signal.SIGINT, signal.default_int_handler)  # (a test runner's worker may ignore Ctrl-C: inherited)
signal.signal(signal.SIGHUP, signal.SIG_DFL)  # (and a CI under nohup SIGHUP: the planner then leaves it ignored)
done = []
try:
    with cli._sigterm_unwinds():
        try:
            if {dropped}:  # one Python dropped (raised in a fork's callback): delivered again in a few ms
                sys.unraisablehook(types.SimpleNamespace(exc_value=cli.Terminated(), exc_type=cli.Terminated,
                                                         exc_traceback=None, err_msg=None, object=None))
            os.kill(os.getpid(), signal.{sig})
            for _ in range(2000):
                time.sleep(0.001)
            print("ran on")
        except KeyboardInterrupt:  # the clean-up (the replays' workers told to stop, the pool left)
            if not {dropped}:  # (else the dropped one's redelivery comes here)
                os.kill(os.getpid(), signal.{sig})  # `timeout` signals the process, then its group
            for _ in range(50):
                time.sleep(0.001)
            done.append("cleaned up")
            raise
except KeyboardInterrupt as stop:
    print(type(stop).__name__, *done)
"""


@pytest.mark.parametrize("sig, raised, dropped", [("SIGTERM", "Terminated", False), ("SIGHUP", "HungUp", False),
                                                  ("SIGTERM", "Terminated", True)])
def test_a_repeated_signal_does_not_cut_the_clean_up_short(sig, raised, dropped):
    """A second SIGTERM (`timeout` signals the planner and then its process group) or SIGHUP, or
    the redelivery of one Python had dropped, arriving while the command unwinds for the first:
    it raised again inside the clean-up, which stopped there (the replays' workers not told to
    stop, the pool waiting for them to finish). The command unwinds once."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    got = subprocess.run([sys.executable, "-c", _REPEATED_SIGNAL.replace("{sig}", sig).replace("{dropped}", str(dropped))],
                         capture_output=True, text=True, env=env, timeout=60)
    assert (got.stdout.strip(), got.stderr.strip()) == (f"{raised} cleaned up", "")


_CALLERS_ALARM = """
import signal, time
from planner import cli

fired = []
signal.signal(signal.SIGALRM, lambda *_: fired.append("alarm"))
signal.setitimer(signal.ITIMER_REAL, {first})
with cli._sigterm_unwinds():  # what main() runs a command in
    time.sleep(0.1)
    if {first} < 0.1:
        time.sleep(0.2)
deadline = time.monotonic() + 1
while not fired and time.monotonic() < deadline:
    time.sleep(0.01)
print(*fired)
"""


@pytest.mark.skipif(not hasattr(__import__("signal"), "setitimer"), reason="interval timers")
@pytest.mark.parametrize("first", [0.05, 0.3])
def test_a_callers_alarm_survives_a_command(first):
    """A program that runs `planner.cli.main` with a timer of its own (a watchdog alarm): while
    the command ran, its SIGALRM went to the redelivery of dropped interrupts and was lost, and
    when the command returned its timer was cancelled. Its alarm now fires, during or after."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    got = subprocess.run([sys.executable, "-c", _CALLERS_ALARM.replace("{first}", str(first))], capture_output=True,
                         text=True, env=env, timeout=60)
    assert (got.stdout.strip(), got.stderr.strip()) == ("alarm", "")
