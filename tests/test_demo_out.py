"""`demo --out DIR` is checked like every output before any work: a DIR whose folder does not
exist is refused (it was created with all its parents, a typo included), and a symbolic link
that loops is one line and exit 2 (it was a FileExistsError traceback, exit 1)."""

import pytest

import planner.cli as cli
from planner.cli import main
from planner.errors import PlannerError


@pytest.fixture(autouse=True)
def no_work(monkeypatch):
    """The demo's planning never starts here: its first step stops at once (the checks of
    --out come before it)."""
    def stop(_name):
        raise PlannerError("the demo started")
    monkeypatch.setattr(cli, "bundled_grasp", stop)


def _one_line(capsys, *words):
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and all(w in err[0] for w in words), err


def test_demo_out_in_a_missing_folder(tmp_path, capsys):
    assert main(["demo", "--out", str(tmp_path / "typo" / "demo"), "-q"]) == 2
    _one_line(capsys, "--out", "does not exist")
    assert not (tmp_path / "typo").exists()


def test_demo_out_a_symlink_loop(tmp_path, capsys):
    (tmp_path / "a").symlink_to(tmp_path / "b")
    (tmp_path / "b").symlink_to(tmp_path / "a")
    assert main(["demo", "--out", str(tmp_path / "a"), "-q"]) == 2
    _one_line(capsys, "--out", "symbolic link to nothing")


def test_demo_out_empty(tmp_path, monkeypatch, capsys):
    """`--out ''` (an empty shell variable) is refused: it wrote the demo's files into the
    current folder."""
    monkeypatch.chdir(tmp_path)
    assert main(["demo", "--out", "", "-q"]) == 2
    _one_line(capsys, "--out: an empty name", "regrasp-demo")
    assert list(tmp_path.iterdir()) == []


def test_ctrl_c_in_a_step_stops_the_demo(tmp_path, monkeypatch, capsys):
    """Ctrl-C during the demo's replay ends the demo (one line, exit 130): it went on to write
    the 3D page and its summary after the replay said 'interrupted'."""
    import planner.commands as commands

    monkeypatch.setattr(cli, "bundled_grasp", lambda name: name)
    monkeypatch.setattr(commands, "cmd_plan", lambda args: 0)
    viewed = []
    monkeypatch.setattr(commands, "cmd_view", lambda args: viewed.append(args) or 0)

    def ctrl_c(_args):
        raise KeyboardInterrupt

    monkeypatch.setattr(commands, "cmd_replay", ctrl_c)
    assert main(["demo", "--out", str(tmp_path / "demo"), "-q"]) == 130
    assert viewed == []
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["regrasp demo: interrupted"]
