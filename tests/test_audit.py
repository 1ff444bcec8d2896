"""`regrasp verify` (planner.audit): a plan edited and resealed with a fresh digest is
intact but wrong; every such edit must be refused by `verify` and by `replay` and `view`
before they start, naming the state or step, the finger and the check. Plans the planner
wrote pass."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from planner.audit import audit_plan
from planner.cli import main
from planner.plan import read_plan
from planner.plan_data import integrity_record
from planner.resources import bundled_grasp

PAIRS = {
    "icub box": ("icub/box_ir2m.yaml", "icub/box_parallel_extension.yaml", ()),
    "allegro sphere execution": ("allegro/sphere_tripod.yaml", "allegro/sphere_four_finger.yaml",
                                 ("--execution", "--no-verify")),
}


@pytest.fixture(scope="module")
def plans(tmp_path_factory):
    folder = tmp_path_factory.mktemp("audit")
    out = {}
    for name, (a, b, extra) in PAIRS.items():
        path = folder / (name.replace(" ", "_") + ".json")
        assert main(["plan", str(bundled_grasp(a)), str(bundled_grasp(b)), "-o", str(path), *extra]) == 0
        out[name] = path
    return out


def _reseal(data: dict, path, closures: bool = True) -> None:
    """A careful forger's edit: closures re-derived from the edited patches, digest renewed."""
    if closures:
        from planner.model import Friction
        from planner.closure import grasp_closure

        fr = Friction(**data["friction"])
        for s in data["states"]:
            patches = {f: (np.array(p["points"]), np.array(p["normals"])) for f, p in s["patches"].items()}
            c = grasp_closure(patches, fr)
            s["closure"] = {"is_force_closure": bool(c.is_force_closure), "metric": float(c.metric)}
    data["integrity"] = integrity_record(data)
    path.write_text(json.dumps(data))


def _data(plans, name="icub box") -> dict:
    return json.loads(plans[name].read_text())


def test_plans_the_planner_wrote_pass(plans, capsys):
    for path in plans.values():
        rep = audit_plan(read_plan(path))
        assert rep.ok, rep.problems
        # it checked what it says: every state, step, contact, the two input grasps and both ends
        assert rep.checked["states"] >= 3 and rep.checked["steps"] >= 2 and rep.checked["waypoints"] > 20
        assert rep.checked["input grasps"] == 2 and rep.checked["grasp ends"] == 2
        assert main(["verify", str(path)]) == 0
    assert "plan verified" in capsys.readouterr().out


def _first_touching(data, finger):
    return next(i for i, s in enumerate(data["states"]) if finger in s["patches"])


def _edit_thumb_off(d):  # the thumb's contact 3 cm off the object in every state
    for s in d["states"]:
        if "thumb" in s["patches"]:
            p = s["patches"]["thumb"]
            p["points"] = (np.array(p["points"]) - 0.03 * np.array(p["normals"])).tolist()


def _edit_inside(d):  # every contact inside the object
    for s in d["states"]:
        for p in s["patches"].values():
            p["points"] = (0.5 * np.array(p["points"])).tolist()


def _edit_normal(d):  # index's normals at 90 deg to its face's
    for s in d["states"]:
        if "index" in s["patches"]:
            n = np.array(s["patches"]["index"]["normals"])
            side = np.cross(n, [0.3, 0.5, 0.8])
            s["patches"]["index"]["normals"] = (side / np.linalg.norm(side, axis=1, keepdims=True)).tolist()


def _edit_moved(d):
    d["object"]["position"][0] += 0.01


def _edit_mass(d):
    d["object"]["mass_kg"] *= 10


def _edit_removable(d):
    for s in d["states"]:
        s["removable"] = sorted(s["patches"])


def _edit_cut3(d):
    d["states"], d["steps"] = d["states"][:3], d["steps"][:2]
    d["alternatives"] = []


def _edit_initial_only(d):
    d["states"], d["steps"], d["alternatives"] = d["states"][:1], [], []


def _edit_land_through(d):  # a landing path curls through the object
    k = next(i for i, s in enumerate(d["steps"]) if s["action"] == "land")
    path = np.array(d["steps"][k]["path"])
    path[1:-1, 1:] += 0.6 * np.sin(np.linspace(0, np.pi, len(path)))[1:-1, None]
    d["steps"][k]["path"] = path.tolist()


