"""The one-call API (planner.api): the obvious calls work with paths and with loaded objects,
give what the CLI gives, and refuse bad options in one line."""

from __future__ import annotations

import pytest

import planner
from planner.errors import PlannerError, UnknownNameError
from planner.resources import bundled_grasp

A, B = bundled_grasp("icub/box_ir2m.yaml"), bundled_grasp("icub/box_parallel_extension.yaml")


@pytest.fixture(scope="module")
def planned(tmp_path_factory):
    out = tmp_path_factory.mktemp("api") / "plan.yaml"
    return planner.plan(str(A), str(B), motion=False, output=out), out


def test_plan_takes_paths_writes_and_records_the_inputs(planned):
    result, out = planned
    assert result.sequence.gait_steps >= 1
    assert set(result.plan.inputs) == {"initial", "final"}
    again = planner.plan.read_plan(out)  # planner.plan is also the plan-file module
    assert again.to_dict() == result.plan.to_dict()
    assert "plan" in planner.__all__ and callable(planner.plan)


def test_plan_regrasp_accepts_paths_and_gives_the_same_plan(planned):
    result, _ = planned
    direct = planner.plan_regrasp(str(A), str(B), planner.PlanOptions(motion=False))
    assert direct.plan.to_dict()["states"] == result.plan.to_dict()["states"]
    # loaded objects give the same states (the inputs are not recorded then)
    a, b = planner.check(A), planner.check(B)
    assert planner.plan(a, b, motion=False).plan.to_dict()["states"] == result.plan.to_dict()["states"]


def test_verify_and_replay_of_the_written_plan(planned):
    _, out = planned
    audit = planner.verify(out)
    assert audit.ok and audit.checked["steps"] >= 2
    report = planner.replay(out)
    assert report.passed, report.verdict


def test_bad_options_are_planner_errors_naming_the_choices():
    with pytest.raises(UnknownNameError, match="unknown plan option 'bogus'.*time_limit_s"):
        planner.plan(str(A), str(B), bogus=1)
    with pytest.raises(PlannerError):
        planner.plan(str(A), str(B), output="plan.txt")  # bad suffix, before any work


@pytest.mark.parametrize("value, got", [(5, "int 5"), (None, "nothing"), ({"a": 1}, "dict"), (b"a.yaml", "bytes"),
                                         ("", "an empty file name")], ids=["int", "None", "dict", "bytes", "empty"])
def test_a_path_argument_of_the_wrong_type_is_an_input_error_naming_it(value, got):
    """An int, None, a dict, bytes or an empty string where a file is expected: an InputError
    naming the argument, what it takes and what it got (pathlib's TypeError before; an empty
    name read the current folder); plan data (a mapping) is a plan for `verify` as for `replay`."""
    from planner.errors import InputError

    with pytest.raises(InputError, match=f"^grasp file: expected a file path, got {got}"):
        planner.check(value)
    with pytest.raises(InputError, match=f"^initial: expected a grasp file path, a GraspSpec or a RealizedGrasp, got {got}"):
        planner.plan(value, str(B))
    if value is not None:
        with pytest.raises(InputError, match=f"^output: expected a plan file path .*, got {got}"):
            planner.plan(str(A), str(B), output=value)
    if not isinstance(value, dict):
        for call in (planner.verify, planner.replay):
            with pytest.raises(InputError, match=f"^plan: expected a plan file path, got {got}"):
                call(value)
    else:
        with pytest.raises(planner.SpecError, match="schema_version: missing key"):
            planner.verify(value)


def test_an_output_of_the_wrong_type_is_an_input_error(planned):
    """``replay(report=5)``: one line naming the option, not a TypeError in pathlib."""
    from planner.errors import InputError

    _, out = planned
    with pytest.raises(InputError, match="^--report: expected an output file path, got int 5"):
        planner.replay(out, report=5)


