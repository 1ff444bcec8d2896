"""Whole-hand grasps (issue 34): patches keyed by their owner (a finger or the palm) with the
link of every point, the "link" contact model, the palm as a rigid contact that is never
lifted, grasp files that require or forbid it, and the ball resting in the palm of each
bundled hand regrasped to another thumb contact, planned for execution and held in pybullet."""

from __future__ import annotations

import json
import pickle
from pathlib import Path

import numpy as np
import pytest
import yaml

from planner.audit import audit_plan
from planner.cli import main
from planner.closure import apply_contact_model, grasp_closure, min_grip_force, removable_fingers
from planner.errors import InputError, NoSequenceError, PlannerError
from planner.grasp import load_grasp, parse_grasp
from planner.graph import LIFTED, GaitProblem, Slot
from planner.gravity import named_gravity
from planner.model import PALM, Friction, Patch, holders
from planner.options import PlanOptions
from planner.plan import read_plan
from planner.plan_data import integrity_record
from planner.realization import realize
from planner.regrasp import plan_regrasp
from planner.resources import bundled_grasp
from planner.sim.replay import replay_plan

FR = Friction(0.5, 0.0, 8)
BALL_PAIRS = {
    "icub": ("icub/ball_palm_thumb_wrap.yaml", "icub/ball_palm_thumb_across.yaml"),
    "allegro": ("allegro/ball_palm_thumb_tip.yaml", "allegro/ball_palm_thumb_distal.yaml"),
}


# --------------------------------------------------------------------------- the patch type


def test_patch_is_a_pair_that_knows_its_links():
    p = Patch(np.zeros((3, 3)), np.tile([0.0, 0.0, 1.0], (3, 1)), ["a", "a", "b"])
    points, normals = p  # unpacks as before
    assert len(p) == 2 and points is p.points and normals is p.normals
    assert p.links == ("a", "a", "b")
    assert [(link, list(idx)) for link, idx in p.link_groups()] == [("a", [0, 1]), ("b", [2])]
    assert pickle.loads(pickle.dumps(p)).links == p.links
    plain = Patch(np.zeros((2, 3)), np.ones((2, 3)))
    assert plain.links is None and [link for link, _ in plain.link_groups()] == [None]
    with pytest.raises(InputError, match="2 points but 3 links"):
        Patch(np.zeros((2, 3)), np.ones((2, 3)), ["a", "b", "c"])
    assert holders({"thumb": p, PALM: p, "index": p}) == ("thumb", "index")


def test_link_model_gives_one_contact_per_link_at_its_mean():
    """Analytic: three points on one link and two on another, with their own normals."""
    pts = np.array([[0.0, 0.0, 0.0], [0.002, 0.0, 0.0], [0.004, 0.0, 0.0], [0.0, 0.01, 0.0], [0.0, 0.012, 0.0]])
    nrm = np.array([[0.0, 0.0, 1.0]] * 3 + [[0.0, 1.0, 0.0], [0.0, 0.6, 0.8]])
    patch = Patch(pts, nrm, ["prox", "prox", "prox", "dist", "dist"])
    out = apply_contact_model({"f": patch}, "link")["f"]
    assert out.links == ("prox", "dist")
    np.testing.assert_allclose(out.points, [[0.002, 0.0, 0.0], [0.0, 0.011, 0.0]])
    np.testing.assert_allclose(out.normals[0], [0.0, 0.0, 1.0])
    np.testing.assert_allclose(out.normals[1], np.array([0.0, 1.6, 0.8]) / np.linalg.norm([0.0, 1.6, 0.8]))
    # the "mean" model puts one point between the links; a patch whose links are unknown is
    # one contact under "link" too
    mean = apply_contact_model({"f": patch}, "mean")["f"]
    assert mean.points.shape == (1, 3)
    unknown = apply_contact_model({"f": (pts, nrm)}, "link")["f"]
    np.testing.assert_allclose(unknown.points, mean.points)
    np.testing.assert_allclose(unknown.normals, mean.normals)


def _box_on_palm(half=0.02):
    """A cube of half-size ``half`` resting on the palm (four corner contacts pushing +z)
    and two fingers pressing its side faces along -x and +x."""
    palm = Patch(np.array([[sx * half, sy * half, -half] for sx in (-1, 1) for sy in (-1, 1)]),
                 np.tile([0.0, 0.0, 1.0], (4, 1)), ["palm"] * 4)
    left = Patch(np.array([[-half, 0.0, 0.0]]), np.array([[1.0, 0.0, 0.0]]), ["l1"])
    right = Patch(np.array([[half, 0.0, 0.0]]), np.array([[-1.0, 0.0, 0.0]]), ["r1"])
    return {"left": left, "right": right, PALM: palm}