def _edit_flexed(d):  # index flexed 0.25 rad further into the object, everywhere
    for s in d["states"]:
        s["q"]["index_2"] += 0.25
    for st in d["steps"]:
        if st["finger"] == "index":
            col = st["joints"].index("index_2")
            for w in st["path"]:
                w[col] += 0.25


def _edit_pinky(d):  # a step names a finger the hand lacks
    k = next(i for i, s in enumerate(d["steps"]) if s["finger"] == "ring")
    d["steps"][k]["finger"] = "pinky"


def _edit_schema1(d):  # version 1 has no digest to check: the physics must still be checked
    _edit_moved(d)
    d["schema_version"] = 1


EDITS = {
    "thumb 3 cm off": (_edit_thumb_off, "thumb"),
    "contacts inside": (_edit_inside, "off the object's surface"),
    "normal not its face's": (_edit_normal, "normal"),
    "object moved 1 cm": (_edit_moved, "object.position"),
    "mass x10": (_edit_mass, "mass_kg"),
    "every finger removable": (_edit_removable, "removable"),
    "cut to 3 states": (_edit_cut3, "final grasp"),
    "initial state only": (_edit_initial_only, "final grasp"),
    "landing path through the object": (_edit_land_through, "into the object"),
    "finger flexed into the object": (_edit_flexed, "index"),
    "unknown finger in a step": (_edit_pinky, "pinky"),
    "schema 1 resealed": (_edit_schema1, "object.position"),
}


@pytest.mark.parametrize("edit", sorted(EDITS))
def test_resealed_wrong_plans_are_refused_by_verify_and_replay(plans, tmp_path, capsys, edit):
    fn, needle = EDITS[edit]
    data = _data(plans)
    fn(data)
    bad = tmp_path / "plan.json"
    _reseal(data, bad)
    if data.get("schema_version") == 1:
        data.pop("integrity", None)
        bad.write_text(json.dumps(data))
    before = bad.read_bytes()
    code = main(["verify", str(bad)])
    out = capsys.readouterr()
    assert code in (1, 2), out
    text = out.out + out.err
    assert needle in text, text
    if code == 1:  # the physics checks ran: one FAIL line per problem, each naming its place
        fails = [line for line in out.out.splitlines() if line.startswith("FAIL ")]
        assert fails and all(("states[" in f or "steps[" in f or "object." in f or "friction." in f or "summary." in f)
                             for f in fails)
    # replay refuses it before simulating anything, in one line
    assert main(["replay", str(bad)]) == 2
    err = [line for line in capsys.readouterr().err.strip().splitlines() if "warning: " not in line]
    assert len(err) == 1 and "error" in err[0] and (code == 2 or "physics check" in err[0]), err
    assert bad.read_bytes() == before


def test_view_refuses_a_wrong_plan_and_writes_nothing(plans, tmp_path, capsys):
    data = _data(plans)
    _edit_thumb_off(data)
    bad = tmp_path / "plan.json"
    _reseal(data, bad)
    page = tmp_path / "page.html"
    assert main(["view", str(bad), "-o", str(page)]) == 2
    assert "physics check" in capsys.readouterr().err
    assert not page.exists()


def test_the_execution_plan_edited_in_friction_is_refused(plans, tmp_path, capsys):
    data = _data(plans, "allegro sphere execution")
    data["friction"]["mu"] = 100.0
    bad = tmp_path / "plan.json"
    _reseal(data, bad, closures=False)
    # read_plan re-derives every state's closure from its patches with the file's friction
    assert main(["verify", str(bad)]) == 2
    assert "closure" in capsys.readouterr().err
    # with the closures consistent (data checked structurally only), the audit names the
    # friction against the recorded inputs
    from planner.plan import plan_from_data

    rep = audit_plan(plan_from_data(data, plans["allegro sphere execution"]))
    assert not rep.ok and any(p.startswith("friction.mu") for p in rep.problems), rep.problems


def test_a_path_into_the_neighbouring_finger_is_refused(plans):
    """Ring abducted mid-path toward the little finger: within its limit it touches little
    (0.16 mm, tolerated), past the limit it overlaps; both the limit and the overlap are named."""
    from planner.hand import Hand
    from planner.plan import plan_from_data

    data = _data(plans)
    hand = Hand.load("icub_right")
    k = next(i for i, s in enumerate(data["steps"]) if s["action"] == "move" and s["finger"] == "ring")
    col = data["steps"][k]["joints"].index("ring_0")
    path = np.array(data["steps"][k]["path"])
    path[1:-1, col] = hand.upper[hand.joint_names.index("ring_0")] + 0.4
    data["steps"][k]["path"] = path.tolist()
    rep = audit_plan(plan_from_data(data, plans["icub box"]), hand)
    mine = [p for p in rep.problems if p.startswith(f"steps[{k}] (move ring)")]
    assert any("ring_0 outside the hand's joint limits" in p for p in mine), rep.problems
    assert any("overlap" in p and "little" in p for p in mine), rep.problems


