"""Grasp files: schema validation, realization, the bundled library and `regrasp check`."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from planner.model import PALM
import pytest
import yaml

from planner.cli import main
from planner.closure import apply_contact_model, grasp_closure
from planner.errors import PlannerError, SpecError
from planner.grasp import SURFACE_TOL_M, load_grasp, load_hand
from planner.realization import PENETRATION_TOL_M, realize, realize_contact

ROOT = Path(__file__).resolve().parent.parent
GRASPS = sorted((ROOT / "grasps").rglob("*.yaml"))
BOX_PE = ROOT / "grasps/icub/box_parallel_extension.yaml"
BOX_IR2M = ROOT / "grasps/icub/box_ir2m.yaml"
PAIRS = [
    ("icub/box_parallel_extension.yaml", "icub/box_ir2m.yaml"),
    ("icub/cylinder_parallel_extension.yaml", "icub/cylinder_ir2m.yaml"),
    ("icub/pen_palmar_pinch.yaml", "icub/pen_writing_tripod.yaml"),
    ("allegro/box_four_finger.yaml", "allegro/box_tripod.yaml"),
]


@pytest.fixture(scope="module")
def realized():
    """Every library grasp realized once (realization is deterministic)."""
    return {p: realize(load_grasp(p)) for p in GRASPS}


# ---------------------------------------------------------------------------- library


def test_library_is_not_empty():
    """The library holds the demo pair and grasps for both hands."""
    assert BOX_PE in GRASPS and BOX_IR2M in GRASPS
    hands = {load_grasp(p).hand for p in GRASPS}
    assert {"icub_right", "allegro_right"} <= hands


@pytest.mark.parametrize("path", GRASPS, ids=lambda p: str(p.relative_to(ROOT / "grasps")))
def test_library_grasp_names_exist(path):
    """Every finger and link a library file names exists in its hand."""
    data = yaml.safe_load(path.read_text())
    spec = load_grasp(path)
    hand = load_hand(spec.hand_ref)
    for finger, entry in data["fingers"].items():
        assert finger in hand.fingers
        if isinstance(entry, dict) and "contact" in entry and "link" in entry["contact"]:
            assert entry["contact"]["link"] in hand.fingers[finger].contact_links
        if isinstance(entry, dict) and "posture" in entry:
            assert len(entry["posture"]) == len(hand.fingers[finger].joints)


@pytest.mark.parametrize("path", GRASPS, ids=lambda p: str(p.relative_to(ROOT / "grasps")))
def test_library_grasp_is_force_closure_without_self_collision(path, realized):
    """Every library grasp realizes to force closure, every placed finger touches, no hand part
    collides; the palm holds exactly where the file says palm: hold."""
    g = realized[path]
    assert g.is_force_closure and g.metric > 0
    assert g.missing == ()
    assert g.collisions == ()
    assert set(g.patches) - {PALM} == set(g.spec.contact_fingers)
    assert (PALM in g.patches) == (g.spec.palm == "hold")
    for p, n in g.patches.values():
        assert np.all(np.isfinite(p)) and np.all(np.isfinite(n))
        assert np.allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-6)


@pytest.mark.parametrize("initial,final", PAIRS)
def test_pairs_share_hand_object_pose_and_friction(initial, final):
    """The two grasps of a pair describe the same hand, object, pose and friction."""
    a, b = load_grasp(ROOT / "grasps" / initial), load_grasp(ROOT / "grasps" / final)
    assert a.hand_ref == b.hand_ref
    assert a.object == b.object
    assert a.friction == b.friction


@pytest.mark.parametrize("model", ["patch", "mean"])
def test_box_pair_admits_the_thesis_gait(realized, model):
    """PE -> IR2M: index then ring are moved one at a time, then little lifted, all force
    closure, also with one mean contact per finger (the library box is designed for it; unlike
    the thesis the thumb stays on the box in IR2M: nothing else opposes the three fingers)."""
    pe, ir = realized[BOX_PE], realized[BOX_IR2M]
    assert set(ir.patches) == {"index", "middle", "ring", "thumb"}
    np.testing.assert_allclose(pe.finger_q["middle"], ir.finger_q["middle"])  # the middle finger stays
    np.testing.assert_allclose(pe.finger_q["thumb"], ir.finger_q["thumb"])  # so does the thumb
    for f in ("index", "ring"):  # moved toward the middle finger
        assert abs(ir.patches[f][0][:, 1].mean()) < abs(pe.patches[f][0][:, 1].mean()) - 0.005
    state = dict(pe.patches)
    sequence = [("index", None), ("index", ir.patches["index"]), ("ring", None), ("ring", ir.patches["ring"]),
                ("little", None)]
    for finger, patch in sequence:
        if patch is None:
            state.pop(finger)
        else:
            state[finger] = patch
        c = grasp_closure(apply_contact_model(state, model), pe.friction)
        assert c.is_force_closure, (finger, sorted(state))


def test_realize_contact_lands_on_the_requested_point():
    """A pad contact is placed within a few millimetres of the requested surface point without penetrating."""
    spec = load_grasp(BOX_PE)
    hand = load_hand(spec.hand_ref)
    obj = spec.object
    p = np.array(spec.finger("thumb").point_obj)
    q, patch = realize_contact(hand, obj, "thumb", p, hand.q_open)
    assert patch is not None
    assert np.min(np.linalg.norm(patch[0] - p, axis=1)) < 0.004
    others = [i for i in range(len(q)) if i not in hand.fingers["thumb"].q_index]
    np.testing.assert_array_equal(q[others], hand.q_open[others])


def test_unlisted_fingers_are_free(tmp_path):
    """A finger the file does not list is free and stays at the open posture."""
    data = yaml.safe_load(BOX_IR2M.read_text())
    del data["fingers"]["little"]
    path = _write(tmp_path, data)
    spec = load_grasp(path)
    assert spec.finger("little").kind == "free"
    g = realize(spec)
    np.testing.assert_allclose(g.finger_q["little"], np.asarray(g.hand.q_open)[list(g.hand.fingers["little"].q_index)])


# ---------------------------------------------------------------------------- bad input


def _write(tmp_path: Path, data, name="grasp.yaml") -> Path:
    path = tmp_path / name
    path.write_text(data if isinstance(data, str) else yaml.safe_dump(data, sort_keys=False))
    return path


def _box() -> dict:
    return yaml.safe_load(BOX_PE.read_text())


def _edit(fn):
    def make():
        d = _box()
        fn(d)
        return d

    return make


BAD = {
    "unknown top key": (_edit(lambda d: d.update(colour="red")), "colour", "unknown key"),
    "unsupported version": (_edit(lambda d: d.update(schema_version=2)), "schema_version", "unsupported schema version"),
    "missing object": (_edit(lambda d: d.pop("object")), "object", "missing"),
    "unknown shape": (_edit(lambda d: d["object"].update(shape="cone")), "object.shape", "box, cylinder, sphere, mesh"),
    "negative size": (_edit(lambda d: d["object"]["size"].__setitem__(1, -0.05)), "object.size[1]", "positive"),
    "size length": (_edit(lambda d: d["object"].update(size=[0.06, 0.05])), "object.size", "expected 3 numbers"),
    "nan position": (_edit(lambda d: d["object"]["position"].__setitem__(0, math.nan)), "object.position[0]", "finite"),
    "quaternion": (_edit(lambda d: d["object"].update(quat_xyzw=[0, 0, 0, 2])), "object.quat_xyzw", "unit quaternion"),
    "negative mu": (_edit(lambda d: d["friction"].update(mu=-1)), "friction.mu", "positive"),
    "unknown finger": (_edit(lambda d: d["fingers"].update(pinky="free")), "fingers.pinky", "index, middle, ring, little"),
    "unknown link": (
        _edit(lambda d: d["fingers"]["thumb"]["contact"].update(link="index_distal")),
        "fingers.thumb.contact.link",
        "thumb_distal",
    ),
    "point length": (
        _edit(lambda d: d["fingers"]["thumb"]["contact"].update(point=[0.0, 0.0])),
        "fingers.thumb.contact.point",
        "expected 3 numbers",
    ),
    "point off surface": (
        _edit(lambda d: d["fingers"]["thumb"]["contact"].update(point=[0.0, 0.0, 0.03])),
        "fingers.thumb.contact.point",
        "outside the object surface",
    ),
    "point inside": (
        _edit(lambda d: d["fingers"]["thumb"]["contact"].update(point=[0.0, 0.0, 0.0])),
        "fingers.thumb.contact.point",
        "inside the object surface",
    ),
    "posture length": (
        _edit(lambda d: d["fingers"].update(little={"posture": [0.1, 0.2]})),
        "fingers.little.posture",
        "expected 4 numbers",
    ),
    "posture limits": (
        _edit(lambda d: d["fingers"].update(little={"posture": [0.0, 3.0, 0.0, 0.0]})),
        "fingers.little.posture[1]",
        "outside its limits",
    ),
    "finger entry": (_edit(lambda d: d["fingers"].update(ring="touch")), "fingers.ring", "'free'"),
    "contact and posture": (
        _edit(lambda d: d["fingers"]["thumb"].update(posture=[0.0, 0.0, 0.0, 0.0])),
        "fingers.thumb",
        "either contact or posture",
    ),
    "string number": (_edit(lambda d: d["friction"].update(gamma="0.004")), "friction.gamma", "expected a number"),
    "unknown hand": (_edit(lambda d: d.update(hand="shadow_left")), "hand", "cannot load hand"),
    "no touching finger": (
        _edit(lambda d: d.update(fingers={f: "free" for f in d["fingers"]})),
        "fingers",
        "no finger touches",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_grasp_gives_one_spec_error_naming_file_and_key(tmp_path, case):
    """Each kind of bad input raises a SpecError naming the file, the key path and what was expected."""
    make, key, expected = BAD[case]
    path = _write(tmp_path, make())
    with pytest.raises(SpecError) as info:
        load_grasp(path)
    err = info.value
    assert err.key == key
    assert str(path) in str(err)
    assert f": {key}: " in str(err)
    assert expected in str(err)
    assert "\n" not in str(err)


def test_malformed_yaml_names_the_line(tmp_path):
    """Malformed YAML is a SpecError with the file and the line, not a parser traceback."""
    path = _write(tmp_path, "schema_version: 1\nhand: [icub_right\nobject: {}\n")
    with pytest.raises(SpecError, match=r"malformed YAML at line \d+") as info:
        load_grasp(path)
    assert str(path) in str(info.value)


def test_missing_file_and_non_mapping(tmp_path):
    """A missing file and a YAML list are reported as SpecErrors naming the file."""
    with pytest.raises(SpecError, match="cannot read grasp file"):
        load_grasp(tmp_path / "nope.yaml")
    with pytest.raises(SpecError, match="YAML mapping"):
        load_grasp(_write(tmp_path, "- 1\n- 2\n"))


def test_hand_path_is_relative_to_the_grasp_file(tmp_path):
    """`hand` may be a path to a hand.yaml, resolved against the grasp file's folder."""
    import os

    d = _box()
    sub = tmp_path / "grasps"
    sub.mkdir()
    d["hand"] = os.path.relpath(ROOT / "robots/icub_right/hand.yaml", sub)
    spec = load_grasp(_write(sub, d))
    assert Path(spec.hand_ref) == (ROOT / "robots/icub_right/hand.yaml").resolve()
    assert set(load_hand(spec.hand_ref).fingers) == {"thumb", "index", "middle", "ring", "little"}