def test_bad_replay_keywords_are_planner_errors(planned):
    """replay's keywords: a misspelt one is an UnknownNameError listing them (a TypeError from
    replay_plan before), ``workers`` 0, -1 or 'two' an InputError (0 and -1 replayed serially,
    'two' was a ValueError), ``gravity_set=True`` is not a set size, and ``film`` may be one
    comma-separated string as --film (its letters were taken for direction names)."""
    from planner.errors import InputError

    _, out = planned
    with pytest.raises(UnknownNameError, match="unknown replay option 'drift_mm'; .*drift_mm_max"):
        planner.replay(out, drift_mm=3)
    for workers in (0, -1, "two", 1.5):
        with pytest.raises(InputError, match=r"^workers must be an integer in \[1, 256\] \(processes\), got"):
            planner.replay(out, gravity_set=2, workers=workers)
    with pytest.raises(PlannerError, match="gravity set size must be one of 1, 2, 6, 7, got True"):
        planner.replay(out, gravity_set=True)
    with pytest.raises(InputError, match="^cannot film side_\\+x: the gravity set of 2 has palm_down, palm_up$"):
        planner.replay(out, gravity_set=2, gif=out.with_suffix(".gif"), film="palm_down,side_+x")


def test_exported_functions_refuse_wrong_argument_types(planned, tmp_path):
    """The other exported calls name a wrong argument in an InputError instead of an
    AttributeError or TypeError deep inside: Hand.load(None), plan_regrasp with options as a
    dict, write_plan to a non-path or of a non-plan; realize takes a grasp file as
    plan_regrasp does (it was an AttributeError on the path)."""
    from planner.errors import InputError

    result, _ = planned
    with pytest.raises(InputError, match="^hand: expected a bundled hand's name or a hand.yaml path, got nothing"):
        planner.Hand.load(None)
    with pytest.raises(InputError, match=r"^options: expected a PlanOptions .*got dict"):
        planner.plan_regrasp(str(A), str(B), {"motion": False})
    with pytest.raises(InputError, match="^plan: expected a plan file path .*got int 5"):
        planner.write_plan(result.plan, 5)
    with pytest.raises(InputError, match="^plan: expected a Plan or plan data, got int 5"):
        planner.write_plan(5, tmp_path / "p.yaml")
    assert not (tmp_path / "p.yaml").exists()
    assert planner.realize(str(A)).closure == planner.check(A).closure


@pytest.mark.parametrize("film", ["", ",", []], ids=["empty", "comma", "no-list"])
def test_a_film_of_no_direction_is_refused(planned, capsys, film):
    """``--film ''`` filmed every direction of the set (seven films, minutes) and ``--film ,``
    none: a --film naming no direction is refused, naming the set's directions (the CLI too)."""
    from planner.cli import main
    from planner.errors import InputError

    _, out = planned
    with pytest.raises(InputError, match="^--film names no direction; .*the gravity set of 2 has palm_down, palm_up$"):
        planner.replay(out, gravity_set=2, gif=out.with_suffix(".gif"), film=film)
    if isinstance(film, str):
        assert main(["replay", str(out), "--gravity-set", "2", "--gif", str(out.with_suffix(".gif")), "--film", film]) == 2
        assert "--film names no direction" in capsys.readouterr().err
    assert not list(out.parent.glob("*.gif"))


def test_check_realizes_a_grasp_file():
    g = planner.check(A)
    assert g.closure.is_force_closure and not g.problems
    assert planner.check(g) is g


def test_progress_lines_on_a_terminal_only_and_not_with_quiet(tmp_path):
    """A long command says what it does on stderr when stderr is a terminal (logging records of
    the ``planner`` logger), nothing when it is a pipe or with -q; stdout is the same."""
    import os
    import pty
    import subprocess
    import sys

    argv = [sys.executable, "-m", "planner", "plan", str(A), str(B), "--no-motion", "-o", str(tmp_path / "p.yaml")]

    def run(extra=(), tty=True):
        if not tty:
            out = subprocess.run(argv + list(extra), capture_output=True, text=True, timeout=300)
            return out.stdout, out.stderr
        master, slave = pty.openpty()
        try:
            proc = subprocess.run(argv + list(extra), stdout=subprocess.PIPE, stderr=slave, text=True, timeout=300)
        finally:
            os.close(slave)
        chunks = []
        while True:
            try:
                data = os.read(master, 65536)
            except OSError:
                break
            if not data:
                break
            chunks.append(data)
        os.close(master)
        return proc.stdout, b"".join(chunks).decode()

    out_tty, err_tty = run()
    assert "regrasp plan: searching the grasp-state graph" in err_tty
    assert "regrasp plan: search: " in err_tty
    out_pipe, err_pipe = run(tty=False)
    assert err_pipe.strip() == ""
    assert out_pipe.splitlines()[:-1] == out_tty.splitlines()[:-1]  # (the last line has the time)
    _, err_quiet = run(["-q"])
    assert "searching" not in err_quiet