def test_palm_holds_pushing_only_is_never_removable_and_not_capped():
    patches = _box_on_palm()
    assert grasp_closure(patches, FR).is_force_closure
    # each finger can go: the other one and the palm's friction still close the grasp?
    # No: without "left" nothing pushes +x except friction, which needs a normal force that
    # only gravity could give, so neither finger is removable; the palm never is.
    rem = removable_fingers(patches, FR)
    assert PALM not in rem
    # the weight pushing the cube onto the palm: the palm carries it, the fingers need not press
    W = 2.0
    assert min_grip_force(patches, FR, [0.0, 0.0, -W, 0.0, 0.0, 0.0]) == pytest.approx(0.0, abs=1e-9)
    # the weight pulling the cube off the palm: the fingers hold it by friction alone, W / (2 mu)
    # each (the palm cannot pull); within the 16-gon's inscribed cone (cos(pi/16))
    need = min_grip_force(patches, FR, [0.0, 0.0, W, 0.0, 0.0, 0.0])
    assert W / (2 * FR.mu) * (1 - 1e-6) <= need <= W / (2 * FR.mu * np.cos(np.pi / 16)) * (1 + 1e-6)
    # sideways (+x) the palm's friction helps only as far as something presses the cube onto it:
    # here nothing does, so the fingers hold the load as without the palm
    side = min_grip_force(patches, FR, [W, 0.0, 0.0, 0.0, 0.0, 0.0])
    without = min_grip_force({k: v for k, v in patches.items() if k != PALM}, FR, [W, 0.0, 0.0, 0.0, 0.0, 0.0])
    assert side == pytest.approx(without, rel=1e-6)


def test_graph_states_carry_the_palm_and_never_lift_it():
    """A finger lifts when the other fingers and the palm keep force closure: with the palm as
    a support the top finger of a three-finger grasp can go, without it the two point
    contacts left pinch along one line (no torsion) and the cube turns about it."""
    patches = _box_on_palm()
    top = Slot("top", "initial", [[0.0, 0.0, 0.02]], [[0.0, 0.0, -1.0]], links=["t1"])
    slots = {"left": (Slot("left", "initial", *patches["left"], links=patches["left"].links),),
             "right": (Slot("right", "initial", *patches["right"], links=patches["right"].links),),
             "top": (top,)}
    fr = Friction(0.5, 0.0, 8)
    with_palm = GaitProblem(("left", "right", "top"), slots, (0, 0, 0), (0, 0, LIFTED), fr, support={PALM: patches[PALM]})
    bare = GaitProblem(("left", "right", "top"), slots, (0, 0, 0), (0, 0, LIFTED), fr)
    lifted = (0, 0, LIFTED)
    assert PALM in with_palm.patches(lifted) and PALM not in bare.patches(lifted)
    assert all(a != "lift" or i < 3 for i, a, _ in with_palm.neighbours((0, 0, 0)))  # only fingers move
    assert grasp_closure(with_palm.patches(lifted), fr).is_force_closure
    assert not grasp_closure(bare.patches(lifted), fr).is_force_closure
    with pytest.raises(InputError, match="is a finger"):
        GaitProblem(("left", "right", "top"), slots, (0, 0, 0), (0, 0, 0), fr, support={"top": patches[PALM]})


# --------------------------------------------------------------------------- grasp files


def _grasp_data(rel: str) -> dict:
    return yaml.safe_load(bundled_grasp(rel).read_text())