def test_surface_tolerance_accepts_points_near_the_surface(tmp_path):
    """A contact point within the tolerance of the surface is accepted (and projected onto it)."""
    d = _box()
    x, y, z = d["fingers"]["thumb"]["contact"]["point"]
    d["fingers"]["thumb"]["contact"]["point"] = [x, y, z + 0.5 * SURFACE_TOL_M]
    assert load_grasp(_write(tmp_path, d)).finger("thumb").kind == "contact"


# ---------------------------------------------------------------------------- command line


def test_check_exit_0_and_report(capsys):
    """`regrasp check` on a force-closure grasp exits 0 and reports fingers, closure and removable fingers."""
    assert main(["check", str(BOX_PE)]) == 0
    out = capsys.readouterr().out
    assert "force closure: yes" in out
    for finger in ("thumb", "index", "middle", "ring", "little"):
        assert finger in out


def test_check_exit_1_when_not_force_closure(tmp_path, capsys):
    """A grasp that is not force closure (one finger) exits 1."""
    d = _box()
    d["fingers"] = {"thumb": d["fingers"]["thumb"]}
    assert main(["check", str(_write(tmp_path, d))]) == 1
    assert "force closure: no" in capsys.readouterr().out


def test_check_exit_2_on_bad_input(tmp_path, capsys):
    """Bad input exits 2 with one line on stderr naming the file and key."""
    d = _box()
    d["fingers"]["pinky"] = "free"
    path = _write(tmp_path, d)
    assert main(["check", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert str(path) in err and "fingers.pinky" in err


def test_check_json_parses(capsys):
    """`--json` prints one JSON document with closure, metric and per-finger contacts."""
    assert main(["check", str(BOX_IR2M), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["force_closure"] is True and report["metric"] > 0
    assert set(report["removable"]) <= {"index", "middle", "ring", "thumb"}
    assert report["mean_contact_closure"]["force_closure"] is True
    assert report["fingers"]["little"]["contact_points"] == 0
    assert report["fingers"]["middle"]["contact_points"] > 0
    assert len(report["joints"]) == 19


@pytest.mark.needs_pybullet("pictures (check --png)")
def test_check_png_renders_hand_and_object(tmp_path, capsys):
    """`--png` writes a picture in which both the object colour and the hand colour appear."""
    from PIL import Image

    png = tmp_path / "grasp.png"
    assert main(["check", str(BOX_PE), "--png", str(png), "--json"]) == 0
    json.loads(capsys.readouterr().out)  # pybullet's console noise does not reach stdout
    img = np.asarray(Image.open(png).convert("RGB")).astype(int)
    assert img.shape[0] >= 100 and img.shape[1] >= 100
    orange = (img[..., 0] > 150) & (img[..., 1] > 60) & (img[..., 1] < 170) & (img[..., 2] < 90)
    grey = (abs(img[..., 0] - img[..., 2]) < 25) & (img[..., 0] > 60) & (img[..., 0] < 220)
    assert orange.mean() > 0.02, "object not visible"
    assert grey.mean() > 0.02, "hand not visible"


# ---------------------------------------------------------------------------- honest check

SPHERE4 = ROOT / "grasps/icub/sphere_four_finger.yaml"


def _sphere4():
    return yaml.safe_load(SPHERE4.read_text())


def _check_out(tmp_path, capsys, data):
    code = main(["check", str(_write(tmp_path, data))])
    return code, capsys.readouterr().out


def test_check_fails_a_finger_that_misses_and_curls_into_the_palm(tmp_path, capsys):
    """The little finger closes past the ball into the palm: force closure of the others is not
    enough, check exits 1 and says the finger does not touch, collides with the palm and ran to
    its closing limit (the issue's 7.7 mm palm collision that exited 0)."""
    d = _sphere4()
    d["fingers"]["little"] = {"posture": [0.0, 0.0, 0.0, 0.0]}
    code, out = _check_out(tmp_path, capsys, d)
    assert code == 1
    assert "force closure: yes" in out  # the other four fingers still hold it: only the new checks fail it
    assert "fingers.little: placed by the file but does not touch the object" in out
    assert "collision palm - little_distal" in out and "NOT AS WRITTEN" in out
    assert "little_1 = 1.5708 rad is at its upper limit" in out
    g = realize(load_grasp(_write(tmp_path, d)))
    assert not g.ok and g.missing == ("little",)
    with pytest.raises(PlannerError, match="fingers.little: the file places it but it does not touch"):
        g.require_placed()


def test_check_fails_a_finger_finger_collision(tmp_path, capsys):
    """The ring finger spread fully toward the open little finger: their proximal phalanges overlap."""
    d = _sphere4()
    d["fingers"]["ring"] = {"posture": [0.349, 0.0, 0.0, 0.0]}
    d["fingers"]["little"] = "free"
    g = realize(load_grasp(_write(tmp_path, d)))
    deep = [c for c in g.collisions if "object" not in c and "palm" not in c[:2] and c[2] > PENETRATION_TOL_M]
    assert deep and {deep[0][0].split("_")[0], deep[0][1].split("_")[0]} == {"ring", "little"}
    code, out = _check_out(tmp_path, capsys, d)
    assert code == 1 and "ring_proximal" in out and "NOT AS WRITTEN: collision" in out


def test_check_fails_an_object_in_the_palm(tmp_path, capsys):
    """The ball moved 13 mm into the hand: links penetrate the object beyond the tolerance."""
    d = _sphere4()
    d["object"]["position"] = [0.045, -0.005, 0.015]
    code, out = _check_out(tmp_path, capsys, d)
    assert code == 1
    assert "- object:" in out and f"tolerance {PENETRATION_TOL_M * 1e3:.1f} mm" in out


def test_check_lists_realized_contacts_in_text_and_json(capsys):
    """Every touching link is listed with an on-surface point and a unit inward normal; a mesh
    reports its extents, not its scale; the thumb's contact point is realized by its pad."""
    mesh = ROOT / "grasps/icub/mesh_rounded_box_parallel_extension.yaml"
    assert main(["check", str(mesh), "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["as_written"] and rep["problems"] == []
    assert np.allclose(rep["object_extents_m"], [0.035, 0.08, 0.03], atol=1e-3)
    for path in (mesh, SPHERE4):  # normals checked on the sphere (a mesh's edges have no single normal)
        g = realize(load_grasp(path))
        links = {(c["finger"], c["link"]) for c in g.summary()["contacts"]}
        assert links == {(f, l) for f, ls in g.touching.items() for l in ls}
    for c in g.summary()["contacts"]:
        _, n_out, dist = g.obj.closest_surface(np.array(c["point"]))
        assert abs(dist) < 1e-6 and np.allclose(-n_out, c["normal"], atol=1e-6)
        assert np.allclose(-np.array(c["point"]) / 0.025, c["normal"], atol=1e-6)  # a ball's inward normal
    # the thumb's contact point is realized where the file puts it, by its pad (issue 36 item 1;
    # it used to land 13 mm away on the intermediate phalanx, with a warning)
    assert not any(w.startswith("fingers.thumb.contact") for w in rep["warnings"])
    thumb = [c for c in rep["contacts"] if c["finger"] == "thumb" and c["link"] == "thumb_distal"]
    point = load_grasp(mesh).finger("thumb").point_obj
    assert thumb and min(np.linalg.norm(np.array(c["point"]) - point) for c in thumb) <= 2e-3
    assert main(["check", str(mesh)]) == 0
    out = capsys.readouterr().out
    assert "35.0 x 80.0 x 30.0 mm" in out and "realized contacts" in out


def test_plan_refuses_a_placed_finger_that_does_not_touch(tmp_path, capsys):
    """`plan` exits 2 with one line instead of treating the missing finger as lifted."""
    d = _sphere4()
    d["fingers"]["little"] = {"posture": [0.0, 0.0, 0.0, 0.0]}
    bad = _write(tmp_path, d)
    assert main(["plan", str(SPHERE4), str(bad), "--no-motion"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "fingers.little" in err and "does not touch" in err


def test_unreachable_contact_says_where_to_move_it(tmp_path):
    """A contact point out of reach: the error gives the closest approach and the direction to
    move the point, in the object frame; moving the target that way by that distance reaches the
    closest point the IK found."""
    from planner.ik import UnreachableError

    d = _sphere4()
    d["object"]["position"] = [0.045, -0.005, 0.2]  # far above the hand: ring cannot reach its top
    d["fingers"]["ring"] = {"contact": {"point": [0.0, 0.0, 0.025]}}
    for f in ("thumb", "index", "middle"):
        d["fingers"][f] = "free"
    spec = load_grasp(_write(tmp_path, d))
    with pytest.raises(UnreachableError) as info:
        realize(spec)
    err = info.value
    assert "fingers.ring.contact.point" in str(err) and "move the point along" in str(err)
    assert np.isclose(np.linalg.norm(err.direction_palm), 1.0)
    np.testing.assert_allclose(err.target_palm + err.distance_m * err.direction_palm, err.closest_palm, atol=1e-9)


@pytest.mark.needs_pybullet("pictures (render_png)")
def test_check_png_draws_the_contacts(tmp_path, capsys):
    """The picture shows the realized contacts as green dots and normals (none without markers)."""
    from PIL import Image

    from planner.grasp_report import contact_markers
    from planner.sim.render import render_png

    g = realize(load_grasp(SPHERE4))
    assert len(contact_markers(g)) == len(g.contacts) >= 4
    green = []
    for markers in (None, contact_markers(g)):
        render_png(g.hand, g.q, g.obj, tmp_path / "g.png", markers=markers)
        img = np.asarray(Image.open(tmp_path / "g.png").convert("RGB")).astype(int)
        green.append(((img[..., 1] > 150) & (img[..., 0] < 100) & (img[..., 2] < 120)).sum())
    assert green[0] == 0 and green[1] > 30


def _far_cube() -> dict:
    """A 40 mm cube held at its face centres by the iCub, index and middle out of reach."""
    return {"schema_version": 1, "name": "cube", "hand": "icub_right",
            "object": {"shape": "box", "size": [0.04, 0.04, 0.04], "position": [0.03, -0.01, 0.035],
                       "quat_xyzw": [0, 0, 0, 1], "mass_kg": 0.05},
            "friction": {"mu": 0.9, "gamma": 0.004},
            "fingers": {"thumb": {"contact": {"point": [0.0, -0.02, 0.0]}},
                        "index": {"contact": {"point": [0.02, 0.0, 0.0]}},
                        "middle": {"contact": {"point": [0.0, 0.02, 0.0]}}, "ring": "free", "little": "free"}}


def test_out_of_reach_names_every_finger_and_its_suggestion_is_reachable(tmp_path):
    """A 40 mm cube held at its face centres, two of them out of reach: one error naming both
    fingers; the point suggested for a finger (checked by IK) is in reach when used; where no
    nearby surface point is, the advice is to move the object."""
    import re

    import yaml

    from planner.grasp import load_grasp
    from planner.ik import UnreachableError
    from planner.realization import realize

    data = _far_cube()
    path = tmp_path / "cube.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(UnreachableError) as info:
        realize(load_grasp(path))
    msg = str(info.value)
    assert "fingers.index.contact.point" in msg and "fingers.middle.contact.point" in msg and "\n" not in msg
    assert "move the object toward the finger" in msg
    # the index realizes (pad within 45 deg, no collision) 1 in 120 points of this cube, none
    # near its own: it is told to move the object; a suggestion, when there is one, is realized
    m = re.search(r"fingers\.index\.contact\.point:.*?a surface point it does reach \(checked\): \[([^\]]+)\]", msg)
    if m is None:
        assert re.search(r"fingers\.index\.contact\.point: reach:.*?no surface point near it is realized", msg), msg
        return
    data["fingers"]["index"] = {"contact": {"point": [float(v) for v in m.group(1).split(",")]}}
    data["fingers"]["middle"] = "free"
    path.write_text(yaml.safe_dump(data))
    g = realize(load_grasp(path))  # no UnreachableError: the suggestion was in reach
    assert "index" in g.touching


def test_realizing_without_suggestions_places_the_same_and_keeps_reach_errors_hinted(tmp_path):
    """realize(suggest=False) (what `plan` and the audit do: they show no realization
    warnings): the same joints and contacts as with suggestions, the same warnings without the
    suggested point (a thumb on a box that it reaches only with its pad facing away); and a
    contact out of reach still raises the error with its suggestion (the cube above)."""
    import yaml

    from planner.grasp import load_grasp
    from planner.ik import UnreachableError
    from planner.realization import realize

    data = {"schema_version": 1, "name": "box", "hand": "allegro_right",
            "object": {"shape": "box", "size": [0.05563, 0.06529, 0.03687], "position": [0.031701, -0.002114, -0.015615],
                       "quat_xyzw": [-0.7046386, 0.0590286, -0.7046386, 0.0590286], "mass_kg": 0.03},
            "friction": {"mu": 0.9, "gamma": 0.004},
            "fingers": {"thumb": {"contact": {"point": [-0.02782, 0.00705, 0.00455]}},
                        "index": {"posture": [0.235, 0.3, 0.0, 0.0]}, "middle": {"posture": [0.235, 0.3, 0.0, 0.0]},
                        "ring": {"posture": [-0.235, 0.3, 0.0, 0.0]}}}
    path = tmp_path / "box.yaml"
    path.write_text(yaml.safe_dump(data))
    spec = load_grasp(path)
    told, quiet = realize(spec), realize(spec, suggest=False)
    np.testing.assert_array_equal(told.q, quiet.q)
    assert sorted(told.patches) == sorted(quiet.patches)
    for f in told.patches:
        np.testing.assert_array_equal(told.patches[f].points, quiet.patches[f].points)
    hinted = [w for w in told.warnings if "a surface point it does reach (checked)" in w]
    assert hinted, told.warnings  # the case this test is about
    assert list(quiet.warnings) == [w.split("; a surface point it does reach (checked)")[0] for w in told.warnings]
    path = tmp_path / "cube.yaml"
    path.write_text(yaml.safe_dump(_far_cube()))
    errors = []
    for suggest in (True, False):
        with pytest.raises(UnreachableError) as info:
            realize(load_grasp(path), suggest=suggest)
        errors.append(str(info.value))
    assert errors[0] == errors[1] and "move the object toward the finger" in errors[0]
