"""MuJoCo behind the physics seam: a bundled execution plan replays in it, the engine is named
in every verdict and report, ``--engine both`` refuses a plan one engine drops, and an engine
that is not installed is one clear line."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import pytest

from planner.errors import InputError, SimulationError

pytest.importorskip("mujoco")

DATA = Path(__file__).parent / "data"
#: The suite's bundled cylinder pair planned with --execution (the demo's pair).
PLAN = DATA / "plans" / "schema2_cylinder_execution.json"
#: Gravity no grip of the plan's squeeze can hold (30 g): the object drops during the ramp, so
#: a failing replay costs a fraction of a second in either engine.
CRUSHING_G = (0.0, 0.0, 300.0)


@pytest.fixture(scope="module")
def mujoco_report():
    """The plan replayed palm down in MuJoCo (one replay for the module)."""
    from planner.sim.replay import replay_plan

    return replay_plan(str(PLAN), engine="mujoco")


def test_a_bundled_execution_plan_holds_in_mujoco_palm_down(mujoco_report):
    """The demo's cylinder pair, planned for execution, holds in MuJoCo: no drop, drift within
    the limits, every state reached with the plan's force closure."""
    r = mujoco_report
    assert r.engine == "mujoco" and r.passed, r.verdict
    assert not r.dropped and r.max_drift_mm <= 5.0 and r.max_drift_deg <= 5.0
    agree, reached = r.closure_agreement
    assert reached == len(r.states) and agree == reached
    assert r.to_dict()["engine"] == "mujoco"


def test_mujoco_reads_contacts_on_the_object_with_normals_into_it(mujoco_report):
    """At every reached state the filtered contacts lie on the cylinder's surface (within the
    touch tolerance) and their normals point into it (radially inward on the side)."""
    import numpy as np

    from planner.plan import read_plan

    obj = read_plan(PLAN).object
    radius, half = obj.size[0], obj.size[1] / 2
    for s in mujoco_report.states:
        for f, (pts, normals) in s.sim_patches.items():
            for p, n in zip(np.asarray(pts), np.asarray(normals)):
                r_xy = float(np.hypot(p[0], p[1]))
                on_side = abs(r_xy - radius) <= 1e-3 and abs(p[2]) <= half + 1e-3
                on_cap = abs(abs(p[2]) - half) <= 1e-3 and r_xy <= radius + 1e-3
                assert on_side or on_cap, (s.index, f, p)
                if on_side and abs(p[2]) < half - 1e-3:
                    assert float(np.dot(n[:2], -p[:2] / r_xy)) > 0.9, (s.index, f, n)


def test_the_cli_names_the_engine_in_the_verdict(capsys):
    """`regrasp replay --engine mujoco` under a crushing gravity fails with a verdict line
    naming MuJoCo, and exits 1."""
    from planner.cli import main

    code = main(["replay", str(PLAN), "--engine", "mujoco", "--gravity", *map(str, CRUSHING_G)])
    last = capsys.readouterr().out.rstrip().splitlines()[-1]
    assert code == 1 and last.startswith("FAIL in mujoco: object dropped"), last


@pytest.mark.needs_pybullet("--engine both replays in pybullet too")
def test_both_engines_refuse_a_plan_that_drops_and_name_the_engine():
    """`verify_plan(engine="both")` (what ``plan --execution --engine both`` runs) refuses a
    plan that drops: the refusal's verdict names pybullet, which failed first, and MuJoCo is
    not asked; the single-engine verification names MuJoCo."""
    from planner.plan import read_plan
    from planner.sim.inputs import plan_hand
    from planner.sim.verify import verify_plan

    plan = read_plan(PLAN)
    hand = plan_hand(plan)
    both = verify_plan(plan, hand, [("crushing", CRUSHING_G)], workers=1, engine="both")
    assert not both.passed and [e for e, _ in both.by_engine] == ["pybullet"]
    direction, step, verdict, _ = both.first_failure()
    assert direction == "crushing" and step == -1 and verdict.startswith("pybullet: FAIL: object dropped")
    alone = verify_plan(plan, hand, [("crushing", CRUSHING_G)], workers=1, engine="mujoco")
    assert not alone.passed and alone.first_failure()[2].startswith("mujoco: FAIL: object dropped")
    assert alone.record()["engine"] == "mujoco"


@pytest.mark.needs_pybullet("--engine both replays in pybullet too")
def test_both_refuses_when_only_the_second_engine_fails(monkeypatch):
    """With both engines a plan that holds in pybullet and drops in MuJoCo is refused: the
    merged verdict is MuJoCo's, its failed step the plan's, the drifts the larger; a plan that
    holds in both records each engine's verdicts."""
    from planner.sim import verify

    def report(ok, step, mm):
        return SimpleNamespace(passed=ok, verdict="PASS: fine" if ok else "FAIL: object dropped", failed_step=step,
                               failed_at_state=False, max_drift_mm=mm, max_drift_deg=mm, stopped_after=None)

    outcome = {"pybullet": report(True, None, 0.5), "mujoco": report(False, 2, 40.0)}
    monkeypatch.setattr(verify, "replay_directions",
                        lambda plan, hand, directions, workers=None, engine=None, **kw: [outcome[engine]] * len(directions))
    monkeypatch.setattr(verify, "as_written", lambda plan: plan)
    v = verify.verify_plan(None, None, [("palm_down", (0, 0, 9.81))], engine="both")
    assert not v.passed and v.first_failure() == ("palm_down", 2, "mujoco: FAIL: object dropped", False)
    assert v.directions[0][5] == 40.0 and [e for e, _ in v.by_engine] == ["pybullet", "mujoco"]
    outcome["mujoco"] = report(True, None, 1.5)
    rec = verify.verify_plan(None, None, [("palm_down", (0, 0, 9.81))], engine="both").record()
    assert rec["engine"] == "both" and rec["directions"]["palm_down"]["max_drift_mm"] == 1.5
    assert rec["engines"]["pybullet"]["palm_down"]["max_drift_mm"] == 0.5