def test_grasp_file_palm_key(tmp_path, capsys):
    data = _grasp_data("icub/ball_palm_thumb_wrap.yaml")
    g = realize(parse_grasp(data, bundled_grasp("icub/ball_palm_thumb_wrap.yaml")))
    assert g.ok and PALM in g.patches and g.patches[PALM].links == ("palm",) * len(g.patches[PALM].points)
    assert g.palm_summary()["holds"] and g.palm_summary()["touching_links"] == ["palm"]
    # the thumb is removable; palm up the palm carries the ball, so the fingers need not press
    assert "thumb" in g.removable
    R = np.asarray(g.obj.T_palm_obj)[:3, :3]
    up = np.r_[g.obj.mass_kg * R.T @ np.array([0.0, 0.0, -9.81]), np.zeros(3)]
    link = apply_contact_model(g.patches, "link")
    assert min_grip_force(link, g.friction, up) == pytest.approx(0.0, abs=1e-6)
    assert min_grip_force({k: v for k, v in link.items() if k != PALM}, g.friction, up) > 0.05
    # palm: free on a grasp whose palm touches is not as written; its closure has no palm
    free = realize(parse_grasp({**data, "palm": "free"}, tmp_path / "free.yaml"))
    assert PALM not in free.patches and any("palm: free" in p for p in free.problems)
    # palm: hold with the ball 5 mm off the palm: not as written, with the gap
    up = {**data, "object": {**data["object"], "position": [0.005, 0.008, 0.033]}}
    off = realize(parse_grasp(up, tmp_path / "off.yaml"))
    assert any("palm: hold, but the palm does not touch" in p and "5.0 mm" in p for p in off.problems)
    # a bad value: one line, exit 2, naming the file, the key and the valid choices
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump({**data, "palm": "maybe"}))
    assert main(["check", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "bad.yaml" in err and "palm" in err and "auto, hold, free" in err
    # check always says what the palm does
    assert main(["check", str(bundled_grasp("icub/box_ir2m.yaml"))]) == 0
    assert "palm     auto          0  never      does not touch" in capsys.readouterr().out


# --------------------------------------------------------------------------- the acceptance pairs


@pytest.mark.parametrize("hand", sorted(BALL_PAIRS))
def test_ball_in_palm_regrasp_is_planned_for_execution_and_holds(hand, tmp_path):
    """The ball resting in the palm, held by the palm and the fingers, regrasped to a grasp
    whose thumb lands elsewhere: planned with --execution for the hand held palm up, verified
    in pybullet before it is returned, and held again by a fresh replay; `verify` passes."""
    a, b = (bundled_grasp(x) for x in BALL_PAIRS[hand])
    out = tmp_path / "plan.yaml"
    assert main(["plan", str(a), str(b), "-o", str(out), "--execution", "--gravity", "palm_up"]) == 0
    plan = read_plan(out)
    assert yaml.safe_load(out.read_text())["schema_version"] == 3
    assert plan.parameters["contact_model"] == "link" and plan.summary["verification"]["passed"]
    assert all(s.palm_holds for s in plan.states)  # the palm never lifts
    assert any(s.finger == "thumb" and s.action == "lift" for s in plan.steps)
    first, last = plan.states[0].patches["thumb"], plan.states[-1].patches["thumb"]
    assert np.linalg.norm(first.points.mean(axis=0) - last.points.mean(axis=0)) > 0.005  # the thumb moved
    for s in plan.states:  # one contact per touching link, each naming its link
        for owner, patch in s.patches.items():
            assert patch.links is not None and len(set(patch.links)) == len(patch.links)
    assert audit_plan(plan).ok
    g = named_gravity("palm_up", realize(load_grasp(a)).hand)
    report = replay_plan(out, gravity=g)
    assert report.passed, report.verdict
    assert all(PALM in st.planned_fingers for st in report.states)


def test_palm_plans_are_audited(tmp_path):
    """An edit that moves the plan's palm contact, resealed, is refused by verify."""
    a, b = (bundled_grasp(x) for x in BALL_PAIRS["icub"])
    out = tmp_path / "plan.json"
    assert main(["plan", str(a), str(b), "-o", str(out), "--execution", "--gravity", "palm_up", "--no-verify"]) == 0
    original = out.read_text()

    def resealed(edit) -> list:
        data = json.loads(original)
        edit(data)
        fr = Friction(**data["friction"])
        for s in data["states"]:  # a careful forger: closures re-derived, digest renewed
            c = grasp_closure({f: (np.array(p["points"]), np.array(p["normals"])) for f, p in s["patches"].items()}, fr)
            s["closure"] = {"is_force_closure": bool(c.is_force_closure), "metric": float(c.metric)}
        data["integrity"] = integrity_record(data)
        out.write_text(json.dumps(data))
        return audit_plan(read_plan(out)).problems

    def move_palm(data):
        for s in data["states"]:
            s["patches"][PALM]["points"] = [[p[0] + 0.006, p[1], p[2]] for p in s["patches"][PALM]["points"]]

    problems = resealed(move_palm)
    assert any("patches.palm" in p for p in problems), problems

    def palm_removable(data):
        data["states"][0]["removable"] = sorted(data["states"][0]["removable"] + [PALM])

    problems = resealed(palm_removable)
    assert any("the palm is never removable" in p for p in problems), problems

    def drop_palm(data):
        for s in data["states"]:
            del s["patches"][PALM]

    problems = resealed(drop_palm)
    assert sum("the palm touches the object but the plan does not count it" in p for p in problems) == 1, problems


def test_execution_mode_accepts_the_mean_model_for_comparison():
    opts = PlanOptions.for_execution(contact_model="mean")
    assert opts.contact_model == "mean" and PlanOptions.for_execution().contact_model == "link"
    with pytest.raises(PlannerError, match="'link'"):
        PlanOptions.for_execution(contact_model="patch")


def test_refusal_says_the_palm_would_let_the_thumb_lift(tmp_path):
    """The ball 5 mm above the palm: the four fingers alone cannot hold it without the thumb,
    and the explanation says the palm would let the thumb lift, and how far the ball is."""
    files = []
    for rel in BALL_PAIRS["icub"]:
        data = _grasp_data(rel)
        data["palm"] = "auto"
        data["object"]["position"] = [0.005, 0.008, 0.033]
        path = tmp_path / rel.split("/")[1]
        path.write_text(yaml.safe_dump(data))
        files.append(path)
    g0, g1 = (realize(load_grasp(p)) for p in files)
    assert PALM not in g0.patches and g0.ok
    with pytest.raises(NoSequenceError) as err:
        plan_regrasp(g0, g1, PlanOptions.for_execution(max_rounds=0, verify=False, motion=False))
    text = str(err.value)
    assert "thumb cannot be lifted" in text and "resting the object on the palm would likely let thumb lift" in text
    assert "5.0 mm from it" in text


def test_verification_replays_the_directions_that_rejected_before_first(monkeypatch):
    """A direction that rejected an earlier sequence is replayed first (the others after it,
    as listed, in the same replays), and the rows come back in the planned order."""
    import planner.sim.verify as V

    calls = []

    def fake(plan, hand, directions, *, workers=None):
        names = [n for n, _ in directions]
        calls.append(names)
        rows = []
        for n in names:  # the rows up to the first failure in the order replayed (verify_plan's)
            rows.append((n, n != "bad", "v", None if n != "bad" else 2, False, 0.0, 0.0))
            if n == "bad":
                break
        return V.Verification(all(r[1] for r in rows), tuple(rows), 1.0)

    monkeypatch.setattr(V, "verify_plan", fake)
    dirs = [("a", (0, 0, 1)), ("bad", (0, 0, -1)), ("c", (1, 0, 0))]
    got = V.verify_suspects_first(None, None, dirs, {"bad"})
    assert calls == [["bad", "a", "c"]] and not got.passed and got.first_failure()[:2] == ("bad", 2)
    assert [r[0] for r in got.directions] == ["bad"]
    calls.clear()
    got = V.verify_suspects_first(None, None, dirs, {"c"})
    assert calls == [["c", "a", "bad"]] and [r[0] for r in got.directions] == ["a", "bad", "c"]
    assert got.first_failure()[:2] == ("bad", 2)
    calls.clear()
    got = V.verify_suspects_first(None, None, dirs, ["c", "bad", "c", "gone"])  # the latest rejection first
    assert calls == [["c", "bad", "a"]] and [r[0] for r in got.directions] == ["bad", "c"]
    calls.clear()
    V.verify_suspects_first(None, None, dirs, {"c", "bad"})  # a set has no order: by name
    assert calls == [["bad", "c", "a"]]
    calls.clear()
    good = [("a", (0, 0, 1)), ("c", (1, 0, 0)), ("d", (0, 1, 0))]
    got = V.verify_suspects_first(None, None, good, {"c"})
    assert calls == [["c", "a", "d"]] and got.passed and [r[0] for r in got.directions] == ["a", "c", "d"]
    calls.clear()
    V.verify_suspects_first(None, None, good, set())
    assert calls == [["a", "c", "d"]]


def test_a_finger_cannot_be_called_palm(tmp_path):
    """'palm' keys the palm's contacts, so a hand.yaml finger of that name is refused, naming
    the file and the key."""
    import shutil

    from planner.errors import SpecError
    from planner.hand import Hand
    from planner.resources import hand_dir

    src = hand_dir("icub_right")
    for f in src.iterdir():
        if f.is_file():
            shutil.copy(f, tmp_path / f.name)
    text = (tmp_path / "hand.yaml").read_text().replace("\n  little:\n", "\n  palm:\n")
    (tmp_path / "hand.yaml").write_text(text)
    with pytest.raises(SpecError, match=r"fingers\.palm.*names the hand's base links"):
        Hand.load(str(tmp_path / "hand.yaml"))


def test_explanations_merge_repeated_clauses_and_name_a_next_move():
    """The same reason for two fingers is one clause naming both, and the refusal ends with a
    move the user can make (here: let more fingers off the object at once)."""
    a, b = (realize(load_grasp(bundled_grasp(x))) for x in ("icub/sphere_four_finger.yaml", "icub/sphere_ir2m.yaml"))
    with pytest.raises(NoSequenceError) as err:
        plan_regrasp(a, b, PlanOptions.for_execution(max_rounds=0, max_lifted=1, verify=False, motion=False))
    text = str(err.value)
    assert "index and ring cannot be lifted in the initial grasp: too many fingers lifted" in text
    assert text.count("too many fingers lifted") == 1
    assert text.endswith("to go on: allow more fingers off the object at once (--max-lifted N)")


def test_schema_2_plans_still_read_verify_and_replay():
    """A plan written by the planner before whole-hand grasps (schema 2, commit 5b82ab1: the
    bundled cylinder pair in execution mode with one mean contact per finger, no links, no
    palm; tests/data/plans) reads, passes verify and replays palm down."""
    path = Path(__file__).parent / "data" / "plans" / "schema2_cylinder_execution.json"
    assert json.loads(path.read_text())["schema_version"] == 2
    plan = read_plan(path)
    assert plan.parameters["contact_model"] == "mean"
    assert all(p.links is None for s in plan.states for p in s.patches.values())
    assert all(not s.palm_holds for s in plan.states)
    assert audit_plan(plan).ok, audit_plan(plan).problems
    report = replay_plan(path, gravity=(0.0, 0.0, 9.81))
    assert report.passed, report.verdict


def test_plan_refuses_a_grasp_whose_palm_is_not_as_written(tmp_path, capsys):
    """`plan` refuses, in one line naming the file and the palm key, what `check` fails: the
    palm touching where the file says palm: free, or not touching where it says hold."""
    paths = {}
    for mode, z in (("free", 0.028), ("hold", 0.033)):
        for rel in BALL_PAIRS["icub"]:
            data = _grasp_data(rel)
            data["palm"] = mode
            data["object"]["position"] = [0.005, 0.008, z]
            p = tmp_path / f"{mode}_{rel.split('/')[1]}"
            p.write_text(yaml.safe_dump(data))
            paths.setdefault(mode, []).append(p)
    for mode, why in (("free", "palm: free, but the palm touches"), ("hold", "palm: hold, but the palm does not touch")):
        a, b = paths[mode]
        assert main(["plan", str(a), str(b), "--no-motion"]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and str(a) in err and why in err, err


def test_a_problem_extended_with_another_palm_support_is_refused():
    from planner.graph import Evaluator

    patches = _box_on_palm()
    slots = {"left": (Slot("left", "initial", *patches["left"]),), "right": (Slot("right", "initial", *patches["right"]),)}
    p = GaitProblem(("left", "right"), slots, (0, 0), (0, 0), FR, support={PALM: patches[PALM]})
    ev = Evaluator(p)
    ev.extend(p)  # the same support: fine
    moved = Patch(patches[PALM].points + [0.0, 0.0, 0.001], patches[PALM].normals, patches[PALM].links)
    with pytest.raises(InputError, match="support"):
        ev.extend(GaitProblem(("left", "right"), slots, (0, 0), (0, 0), FR, support={PALM: moved}))
    with pytest.raises(InputError, match="support"):
        ev.extend(GaitProblem(("left", "right"), slots, (0, 0), (0, 0), FR))


def test_the_api_takes_named_orientations():
    import planner

    a, b = (bundled_grasp(x) for x in BALL_PAIRS["icub"])
    named = planner.plan(a, b, execution=True, gravity="palm_up", verify=False, motion=False)
    vector = planner.plan(a, b, execution=True, gravity=(0.0, 0.0, -9.81), verify=False, motion=False)
    assert list(named.plan.parameters["gravity"]) == [0.0, 0.0, -9.81]
    assert named.plan.to_dict() == vector.plan.to_dict()


def test_synth_palm_on_a_hand_without_palm_geometry_is_one_line(tmp_path, capsys):
    import re as _re
    import shutil

    from planner.resources import hand_dir

    src = hand_dir("icub_right")
    for f in src.iterdir():
        if f.is_file():
            shutil.copy(f, tmp_path / f.name)
    urdf = tmp_path / "icub_right.urdf"
    text = urdf.read_text()
    palm = text.index('<link name="palm">')
    end = text.index("</link>", palm)
    urdf.write_text(text[:palm] + _re.sub(r"<collision>.*?</collision>", "", text[palm:end], flags=_re.S) + text[end:])
    obj = tmp_path / "ball.yaml"
    obj.write_text(yaml.safe_dump({"shape": "sphere", "size": [0.025], "mass_kg": 0.05}))
    out = tmp_path / "out"
    out.mkdir()
    assert main(["synth", str(tmp_path / "hand.yaml"), str(obj), "--palm", "-n", "1", "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "no palm collision geometry" in err, err