def test_a_no_motion_plan_is_checked_like_any_plan(plans, tmp_path, capsys):
    """A file's parameters do not switch a check off: a plan whose parameters say it was made
    without motion planning has its straight segments checked like any path, by verify, replay
    and view alike."""
    data = _data(plans)
    data["parameters"]["motion"] = False
    _edit_land_through(data)
    bad = tmp_path / "straight.json"
    _reseal(data, bad)
    assert main(["verify", str(bad)]) == 1
    assert "into the object" in capsys.readouterr().out
    assert main(["replay", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "physics check" in err and "into the object" in err, err
    page = tmp_path / "page.html"
    assert main(["view", str(bad), "-o", str(page)]) == 2
    assert not page.exists()


def _claim_bottleneck(d):
    d["summary"]["bottleneck_metric"] = 99.0


def _claim_mean(d):
    d["summary"]["mean_metric"] *= 1.5


def _claim_grip(d):  # no force needed, a hundred times the weight held
    for s in d["states"]:
        s["grip_force_n"] = 0.0
        s["grip_force_by_gravity_n"] = {k: 0.0 for k in s["grip_force_by_gravity_n"]}
        s["hold_factor_by_gravity"] = {k: 100.0 for k in s["hold_factor_by_gravity"]}
    d["summary"]["bottleneck_grip_force_n"] = 0.0


def _claim_hold(d):
    s = d["states"][len(d["states"]) // 2]
    s["hold_factor_by_gravity"] = {k: v * 3 for k, v in s["hold_factor_by_gravity"].items()}


def _claim_verified(d):  # a verification that never ran
    names = [g["name"] for g in d["parameters"]["gravity_directions"]]
    d["summary"]["verification"] = {"passed": True, "attempts": 1, "rejected": [],
                                    "directions": {n: {"passed": True, "max_drift_mm": 0.1, "max_drift_deg": 0.1}
                                                   for n in names}}


def _claim_verified_wrong_directions(d):
    _claim_verified(d)
    d["parameters"]["verify"] = True
    d["summary"]["verification"]["directions"].popitem()


def _claim_hold_factor_zero(d):  # a parameter that would switch the hold check off
    d["parameters"]["hold_factor"] = 0


def _claim_hold_factor_low(d):
    d["parameters"]["hold_factor"] = 1.0


def _claim_verify_without_record(d):  # "verified" in the parameters, no verification in the summary
    d["parameters"]["verify"] = True
    d["summary"].pop("verification", None)


def _claim_fewer_directions(d):  # two of the gravity set's six directions, every state's claims trimmed to match
    keep = [g["name"] for g in d["parameters"]["gravity_directions"][:2]]
    d["parameters"]["gravity_directions"] = d["parameters"]["gravity_directions"][:2]
    for s in d["states"]:
        for key in ("grip_force_by_gravity_n", "hold_factor_by_gravity"):
            if s.get(key):
                s[key] = {n: v for n, v in s[key].items() if n in keep}
        if s.get("grip_force_by_gravity_n"):
            s["grip_force_n"] = max(s["grip_force_by_gravity_n"].values())
    d["summary"]["bottleneck_grip_force_n"] = max(s["grip_force_n"] for s in d["states"])


def _claim_order(d):  # the gait sequence other tools read, its first two moves swapped
    d["summary"]["order"][0], d["summary"]["order"][1] = d["summary"]["order"][1], d["summary"]["order"][0]


CLAIMS = {
    "parameters.hold_factor 0": (_claim_hold_factor_zero, "parameters.hold_factor"),
    "parameters.hold_factor below execution's": (_claim_hold_factor_low, "parameters.hold_factor"),
    "bottleneck metric 99": (_claim_bottleneck, "summary.bottleneck_metric"),
    "mean metric x1.5": (_claim_mean, "summary.mean_metric"),
    "grip forces 0, hold factors 100": (_claim_grip, "grip_force"),
    "hold factors x3 at one state": (_claim_hold, "hold_factor_by_gravity"),
    "verification that never ran": (_claim_verified, "summary.verification"),
    "verification over other directions": (_claim_verified_wrong_directions, "summary.verification.directions"),
    "verify: true without a verification": (_claim_verify_without_record, "summary.verification: missing"),
    "two of the gravity set's six directions": (_claim_fewer_directions, "parameters.gravity_directions"),
    "the order's first two moves swapped": (_claim_order, "summary.order[0]"),
}


@pytest.mark.parametrize("edit", sorted(CLAIMS))
def test_recorded_claims_are_recomputed_not_trusted(plans, tmp_path, capsys, edit):
    """Numbers a plan claims (metrics, grip forces, hold factors, a verification) are re-derived
    from its contacts and the hand by verify, and replay refuses a plan whose claims are wrong."""
    fn, needle = CLAIMS[edit]
    data = _data(plans, "allegro sphere execution")
    fn(data)
    bad = tmp_path / "plan.json"
    _reseal(data, bad, closures=False)
    assert main(["verify", str(bad)]) == 1
    out = capsys.readouterr().out
    assert any(line.startswith("FAIL " + needle) or (line.startswith("FAIL ") and needle in line)
               for line in out.splitlines()), out
    assert main(["replay", str(bad)]) == 2
    assert "physics check" in capsys.readouterr().err


@pytest.mark.parametrize("key, value, words", [
    ("strategy", "bogus", "unknown strategy 'bogus'; valid: graph, greedy"),
    ("rank", "fastest", "unknown rank 'fastest'; valid: metric, grip"),
    ("gravity_set", 99, "unknown gravity set 99; valid: 1, 2, 6, 7"),
    ("gravity_set", True, "unknown gravity set True; valid: 1, 2, 6, 7"),
    ("contact_model", "bogus", "unknown contact model 'bogus'; valid: patch, mean, link"),
    ("execution", "yes", "expected true or false, got 'yes'"),
    ("verify", 1, "expected true or false, got 1"),
])
def test_a_parameter_the_planner_never_writes_is_refused_in_one_line(plans, tmp_path, capsys, key, value, words):
    """The parameters verify checks a plan against (its contact model, gravity set, whether it
    was verified) are names and flags the planner writes: any other value is refused when the
    plan is read, naming the key and the valid choices."""
    data = _data(plans, "allegro sphere execution")
    data["parameters"][key] = value
    bad = tmp_path / "plan.json"
    _reseal(data, bad, closures=False)
    assert main(["verify", str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"parameters.{key}: {words}" in err[0], err


def test_a_mean_contact_below_a_curved_surface_is_the_model_not_an_error(tmp_path):
    """Execution mode records one mean contact per finger: on a 22 mm ball the thumb's
    patch spans two phalanges and its mean lies 1 mm below the surface (an exp8 plan whose
    fresh replay was refused for it). The audit allows a mean contact the depth the hand's
    own patch mean has at the state's joints, and still refuses one moved off the surface."""
    from pathlib import Path

    from planner.options import PlanOptions
    from planner.regrasp import plan_regrasp

    data = Path(__file__).parent / "data" / "grasps"
    res = plan_regrasp(data / "icub_sphere22_i.yaml", data / "icub_sphere22_f.yaml",
                       PlanOptions.for_execution(verify=False, motion=False))
    report = audit_plan(res.plan, paths=False)
    assert report.ok, report.problems
    good = tmp_path / "good.json"
    good.write_text(json.dumps(res.plan.to_dict()))
    d = json.loads(good.read_text())
    for st in d["states"]:  # the thumb's mean contact 2 mm deeper, toward the ball's centre
        if "thumb" in st["patches"]:
            p = np.asarray(st["patches"]["thumb"]["points"][0])
            st["patches"]["thumb"]["points"][0] = (p - 0.002 * p / np.linalg.norm(p)).tolist()
    bad = tmp_path / "bad.json"
    _reseal(d, bad)
    problems = audit_plan(read_plan(bad), paths=False).problems
    assert any("thumb" in p and "off the object's surface" in p for p in problems), problems


def test_a_mean_contact_across_a_box_edge_keeps_its_mean_normal(tmp_path):
    """The bundled Allegro box pair planned for execution: the index finger's patch spans two
    faces, so its mean contact's normal (the mean of the patch's normals) is 21 deg from the
    face under the mean point, and `verify` refused the plan the planner had verified in
    pybullet. The audit takes the mean of the hand's own patch normals as a mean contact's
    reference, and still refuses that normal turned by 30 deg."""
    from planner.options import PlanOptions
    from planner.regrasp import plan_regrasp

    root = Path(__file__).resolve().parents[1] / "grasps" / "allegro"
    res = plan_regrasp(root / "box_four_finger.yaml", root / "box_tripod.yaml",
                       PlanOptions.for_execution(verify=False, motion=False))
    report = audit_plan(res.plan, paths=False)
    assert report.ok, report.problems
    d = json.loads(json.dumps(res.plan.to_dict()))
    turned = 0
    for st in d["states"]:
        patch = st["patches"].get("index")
        if patch is None:
            continue
        n = np.asarray(patch["normals"][0])
        t = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
        t /= np.linalg.norm(t)
        a = np.radians(30.0)
        patch["normals"][0] = (np.cos(a) * n + np.sin(a) * t).tolist()  # unit, 30 deg off
        turned += 1
    assert turned
    bad = tmp_path / "bad.json"
    _reseal(d, bad)
    problems = audit_plan(read_plan(bad), paths=False).problems
    assert any("index" in p and "contact normal" in p for p in problems), problems


def test_a_replay_tells_a_recorded_verification_it_did_not_write(capsys):
    """The replay is deterministic: `replay --gravity-set` compares the plan's recorded
    verification (verdict and drifts per direction) with what it measured now, and says when
    they differ (a record edited or made up), instead of trusting it."""
    from types import SimpleNamespace

    from planner.commands import _compare_verification

    def report(passed, mm, deg):
        return SimpleNamespace(passed=passed, max_drift_mm=mm, max_drift_deg=deg)

    result = SimpleNamespace(directions=[("palm_down", None, report(True, 0.238, 0.775)),
                                         ("palm_up", None, report(True, 0.249, 0.685))])

    def plan(directions):
        return SimpleNamespace(summary={"verification": {"passed": True, "directions": directions}})

    same = {"palm_down": {"passed": True, "max_drift_mm": 0.238, "max_drift_deg": 0.775},
            "palm_up": {"passed": True, "max_drift_mm": 0.249, "max_drift_deg": 0.685}}
    _compare_verification(plan(same), result)
    assert "same verdicts and drifts" in capsys.readouterr().out
    for edit in ({"max_drift_mm": 0.0}, {"max_drift_deg": 9.0}, {"passed": False}, {"max_drift_mm": "0"}):
        forged = {**same, "palm_down": {**same["palm_down"], **edit}}
        _compare_verification(plan(forged), result)
        out = capsys.readouterr().out
        assert out.startswith("warning:") and "palm_down" in out and "palm_up" not in out.split("in ")[1], out


def test_a_plan_records_its_hand_and_is_refused_after_the_urdf_changed(tmp_path, capsys):
    """The plan records the sha256 of its hand's files (hand.yaml, URDF, meshes); after the
    URDF is edited, verify fails naming it and replay refuses the plan in one line."""
    import shutil

    import yaml

    from planner.resources import hand_dir

    shutil.copytree(hand_dir("icub_right"), tmp_path / "hand")
    grasps = []
    for name in PAIRS["icub box"][:2]:
        data = yaml.safe_load(bundled_grasp(name).read_text())
        data["hand"] = "hand/hand.yaml"
        grasps.append(tmp_path / Path(name).name)
        grasps[-1].write_text(yaml.safe_dump(data, sort_keys=False))
    plan = tmp_path / "plan.json"
    assert main(["plan", *map(str, grasps), "--no-motion", "-o", str(plan)]) == 0
    files = json.loads(plan.read_text())["hand"]["files"]
    assert set(files) == {"hand.yaml", "icub_right.urdf"} and all(len(v) == 64 for v in files.values())
    assert main(["verify", str(plan)]) == 0
    capsys.readouterr()
    urdf = tmp_path / "hand" / "icub_right.urdf"
    urdf.write_text(urdf.read_text().replace('effort="0.5"', 'effort="0.6"', 1))
    assert main(["verify", str(plan)]) == 1
    assert "FAIL hand.files: icub_right.urdf" in capsys.readouterr().out
    assert main(["replay", str(plan)]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if "warning:" not in line]
    assert len(err) == 1 and "icub_right.urdf" in err[0], err


def test_verify_says_what_it_checks_before_a_large_plan(plans, monkeypatch, caplog, capsys):
    """A plan of thousands of states takes a minute to check (2,701 states: 69.5 s): verify says
    first what it is checking, as a progress line (the `planner` log, shown on a terminal)."""
    import logging

    import planner.commands as commands

    monkeypatch.setattr(commands, "LARGE_PLAN_WAYPOINTS", 10)
    with caplog.at_level(logging.INFO, logger="planner"):
        assert main(["verify", str(plans["icub box"])]) == 0
    said = [r.getMessage() for r in caplog.records if r.getMessage().startswith("checking ")]
    plan = read_plan(plans["icub box"])
    assert said == [f"checking {len(plan.states)} states, {len(plan.steps)} steps, "
                    f"{sum(len(s.path) for s in plan.steps)} path waypoints (about 1 s or more)"], said
    caplog.clear()
    monkeypatch.setattr(commands, "LARGE_PLAN_WAYPOINTS", 10**9)
    with caplog.at_level(logging.INFO, logger="planner"):
        assert main(["verify", str(plans["icub box"])]) == 0
    assert not [r for r in caplog.records if r.getMessage().startswith("checking ")]


def _verify_lines(capsys, data, tmp_path, closures=False) -> tuple[int, str]:
    bad = tmp_path / "plan.json"
    _reseal(data, bad, closures=closures)
    code = main(["verify", str(bad)])
    out = capsys.readouterr()
    assert "Traceback" not in out.err
    return code, out.out + out.err


def test_listed_gravity_directions_must_cover_what_the_parameters_ask(plans, tmp_path, capsys):
    """The directions listed hold the parameters' ones (more is stricter and was written: a
    gravity set of 1 listed palm up too until 2026-11-30); a list without the parameters it
    comes from is refused (deleting them let a file list 2 of 6); a plan older than the list
    (a --gravity plan before 2026-11-30) is not held to it."""
    data = _data(plans, "allegro sphere execution")
    data["parameters"]["gravity_set"] = 1  # six listed, one asked
    assert _verify_lines(capsys, data, tmp_path)[0] == 0
    data = _data(plans, "allegro sphere execution")
    _claim_fewer_directions(data)
    del data["parameters"]["gravity_set"], data["parameters"]["gravity"]
    code, text = _verify_lines(capsys, data, tmp_path)
    assert code == 1 and "FAIL parameters.gravity_directions: listed without the gravity or gravity_set" in text, text
    data = _data(plans)  # no gravity: made without one
    data["parameters"]["gravity"] = [0.0, 0.0, 9.81]
    data["parameters"].pop("gravity_directions", None)
    assert _verify_lines(capsys, data, tmp_path)[0] == 0


@pytest.mark.parametrize("value", [[0.0, 12.3], [0.0, 0.0, 9.81, 1.0], "down", [0.0, 0.0, 1e9]])
def test_a_gravity_parameter_that_is_no_vector_is_one_line(plans, tmp_path, capsys, value):
    """parameters.gravity of 2 or 4 numbers was a numpy broadcast traceback in verify and replay."""
    data = _data(plans)
    data["parameters"]["gravity"] = value
    code, text = _verify_lines(capsys, data, tmp_path)
    assert code == 2 and "parameters.gravity" in text and len(text.strip().splitlines()) == 1, text


@pytest.mark.parametrize("value", [5, "index:lift", {"a": 1}, [1, 2]])
def test_a_summary_order_that_is_no_list_of_moves_is_a_problem(plans, tmp_path, capsys, value):
    """summary.order: 5 was a TypeError traceback in verify and replay; a string was compared
    character by character."""
    data = _data(plans)
    data["summary"]["order"] = value
    code, text = _verify_lines(capsys, data, tmp_path)
    assert code == 1 and "FAIL summary.order: not a list of moves" in text, text


def test_plans_the_greedy_strategy_writes_pass_without_a_verification(tmp_path, capsys):
    """The greedy strategy replays nothing: its execution plan has no verification record and
    verify does not ask for one (it does for the graph search's: the tests above)."""
    out = tmp_path / "greedy.json"
    assert main(["plan", str(bundled_grasp("icub/box_parallel_extension.yaml")), str(bundled_grasp("icub/box_ir2m.yaml")),
                 "--execution", "--strategy", "greedy", "--no-motion", "-o", str(out)]) == 0
    data = json.loads(out.read_text())
    assert data["parameters"]["verify"] is True and "verification" not in data["summary"]
    capsys.readouterr()
    assert main(["verify", str(out)]) == 0, capsys.readouterr().out
    data["parameters"]["strategy"] = "graph"  # the same file said to be the graph search's: it would have one
    code, text = _verify_lines(capsys, data, tmp_path)
    assert code == 1 and "FAIL summary.verification: missing" in text, text
