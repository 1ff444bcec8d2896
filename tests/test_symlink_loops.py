"""A symlink loop where a path goes (a grasp's mesh, synth's -o, hand init's --package-dir, a
hand.yaml's package_dirs) is one line and exit 2: on Python < 3.13 Path.resolve raised
RuntimeError ('Symlink loop from ...'), a traceback and exit 1; since 3.13 it returns the looping
path (`planner.fileio.resolve_path` says ELOOP on both). hand init also refuses a
--package-dir that is not a folder (a typo was ignored, exit 0)."""

import pytest
import yaml

from planner.cli import main
from planner.hand import ROBOTS_DIR
from planner.resources import bundled_grasp

URDF = ROBOTS_DIR / "icub_right" / "icub_right.urdf"


def _loop(folder, name):
    (folder / name).symlink_to(folder / f"{name}.b")
    (folder / f"{name}.b").symlink_to(folder / name)
    return folder / name


def _one_line(capsys, *words):
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and all(w in err[0] for w in words), err
    assert "Traceback" not in err[0]


def test_a_mesh_path_that_loops(tmp_path, capsys):
    grasp = yaml.safe_load(bundled_grasp("icub/mesh_rounded_box_ir2m.yaml").read_text())
    grasp["object"]["mesh"] = _loop(tmp_path, "m.obj").name
    (tmp_path / "g.yaml").write_text(yaml.safe_dump(grasp))
    assert main(["check", str(tmp_path / "g.yaml"), "-q"]) == 2
    _one_line(capsys, "object.mesh", "m.obj")


def test_synth_into_a_folder_that_loops(tmp_path, capsys):
    (tmp_path / "ball.yaml").write_text("shape: sphere\nsize: [0.015]\nmass_kg: 0.03\n")
    out = _loop(tmp_path, "out")
    assert main(["synth", "icub_right", str(tmp_path / "ball.yaml"), "-n", "1", "-q", "-o", str(out)]) == 2
    _one_line(capsys, "-o", "out")


@pytest.mark.parametrize("loop", [True, False])
def test_hand_init_package_dir_not_a_folder(tmp_path, capsys, loop):
    pkg = _loop(tmp_path, "pkgs") if loop else tmp_path / "nope"
    out = tmp_path / "hand.yaml"
    assert main(["hand", "init", str(URDF), "-o", str(out), "--package-dir", str(pkg)]) == 2
    _one_line(capsys, "--package-dir", "not a folder")
    assert not out.exists()


def test_hand_yaml_package_dirs_that_loop(tmp_path, capsys):
    text = (ROBOTS_DIR / "icub_right" / "hand.yaml").read_text().replace("urdf: icub_right.urdf", f"urdf: {URDF}")
    _loop(tmp_path, "pkgs")
    (tmp_path / "hand.yaml").write_text(text + "package_dirs: [pkgs]\n")
    assert main(["hand", "check", str(tmp_path / "hand.yaml")]) == 2
    _one_line(capsys, "package_dirs[0]", "hand.yaml")


def test_package_path_variables_with_loops_missing_folders_and_files(tmp_path, capsys, monkeypatch):
    """ROS_PACKAGE_PATH / AMENT_PREFIX_PATH entries that are no folder (a symlink loop, a
    missing folder, a file) are skipped, as ROS's tools skip them: pinocchio read the variable
    itself and its loader stopped on the loop ("Too many levels of symbolic links" naming the
    folder, not the variable). The hand loads, the page draws it, the variables are left as
    they were."""
    import os

    loop = _loop(tmp_path, "pkgs")
    (tmp_path / "file").write_text("x\n")
    value = os.pathsep.join([str(loop), str(tmp_path / "missing"), str(tmp_path / "file")])
    monkeypatch.setenv("ROS_PACKAGE_PATH", value)
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(loop))
    text = (ROBOTS_DIR / "icub_right" / "hand.yaml").read_text().replace("urdf: icub_right.urdf", f"urdf: {URDF}")
    (tmp_path / "hand.yaml").write_text(text)  # a hand file of its own: loaded here, not cached
    assert main(["hand", "check", str(tmp_path / "hand.yaml")]) == 0
    grasp = yaml.safe_load(bundled_grasp("icub/box_ir2m.yaml").read_text())
    grasp["hand"] = str(tmp_path / "hand.yaml")
    (tmp_path / "g.yaml").write_text(yaml.safe_dump(grasp))
    assert main(["view", str(tmp_path / "g.yaml"), "-o", str(tmp_path / "g.html")]) == 0
    assert "Too many levels" not in capsys.readouterr().err
    assert os.environ["ROS_PACKAGE_PATH"] == value and os.environ["AMENT_PREFIX_PATH"] == str(loop)