@pytest.mark.needs_pybullet("--engine both replays in pybullet too")
def test_a_failed_verification_has_the_rows_up_to_the_failing_direction(monkeypatch):
    """The first direction in order that fails decides: the rows after it are left out
    whether their replays stopped, failed or passed (which of them finished depends on the
    timing); with two engines the second's failing rows merge with the first's by name."""
    from planner.sim import verify

    def report(ok, step, mm, stopped=None):
        verdict = "STOPPED" if stopped is not None else "PASS: fine" if ok else "FAIL: object dropped"
        return SimpleNamespace(passed=ok and stopped is None, verdict=verdict, failed_step=step, failed_at_state=False,
                               max_drift_mm=mm, max_drift_deg=mm, stopped_after=stopped)

    dirs = [("palm_down", (0, 0, 9.81)), ("palm_up", (0, 0, -9.81)), ("side", (9.81, 0, 0)), ("other", (0, 9.81, 0))]
    outcome = {"pybullet": [report(True, None, 0.5)] * 4,
               "mujoco": [report(True, None, 1.0), report(False, 3, 40.0), report(False, 1, 30.0),
                          report(False, None, 0.7, stopped=2)]}
    monkeypatch.setattr(verify, "replay_directions",
                        lambda plan, hand, directions, workers=None, engine=None, **kw: outcome[engine])
    monkeypatch.setattr(verify, "as_written", lambda plan: plan)
    v = verify.verify_plan(None, None, dirs, engine="both")
    assert not v.passed and v.first_failure() == ("palm_up", 3, "mujoco: FAIL: object dropped", False)
    assert [d[0] for d in v.directions] == ["palm_down", "palm_up"] and v.directions[1][5] == 40.0
    assert v.directions[0][5] == 1.0  # the larger drift of the two engines
    outcome["mujoco"][3] = None  # not started
    v = verify.verify_plan(None, None, dirs, engine="mujoco")
    assert not v.passed and [d[0] for d in v.directions] == ["palm_down", "palm_up"]


@pytest.mark.needs_pybullet("MuJoCo hidden, the engine left is pybullet")
def test_an_engine_not_installed_is_one_line(monkeypatch, capsys):
    """Asking for an engine whose package is missing is a one-line SimulationError naming the
    package to install (the CLI: exit 2, no traceback); an unknown name lists the valid ones."""
    import planner.sim.engine as engine
    from planner.cli import main
    from planner.sim.verify import engines_of

    real = engine.engine_installed
    monkeypatch.setattr(engine, "engine_installed", lambda name: name != "mujoco" and real(name))
    with pytest.raises(SimulationError, match=r"^physics engine 'mujoco' is not installed: pip install mujoco"):
        engines_of("both")
    assert engine.default_engine() == "pybullet" or not real("pybullet")
    code = main(["replay", str(PLAN), "--engine", "mujoco"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "pip install mujoco" in err[0]
    with pytest.raises(InputError, match="choose from: pybullet, mujoco, both"):
        engines_of("ode")


def test_friction_is_as_stiff_as_mujocos_stiffest_constraint():
    """The engine's impratio scales the contacts' friction regularizer, (1 - d)/(d impratio),
    down to that of a constraint at MuJoCo's largest impedance (mjMAXIMP)."""
    import mujoco

    from planner.sim.engine_mujoco import friction_impratio
    from planner.sim.mujoco_model import CONTACT_SOLIMP

    d, top = CONTACT_SOLIMP[1], mujoco.mjMAXIMP
    ir = friction_impratio()
    assert abs((1 - d) / (d * ir) - (1 - top) / top) < 1e-12 and 100 < ir < 102


@pytest.mark.needs_pybullet("films are drawn by pybullet's TinyRenderer")
def test_a_mujoco_replay_is_filmed_where_mujoco_has_the_object(tmp_path):
    """A MuJoCo replay's GIF is drawn from a pybullet mirror of MuJoCo's state: as the object
    drops under a crushing gravity, the object's pixels (its colour) move by pixels between
    the first and the last frame (a mirror left at the planned pose would not move)."""
    import numpy as np
    from PIL import Image

    from planner.sim.render import OBJECT_RGBA, rgb255
    from planner.sim.replay import replay_plan

    gif = tmp_path / "drop.gif"
    r = replay_plan(str(PLAN), engine="mujoco", gravity=CRUSHING_G, gif=str(gif), gif_every=4, width=160, height=120)
    assert r.dropped and r.gif_frames >= 2
    im = Image.open(gif)
    rows = []
    for k in (0, im.n_frames - 1):
        im.seek(k)
        rgb = np.asarray(im.convert("RGB"), float)
        shade = rgb / np.maximum(rgb.max(axis=2, keepdims=True), 1.0)  # the object's hue, any lighting
        ref = np.array(rgb255(OBJECT_RGBA), float) / max(rgb255(OBJECT_RGBA))
        mask = np.linalg.norm(shade - ref, axis=2) < 0.08
        assert mask.sum() > 20, k
        rows.append(np.nonzero(mask)[0].mean())
    assert abs(rows[0] - rows[1]) > 2.0, rows  # pixels of a 120-pixel-high picture
