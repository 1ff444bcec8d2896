"""No output overwrites an input: every file a command reads (the plan, its recorded grasps,
the hand.yaml, the URDF, meshes) is protected against every output name the command
derives, and two outputs of one command never share a path. Each refusal is exit 2, one
line naming the option, before any simulation; the input is unchanged."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import yaml

from planner.cli import main
from planner.resources import bundled_grasp, hand_dir

PAIR = ("icub/box_parallel_extension.yaml", "icub/box_ir2m.yaml")


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    """A user's folder: a copy of the hand (hand.yaml beside its URDF), two grasp files that
    name it, and a plan made from them."""
    root = tmp_path_factory.mktemp("outputs")
    hand = root / "hand"
    shutil.copytree(hand_dir("icub_right"), hand)
    grasps = []
    for name in PAIR:
        data = yaml.safe_load(bundled_grasp(name).read_text())
        data["hand"] = "hand/hand.yaml"
        path = root / Path(name).name
        path.write_text(yaml.safe_dump(data, sort_keys=False))
        grasps.append(path)
    plan = root / "plan.json"
    assert main(["plan", str(grasps[0]), str(grasps[1]), "--no-motion", "-o", str(plan)]) == 0
    return {"root": root, "hand": hand / "hand.yaml", "urdf": hand / "icub_right.urdf", "initial": grasps[0],
            "final": grasps[1], "plan": plan}


def _snapshot(setup) -> dict:
    return {k: v.read_bytes() for k, v in setup.items() if isinstance(v, Path) and v.is_file()}


def _refused(capsys, argv, option: str) -> str:
    assert main(argv) == 2
    err = [line for line in capsys.readouterr().err.strip().splitlines() if "warning:" not in line]
    assert len(err) == 1 and option in err[0], err
    return err[0]


@pytest.mark.parametrize("target", ["initial", "final", "hand", "urdf", "plan"])
@pytest.mark.parametrize("option", ["--report", "--gif"])
def test_replay_outputs_may_not_be_any_file_the_plan_reads(setup, capsys, target, option):
    before = _snapshot(setup)
    line = _refused(capsys, ["replay", str(setup["plan"]), option, str(setup[target])], option)
    assert "input" in line
    assert _snapshot(setup) == before


@pytest.mark.parametrize("target", ["hand", "urdf", "initial"])
def test_a_derived_film_name_may_not_be_an_input(setup, capsys, target, tmp_path):
    """--gravity-set films FILE_<direction>.ext: FILE chosen so that the palm-down film is the input."""
    victim = setup[target]
    stem = victim.stem.removesuffix("_palm_down")
    link = victim.with_name(f"{stem}_palm_down{victim.suffix}")
    if link != victim:  # name the input like a derived film: a second name of the same file
        link.hardlink_to(victim)
    try:
        before = _snapshot(setup)
        line = _refused(capsys, ["replay", str(setup["plan"]), "--gravity-set", "1", "--gif",
                                 str(victim.with_name(stem + victim.suffix))], "--gif")
        assert "input" in line
        assert _snapshot(setup) == before
    finally:
        if link != victim:
            link.unlink()


def test_two_outputs_of_one_replay_never_share_a_path(setup, capsys, tmp_path):
    """A report named like the palm-down film would lose the film (or the report)."""
    film = tmp_path / "film.gif"
    line = _refused(capsys, ["replay", str(setup["plan"]), "--gravity-set", "1", "--gif", str(film),
                             "--report", str(tmp_path / "film_palm_down.gif")], "--gif")
    assert "--report" in line
    assert not list(tmp_path.iterdir())


def test_mp4_is_an_output_never_read_as_a_grasp(setup, capsys, tmp_path):
    """`replay --gravity-set N --mp4 out.mp4` once read out.mp4 as a grasp file (a loop
    variable left over in the CLI's validation)."""
    out = tmp_path / "out.mp4"
    out.write_text("an old film\n")
    code = main(["replay", str(setup["plan"]), "--gravity-set", "1", "--mp4", str(out), "--report",
                 str(tmp_path / "r.json")])
    err = capsys.readouterr().err
    assert "grasp file" not in err
    assert code in (0, 1) or "ffmpeg" in err, err  # without ffmpeg: a clear one-line error


def test_plan_output_may_not_be_its_hand_or_urdf(setup, capsys):
    for target in ("hand", "urdf"):
        before = _snapshot(setup)
        bad = setup[target].with_suffix(".yaml") if target == "urdf" else setup[target]
        if target == "urdf":  # a .yaml name of the URDF: a second name (hard link) of the same file
            bad.hardlink_to(setup["urdf"])
        try:
            line = _refused(capsys, ["plan", str(setup["initial"]), str(setup["final"]), "--no-motion", "-o", str(bad)],
                            "-o")
            assert "input" in line
            assert _snapshot(setup) == before
        finally:
            if target == "urdf":
                bad.unlink()


def test_view_film_may_not_be_the_plans_inputs(setup, capsys, tmp_path):
    before = _snapshot(setup)
    link = setup["initial"].with_suffix(".gif")
    link.hardlink_to(setup["initial"])
    try:
        line = _refused(capsys, ["view", str(setup["plan"]), "-o", str(tmp_path / "p.html"), "--gif", str(link)],
                        "--gif")
        assert "input" in line
        assert _snapshot(setup) == before and not (tmp_path / "p.html").exists()
    finally:
        link.unlink()


@pytest.mark.needs_pybullet("what pybullet's URDF loader prints")
def test_pybullet_never_prints_on_stdout(tmp_path):
    """A URDF without inertials makes pybullet's loader warn on the C stdout ("b3Warning ... No
    inertial data"): `hand check` (which loads it in pybullet) prints only its own lines."""
    import re
    import subprocess
    import sys

    hand = tmp_path / "h"
    shutil.copytree(hand_dir("icub_right"), hand)
    urdf = hand / "icub_right.urdf"
    urdf.write_text(re.sub(r"<inertial>.*?</inertial>", "", urdf.read_text(), flags=re.S))
    out = subprocess.run([sys.executable, "-m", "planner", "hand", "check", str(hand / "hand.yaml")],
                         capture_output=True, text=True, timeout=300)
    assert "pybullet: loads the URDF" in out.stdout, out.stdout  # the check ran
    assert "b3Warning" not in out.stdout and "inertial data" not in out.stdout, out.stdout


def test_check_picture_may_not_be_the_hand_or_grasp(setup, capsys):
    before = _snapshot(setup)
    for target in ("hand", "initial"):
        link = setup[target].with_suffix(".png")
        link.hardlink_to(setup[target])
        try:
            line = _refused(capsys, ["check", str(setup["initial"]), "--png", str(link)], "--png")
            assert "input" in line
        finally:
            link.unlink()
    assert _snapshot(setup) == before


@pytest.mark.parametrize("command, option, name, words", [
    ("check", "--png", "grasp.jpg", "--png writes PNG: name the file *.png (not .jpg)"),
    ("check", "--png", "grasp", "--png writes PNG: name the file *.png (this name has no suffix)"),
    ("replay", "--gif", "film.png", "--gif writes GIF: name the file *.gif (not .png)"),
    ("replay --gravity-set 1", "--mp4", "film.gif", "--mp4 writes MP4: name the file *.mp4 (not .gif)"),
    ("replay --gravity-set 2", "--gif", "film.png", "film.png: --gif writes GIF"),  # the name given, not film_palm_down.png
    pytest.param("replay --engine both", "--gif", "film.png", "film.png: --gif writes GIF",
                 marks=pytest.mark.needs_pybullet("--engine both: without pybullet that is said first")),
    ("view", "--gif", "film.png", "--gif writes GIF: name the file *.gif (not .png)"),
])
def test_a_picture_or_film_is_named_with_its_formats_suffix(setup, capsys, tmp_path, command, option, name, words):
    """`check --png x.jpg` wrote a JPEG and `replay --gif x.png` a GIF named .png: a picture or
    film not named with its format's suffix is refused in one line before any work (a name's
    case is the user's: F.GIF is a GIF)."""
    word, *rest = command.split()
    source = setup["initial"] if word == "check" else setup["plan"]
    extra = ["-o", str(tmp_path / "page.html")] if word == "view" else []
    line = _refused(capsys, [word, str(source), *rest, *extra, option, str(tmp_path / name)], option)
    assert words in line, line
    assert not list(tmp_path.iterdir())


def test_the_one_writer_replaces_atomically_or_never(tmp_path):
    """write_atomic: replaces a file whole; exclusive: never replaces one (synth's grasps);
    a writer that fails leaves the old file and no temporary file."""
    from planner.errors import OutputError
    from planner.fileio import write_atomic

    target = tmp_path / "a.yaml"
    write_atomic(target, "one\n")
    write_atomic(target, "two\n")
    assert target.read_text() == "two\n"
    with pytest.raises(OutputError, match="appeared while writing"):
        write_atomic(target, "three\n", exclusive=True)

    def broken(tmp):
        Path(tmp).write_text("half")
        raise OSError(28, "No space left on device")

    with pytest.raises(OutputError, match="No space left"):
        write_atomic(target, write=broken)
    assert target.read_text() == "two\n" and [p.name for p in tmp_path.iterdir()] == ["a.yaml"]
    write_atomic(tmp_path / "b.gif", write=lambda tmp: Path(tmp).write_bytes(b"GIF89a"))
    assert (tmp_path / "b.gif").read_bytes() == b"GIF89a"


def test_an_error_line_stays_bounded_whatever_the_file_holds(tmp_path, capsys):
    """A 3000-character hand name (a hand.yaml may be 1 MB) is refused in one line that quotes
    at most 80 characters of it; any line is at most `MAX_LINE_CHARS` (a backstop)."""
    from planner.cli import MAX_LINE_CHARS

    hand = tmp_path / "h"
    shutil.copytree(hand_dir("icub_right"), hand)
    spec = yaml.safe_load((hand / "hand.yaml").read_text())
    spec["name"] = "n" * 3000
    (hand / "hand.yaml").write_text(yaml.safe_dump(spec, sort_keys=False))
    assert main(["hand", "check", str(hand / "hand.yaml")]) in (1, 2)
    out = capsys.readouterr()
    lines = [line for line in (out.err + out.out).splitlines() if line.strip()]
    assert lines and all(len(line) <= MAX_LINE_CHARS and "n" * 100 not in line for line in lines), lines
    assert any("'nnn" in line and "..." in line for line in lines), lines
