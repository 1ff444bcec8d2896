"""End-to-end planning on the grasp library: plans re-checked from their exported files."""

import itertools
from pathlib import Path

import numpy as np
import pytest
import yaml

from planner.cli import main
from planner.model import Friction
from planner.closure import grasp_closure
from planner.grasp import load_grasp
from planner.options import PlanOptions
from planner.plan import read_plan
from planner.realization import realize
from planner.regrasp import plan_regrasp

ROOT = Path(__file__).resolve().parent.parent
ICUB = ROOT / "grasps" / "icub"
PAIRS = {
    "box": (ICUB / "box_parallel_extension.yaml", ICUB / "box_ir2m.yaml"),
    "cylinder": (ICUB / "cylinder_parallel_extension.yaml", ICUB / "cylinder_ir2m.yaml"),
}


@pytest.fixture(scope="module")
def realized():
    cache = {}

    def get(path):
        if path not in cache:
            cache[path] = realize(load_grasp(path))
        return cache[path]

    return get


def recheck_plan_file(path):
    """Re-check a plan from its file alone: closure of every state, single-finger steps."""
    data = read_plan(path)
    fr = Friction(**data["friction"])
    for i, state in enumerate(data["states"]):
        patches = {f: (np.array(p["points"]), np.array(p["normals"])) for f, p in state["patches"].items()}
        c = grasp_closure(patches, fr)
        assert c.is_force_closure, f"state {i} is not force closure when re-checked"
        assert state["closure"]["is_force_closure"]
        assert c.metric == pytest.approx(state["closure"]["metric"], rel=1e-6, abs=1e-9)
    joints = data["joints"]
    for step in data["steps"]:
        a, b = data["states"][step["from_state"]], data["states"][step["to_state"]]
        moved = {j for j in joints if abs(a["q"][j] - b["q"][j]) > 1e-9}
        assert moved <= set(step["joints"]), f"step moves joints outside finger {step['finger']}"
        assert np.allclose(step["path"][0], [a["q"][j] for j in step["joints"]], atol=1e-8)
        assert np.allclose(step["path"][-1], [b["q"][j] for j in step["joints"]], atol=1e-8)
    return data


@pytest.mark.parametrize("pair", sorted(PAIRS))
def test_parallel_extension_to_ir2m_is_planned_and_rechecks(pair, realized, tmp_path):
    """Box and cylinder: PE -> IR2M plans; every exported state is force closure from its patches."""
    initial, final = (realized(p) for p in PAIRS[pair])
    result = plan_regrasp(initial, final, PlanOptions(motion=False, alternatives=8))
    path = tmp_path / "plan.yaml"
    from planner.plan_data import write_plan

    write_plan(result.plan, path)
    assert result.plan.summary["gait_steps"] >= 2
    data = recheck_plan_file(path)
    last = data["states"][-1]
    assert set(last["patches"]) == set(final.patches)
    keys = [s.rank_key for s in (result.sequence, *result.alternatives)]
    assert keys == sorted(keys)


def test_thesis_orderings_are_among_the_alternatives(realized):
    """The box alternatives include both index-first and ring-first orderings (thesis fig. 11)."""
    initial, final = (realized(p) for p in PAIRS["box"])
    result = plan_regrasp(initial, final, PlanOptions(motion=False, alternatives=16))
    problem = result.graph.graph["problem"]
    firsts = {s.order(problem)[0] for s in (result.sequence, *result.alternatives)}
    assert {"index:lift", "ring:lift"} <= firsts


def test_greedy_baseline_reports_the_same_way(realized):
    """The greedy strategy solves the thesis pair and returns force-closure states only."""
    initial, final = (realized(p) for p in PAIRS["box"])
    greedy = plan_regrasp(initial, final, PlanOptions(strategy="greedy", motion=False))
    graph = plan_regrasp(initial, final, PlanOptions(motion=False))
    assert all(s.is_force_closure for s in greedy.plan.states)
    assert graph.sequence.bottleneck >= greedy.sequence.bottleneck - 1e-12


def test_plan_cli_is_deterministic(tmp_path):
    """Same inputs and seed give a byte-identical plan file."""
    a, b = PAIRS["box"]
    out1, out2 = tmp_path / "p1.yaml", tmp_path / "p2.yaml"
    assert main(["plan", str(a), str(b), "-o", str(out1), "--no-motion"]) == 0
    assert main(["plan", str(a), str(b), "-o", str(out2), "--no-motion"]) == 0
    assert out1.read_bytes() == out2.read_bytes()


def test_plan_cli_refuses_different_objects(tmp_path, capsys):
    """Grasps of different objects are refused with exit 2 and a one-line error naming the key."""
    a = PAIRS["box"][0]
    b = PAIRS["cylinder"][1]
    out = tmp_path / "p.yaml"
    assert main(["plan", str(a), str(b), "-o", str(out), "--no-motion"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "object" in err
    assert not out.exists()


def test_plan_cli_bad_strategy_and_suffix(tmp_path, capsys):
    """Unknown strategy lists the valid ones; a bad output suffix is refused before planning."""
    a, b = PAIRS["box"]
    assert main(["plan", str(a), str(b), "--strategy", "astar", "--no-motion"]) == 2
    assert "graph, greedy" in capsys.readouterr().err
    assert main(["plan", str(a), str(b), "-o", str(tmp_path / "p.txt")]) == 2
    assert ".yaml" in capsys.readouterr().err


def test_unreachable_goal_exits_one_with_an_explanation(tmp_path, capsys):
    """A final grasp with the thumb alone cannot be force closure: exit 1 and a reason."""
    a, _ = PAIRS["box"]
    data = yaml.safe_load(a.read_text())
    data["fingers"] = {f: ("free" if f != "thumb" else v) for f, v in data["fingers"].items()}
    data["name"] = "thumb_only"
    final = tmp_path / "thumb_only.yaml"
    final.write_text(yaml.safe_dump(data))
    assert main(["plan", str(a), str(final), "--no-motion"]) == 1
    assert "force closure" in capsys.readouterr().err


def test_exported_paths_recheck_with_coal(realized, tmp_path):
    """Every exported finger path (box plan with OMPL): limits hold, no link sinks into the object.

    Independent of the planner: the file's waypoints are densified to 0.01 rad and every
    finger link is tested against the object with coal directly.
    """
    import coal

    from planner.plan_data import write_plan

    initial, final = (realized(p) for p in PAIRS["box"])
    result = plan_regrasp(initial, final, PlanOptions(motion=True, seed=3))
    data = recheck_plan_file(write_plan(result.plan, tmp_path / "plan.json"))
    hand, obj = initial.hand, initial.obj
    T_palm_obj = np.asarray(obj.T_palm_obj)
    tf_obj = coal.Transform3s(np.ascontiguousarray(T_palm_obj[:3, :3]), np.ascontiguousarray(T_palm_obj[:3, 3]))
    lo, hi = np.asarray(hand.lower), np.asarray(hand.upper)
    names = list(hand.joint_names)
    assert any(s["action"] == "move" for s in data["steps"])
    for step in data["steps"]:
        q = np.array([data["states"][step["from_state"]]["q"][j] for j in names])
        idx = [names.index(j) for j in step["joints"]]
        path = np.array(step["path"])
        assert np.all(path >= lo[idx] - 1e-9) and np.all(path <= hi[idx] + 1e-9)
        fine = [path[0]]
        for a, b in zip(path[:-1], path[1:]):
            n = max(1, int(np.ceil(np.max(np.abs(b - a)) / 0.01)))
            fine.extend(a + (b - a) * t for t in np.arange(1, n + 1) / n)
        for wp in fine:
            q[idx] = wp
            for link, finger, geom, tf in hand.state(q).collision_objects():
                if finger != step["finger"]:
                    continue
                d = coal.distance(geom, tf, obj.geometry, tf_obj, coal.DistanceRequest(), coal.DistanceResult())
                assert d > -1e-3, f"{link} sinks {-d * 1e3:.2f} mm into the object during {step['finger']} {step['action']}"


#: A pen pinch whose two pads touch 14 mm apart along the pen (the library's pinch before
#: its redesign): force closure from its contact patches, not with one mean contact per finger.
_PATCH_ONLY_PEN = """\
schema_version: 1
name: pen_palmar_pinch
hand: icub_right
object: {shape: cylinder, size: [0.005, 0.14], position: [0.025, -0.012, 0.022],
         quat_xyzw: [0.270598, 0.653281, -0.270598, 0.653281], mass_kg: 0.01}
friction: {mu: 0.9, gamma: 0.004, edges: 5}
fingers:
  thumb: {contact: {point: [-0.0029, -0.0041, 0.0296]}}
  index: {contact: {point: [0.0024, 0.0044, 0.0406]}}
"""


def test_mean_contact_model_refuses_a_grasp_that_holds_only_by_its_patches(realized, capsys, tmp_path):
    """A pen pinch with its pads offset along the pen is force closure from its patches but not
    with one mean contact per finger: planning with --contact-model mean exits 1 and says why."""
    pinch, tripod = tmp_path / "pen_palmar_pinch.yaml", tmp_path / "pen_writing_tripod.yaml"
    pinch.write_text(_PATCH_ONLY_PEN)
    tripod.write_text(_PATCH_ONLY_PEN.replace("name: pen_palmar_pinch", "name: pen_writing_tripod")
                      + "  middle: {posture: [0.6787, 0.95, 0.6039]}\n")
    assert realized(pinch).is_force_closure
    assert not realized(pinch).mean_contact_closure()["force_closure"]
    assert main(["plan", str(pinch), str(tripod), "--no-motion", "--contact-model", "mean"]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "'mean' contact model" in err and "pen_palmar_pinch" in err
    assert main(["plan", str(pinch), str(tripod), "--no-motion", "--contact-model", "average"]) == 2
    assert "mean, patch" in capsys.readouterr().err


def test_gravity_aware_plan_holds_twice_the_weight_within_the_joint_limits_when_rechecked(realized, tmp_path):
    """--gravity: every exported state, re-checked from the file, holds twice the object's
    weight (mass from the plan, gravity rotated into the object frame) within the hand's joint
    torque limits: the grip model's witness forces balance the load inside the cones, and
    pinocchio's own Jacobians and gravity torques at the state's q keep every joint within its
    effort. An extra per-finger cap (--max-finger-force) blocks more states."""
    from planner.closure import apply_contact_model
    from planner.grip import HOLD_FACTOR, grasp_statics, hold_capacity

    a, b = PAIRS["box"]
    out = tmp_path / "g.yaml"
    assert main(["plan", str(a), str(b), "-o", str(out), "--no-motion", "--contact-model", "mean",
                 "--gravity", "0", "0", "-9.81"]) == 0
    data = recheck_plan_file(out)
    assert data["parameters"]["gravity"] == [0.0, 0.0, -9.81] and data["parameters"]["max_finger_force_n"] is None
    fr = Friction(**data["friction"])
    g = realized(a)
    hand, mass = g.hand, g.obj.mass_kg
    T = np.asarray(g.obj.T_palm_obj)
    R = T[:3, :3]
    g_palm = np.array([0.0, 0.0, -9.81])
    load = np.r_[mass * R.T @ g_palm, np.zeros(3)]
    for state in data["states"]:
        patches = {f: (np.array(p["points"]), np.array(p["normals"])) for f, p in state["patches"].items()}
        patches = apply_contact_model(patches, "mean")
        q = np.array([state["q"][j] for j in hand.joint_names])
        cap = hold_capacity(patches, grasp_statics(hand, q, patches, T), fr, load, R.T @ g_palm,
                            margin=data["parameters"]["friction_margin"])
        assert cap.factor >= HOLD_FACTOR
        total = sum(f.sum(axis=0) for f in cap.forces.values())
        np.testing.assert_allclose(total, -cap.factor * load[:3], atol=1e-6)
        tau = hand.state(q).gravity_torques(g_palm)
        for f, forces in cap.forces.items():
            p_palm = patches[f][0] @ R.T + T[:3, 3]
            link = min(hand.fingers[f].contact_links,
                       key=lambda l: hand.state(q).point_distance(p_palm[0], hand.collision.link_geometries[l]))
            (J,) = hand.state(q).point_jacobians([(link, p_palm[0])], angular=True)
            tau = tau + J[:3].T @ (R @ forces[0]) + J[3:].T @ (R @ cap.moments[f][0])
            n = patches[f][1][0]  # inside the cone (the plan's friction margin), torsion too
            fn, k = float(forces[0] @ n), data["parameters"]["friction_margin"]
            assert np.linalg.norm(forces[0] - fn * n) <= k * fr.mu * fn + 1e-9
            assert abs(float(cap.moments[f][0] @ n)) <= k * fr.gamma * fn + 1e-9
        assert np.all(np.abs(tau) <= hand.effort + 1e-6), np.abs(tau).max()
    plain = PlanOptions(motion=False, contact_model="mean", gravity=(0.0, 0.0, -9.81))
    capped = PlanOptions(motion=False, contact_model="mean", gravity=(0.0, 0.0, -9.81), max_finger_force_n=1.2)
    assert not any("cap" in r for r in plan_regrasp(realized(a), realized(b), plain).graph.graph["blocked"].values())
    G = plan_regrasp(realized(a), realized(b), capped).graph
    assert any("(cap 1.2 N)" in r for r in G.graph["blocked"].values())
    # twice the weight with at most 1.2 N per finger: the weight alone with at most 0.6 N
    assert all(d["grip_force"] <= 0.6 + 1e-9 for _, d in G.nodes(data=True))


def test_gravity_budget_too_small_exits_one_and_bad_values_exit_two(capsys):
    a, b = PAIRS["box"]
    assert main(["plan", str(a), str(b), "--no-motion", "--contact-model", "mean",
                 "--gravity", "0", "0", "-9.81", "--max-finger-force", "0.01"]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "(needs 2x)" in err and "(cap 0.01 N)" in err
    assert main(["plan", str(a), str(b), "--no-motion", "--gravity", "0", "nan", "9.81"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "gravity" in err
    assert main(["plan", str(a), str(b), "--no-motion", "--gravity", "0", "0", "9.81", "--max-finger-force", "0"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and ("max_finger_force_n" in err or "--max-finger-force" in err)


MESH_PAIR = (ICUB / "mesh_rounded_box_parallel_extension.yaml", ICUB / "mesh_rounded_box_ir2m.yaml")
ROUNDED_BOX = {"half_extents_m": np.array([0.0175, 0.04, 0.015]), "radius_m": 0.005, "chord_sag_m": 0.0003}
"""grasps/meshes/rounded_box.obj (make_meshes.py): its vertices lie on this ideal rounded box
and its chords at most 0.26 mm inside it (5 mm rounding split in 30 deg arcs)."""


def _rounded_box_sdf(p_obj):
    """Signed distance (m, negative inside) of points (n, 3) to the ideal rounded box."""
    h, r = ROUNDED_BOX["half_extents_m"], ROUNDED_BOX["radius_m"]
    q = np.abs(p_obj) - (h - r)
    return np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0) - r


def test_mesh_pair_plans_with_finger_paths_and_every_state_rechecks(tmp_path):
    """A mesh object (rounded box OBJ) plans end to end with OMPL finger paths, as the issue's
    command line does (coal used to refuse the finger retreat on a mesh, exit 1). The exported
    plan re-checks from its file: every state force closure, single-finger steps, and no
    finger link (a capsule) sinks into the object beyond the touch tolerance anywhere along
    the paths, measured with the rounded box's own signed distance function, not coal."""
    import coal

    from planner.hand import Hand
    from planner.finger_scene import DEFAULT_TOUCH_TOL_M

    a, b = MESH_PAIR
    out = tmp_path / "mesh.yaml"
    assert main(["plan", str(a), str(b), "-o", str(out), "--contact-model", "mean",
                 "--gravity", "0", "0", "9.81"]) == 0
    data = recheck_plan_file(out)
    assert data["object"]["shape"] == "mesh" and Path(data["object"]["mesh"]).name == "rounded_box.obj"
    assert data["parameters"]["motion"] is True
    assert {s["action"] for s in data["steps"]} == {"lift", "move", "land"}
    assert all(len(s["path"]) >= 2 for s in data["steps"])
    hand = Hand.load(data["hand"]["name"])
    names = list(hand.joint_names)
    T_palm_obj = np.asarray(realize(load_grasp(a)).obj.T_palm_obj)
    R, t = T_palm_obj[:3, :3], T_palm_obj[:3, 3]
    s = np.linspace(-1.0, 1.0, 201)  # 0.1 mm along a capsule axis
    worst = np.inf
    for step in data["steps"]:
        q = np.array([data["states"][step["from_state"]]["q"][j] for j in names])
        idx = [names.index(j) for j in step["joints"]]
        path = np.array(step["path"])
        # joint steps of at most 5 mrad between the exported waypoints
        counts = np.maximum(1, np.ceil(np.abs(np.diff(path, axis=0)).max(axis=1) / 0.005)).astype(int)
        pieces = [p0 + np.outer(np.arange(1, n + 1) / n, p1 - p0) for p0, p1, n in zip(path[:-1], path[1:], counts)]
        for wp in np.vstack([path[:1], *pieces]):
            q[idx] = wp
            capsules = [(g, tf) for _, f, g, tf in hand.state(q).collision_objects() if f == step["finger"]]
            assert all(isinstance(g, coal.Capsule) for g, _ in capsules)
            for g, tf in capsules:
                axis_palm = np.asarray(tf.getRotation())[:, 2] * g.halfLength
                segment_obj = (np.asarray(tf.getTranslation()) + np.outer(s, axis_palm) - t) @ R
                worst = min(worst, _rounded_box_sdf(segment_obj).min() - g.radius)
    slack = ROUNDED_BOX["chord_sag_m"] + 0.0001  # chords inside the ideal box; axis sampling
    assert worst > -(DEFAULT_TOUCH_TOL_M + slack), f"a finger sinks {-worst * 1e3:.2f} mm into the rounded box"


# --------------------------------------------------------------------------- execution mode

#: The iCub hand's six named gravity directions (palm_normal +z), written out independently
#: of planner.gravity.
ICUB_GRAVITY_SET_6 = {
    "palm_down": [0.0, 0.0, 9.81], "palm_up": [0.0, 0.0, -9.81], "side_+x": [9.81, 0.0, 0.0],
    "side_-x": [-9.81, 0.0, 0.0], "side_+y": [0.0, 9.81, 0.0], "side_-y": [0.0, -9.81, 0.0],
}


def test_execution_mode_plans_the_cylinder_pair_and_every_state_rechecks_closure_and_grip(realized, tmp_path):
    """--execution (mean contacts, gravity set 6, grip ranking, 3/4 of the friction) plans
    the cylinder pair with OMPL
    paths; from the file alone every state re-checks as force closure and its recorded grip
    force is the largest over the six directions of an independent grip LP (own cone
    polygons, bracketed within the 16-gon's bound); the plan is the grip-best one; a second
    run is byte-identical."""
    from scipy.spatial.transform import Rotation
    from test_closure import _grip_explicit_cone

    from planner.closure import min_grip_force

    a, b = PAIRS["cylinder"]
    out, again = tmp_path / "exec.yaml", tmp_path / "again.yaml"
    assert main(["plan", str(a), str(b), "-o", str(out), "--execution"]) == 0
    data = recheck_plan_file(out)
    par = data["parameters"]
    assert par["execution"] and par["contact_model"] == "link" and par["rank"] == "grip" and par["gravity_set"] == 6
    assert {d["name"]: d["gravity"] for d in par["gravity_directions"]} == ICUB_GRAVITY_SET_6
    assert par["grip_cone_sides"] == 16 and data["summary"]["rank"] == "grip"
    # execution plans keep a friction reserve: their grip is computed with mu and gamma scaled
    k = par["friction_margin"]
    assert k == 0.75
    fr0 = data["friction"]
    fr = Friction(fr0["mu"] * k, fr0["gamma"] * k, fr0["edges"])
    R = Rotation.from_quat(data["object"]["quat_xyzw"]).as_matrix()
    mass = data["object"]["mass_kg"]
    grips, bracketed = [], set()
    for i, state in enumerate(data["states"]):
        patches = {f: (np.array(p["points"]), np.array(p["normals"])) for f, p in state["patches"].items()}
        # one contact per touching link (the "link" model), each point naming its own link
        assert all(len(p["links"]) == len(set(p["links"])) == len(p["points"]) >= 1 for p in state["patches"].values())
        per_dir = {}
        for name, g in ICUB_GRAVITY_SET_6.items():
            load = np.r_[mass * R.T @ np.array(g), np.zeros(3)]
            per_dir[name] = min_grip_force(patches, fr, load)
            key = (repr(state["patches"]), name)  # lift and move states share their contacts
            if key not in bracketed:
                bracketed.add(key)
                lower = _grip_explicit_cone(patches, fr.mu / np.cos(np.pi / 128), fr.gamma, load, 128)
                upper = _grip_explicit_cone(patches, fr.mu * np.cos(np.pi / 16), fr.gamma, load, 128)
                assert lower * (1 - 1e-6) - 1e-9 <= state["grip_force_by_gravity_n"][name] <= upper * (1 + 1e-6) + 1e-9
        assert state["grip_force_by_gravity_n"] == pytest.approx(per_dir, rel=1e-7)
        assert state["grip_force_n"] == pytest.approx(max(per_dir.values()), rel=1e-7), f"state {i}"
        assert par["max_finger_force_n"] is None and set(state["hold_factor_by_gravity"]) == set(ICUB_GRAVITY_SET_6)
        assert min(state["hold_factor_by_gravity"].values()) >= par["hold_factor"] == 2.0
        # the same state needs less grip with the whole cone: the reserve is real
        full = max(min_grip_force(patches, Friction(**fr0), np.r_[mass * R.T @ np.array(g), np.zeros(3)])
                   for g in ICUB_GRAVITY_SET_6.values())
        assert full < state["grip_force_n"]
        grips.append(state["grip_force_n"])
    assert data["summary"]["bottleneck_grip_force_n"] == pytest.approx(max(grips), rel=1e-9)
    # (the ranking compares grips to 1 uN: GRIP_RANK_DECIMALS)
    assert all(alt["bottleneck_grip_force_n"] >= max(grips) - 1e-6 for alt in data["alternatives"])
    # the metric ranking on the same states does not need less grip than the grip ranking
    by_metric = plan_regrasp(realized(a), realized(b), PlanOptions(motion=False, contact_model="link", gravity_set=6,
                                                                   friction_margin=k))
    assert by_metric.sequence.bottleneck_grip >= max(grips) - 1e-6
    # verified in the six directions before it was returned; the record is part of the bytes
    check = data["summary"]["verification"]
    assert check["passed"] and set(check["directions"]) == set(ICUB_GRAVITY_SET_6)
    assert all(d["passed"] for d in check["directions"].values())
    assert main(["plan", str(a), str(b), "-o", str(again), "--execution"]) == 0
    assert out.read_bytes() == again.read_bytes()


def test_execution_mode_options_and_errors_are_one_line(tmp_path, capsys):
    """--execution takes --gravity instead of the set; grip ranking without gravity, a
    gravity vector and a set together, a bad set size, an unknown rank and --execution
    with another contact model are one-line errors with exit 2."""
    a, b = PAIRS["box"]
    out = tmp_path / "g.json"
    assert main(["plan", str(a), str(b), "-o", str(out), "--no-motion", "--execution", "--no-verify",
                 "--gravity", "0", "0", "9.81"]) == 0
    par = read_plan(out)["parameters"]
    assert par["gravity_set"] is None and par["gravity_directions"] == [{"name": "gravity", "gravity": [0.0, 0.0, 9.81]}]
    assert all(s["grip_force_by_gravity_n"].keys() == {"gravity"} for s in read_plan(out)["states"])
    capsys.readouterr()
    for args, words in (
        (["--rank", "grip"], "grip ranking needs a gravity"),
        (["--gravity", "0", "0", "9.81", "--gravity-set", "6"], "not both"),
        (["--gravity-set", "3"], "1, 2, 6, 7"),
        (["--rank", "fastest"], "grip, metric"),
        (["--execution", "--contact-model", "patch"], "execution mode"),
    ):
        try:
            code = main(["plan", str(a), str(b), "--no-motion", *args])
        except SystemExit as stop:  # argparse's choices (--gravity-set)
            code = stop.code
        assert code == 2, args
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and words in err, err


def test_plain_plans_export_null_grip_and_gravity_set_blocks_like_gravity(realized):
    """Without gravity every state's grip force is None (null in the file); gravity set 1
    (palm down) gives the same graph and grips as --gravity along the palm normal."""
    a, b = PAIRS["box"]
    plain = plan_regrasp(realized(a), realized(b), PlanOptions(motion=False, contact_model="mean"))
    assert all(s.grip_force_n is None and s.grip_force_by_gravity_n is None for s in plain.plan.states)
    assert plain.plan.parameters["gravity_directions"] is None and plain.plan.summary["bottleneck_grip_force_n"] is None
    one = plan_regrasp(realized(a), realized(b), PlanOptions(motion=False, contact_model="mean", gravity_set=1))
    vec = plan_regrasp(realized(a), realized(b), PlanOptions(motion=False, contact_model="mean", gravity=(0, 0, 9.81)))
    assert sorted(one.graph.nodes) == sorted(vec.graph.nodes)
    assert [s.grip_force_n for s in one.plan.states] == [s.grip_force_n for s in vec.plan.states]
    assert one.plan.states[0].grip_force_by_gravity_n.keys() == {"palm_down"}


def test_execution_mode_box_is_bounded_by_the_joints_not_a_force_constant(realized, monkeypatch):
    """The bundled box pair, which a 1 N per-finger budget refused without intermediate
    contacts, plans with its own contacts within the iCub model's 0.5 N m joints (twice the
    weight in six directions, 3/4 of the friction). With joints ten times weaker than the
    weight needs, the refusal names the finger's joint, the torque it needs and its limit."""
    import re

    from planner.errors import NoSequenceError
    from planner.options import EXECUTION_FRICTION_MARGIN, PlanOptions
    from planner.regrasp import plan_regrasp

    assert EXECUTION_FRICTION_MARGIN == 0.75
    initial, final = (realized(f) for f in PAIRS["box"])
    res = plan_regrasp(initial, final, PlanOptions.for_execution(motion=False, time_limit_s=0, verify=False))
    assert res.plan.summary["search"]["rounds"] == 0
    assert all(min(s.hold_factor_by_gravity.values()) >= 2.0 and len(s.hold_factor_by_gravity) == 6
               for s in res.plan.states)
    weak = np.full(len(initial.hand.joint_names), 0.01)
    weak.flags.writeable = False
    monkeypatch.setattr(initial.hand, "effort", weak)
    with pytest.raises(NoSequenceError) as err:
        plan_regrasp(initial, final, PlanOptions.for_execution(motion=False, time_limit_s=0, verify=False))
    m = re.search(r"joint (\w+) needs ([0-9.]+) N m \(limit 0.01 N m\)", str(err.value))
    assert m and m.group(1) in initial.hand.joint_names and float(m.group(2)) > 0.01, str(err.value)


ALLEGRO_SPHERE = ROOT / "grasps" / "allegro" / "sphere_four_finger.yaml"


def _middle_for_ring(tmp_path):
    """Allegro sphere, four fingers -> a tripod where the middle finger takes the ring
    finger's place and the ring finger is freed (the pair `benchmarks/bench_plan.py` times):
    the middle finger cannot land while the ring finger is there, and thumb + index alone
    do not hold the ball, so no sequence exists with the two grasps' contacts alone."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("bench_plan", ROOT / "benchmarks" / "bench_plan.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    return bench.middle_for_ring_pair(tmp_path)[1]


def test_pair_needing_intermediate_contacts_is_solved_with_defaults_deterministically(tmp_path, capsys):
    """Without intermediate contacts (--time-limit 0) the pair fails, and the message says
    in words that the middle finger would collide with the ring finger; with the defaults
    the anytime planner adds intermediate contacts and solves it; every exported state
    re-checks force closure; the same inputs give the same plan bytes."""
    final = _middle_for_ring(tmp_path)
    assert main(["plan", str(ALLEGRO_SPHERE), str(final), "--no-motion", "--time-limit", "0"]) == 1
    err = capsys.readouterr().err
    assert "middle cannot land on its final contact: it would collide with ring" in err and "{" not in err
    out1, out2 = tmp_path / "p1.yaml", tmp_path / "p2.yaml"
    assert main(["plan", str(ALLEGRO_SPHERE), str(final), "--no-motion", "-o", str(out1)]) == 0
    assert main(["plan", str(ALLEGRO_SPHERE), str(final), "--no-motion", "-o", str(out2)]) == 0
    assert out1.read_bytes() == out2.read_bytes()
    data = recheck_plan_file(out1)
    search = data["summary"]["search"]
    assert search["rounds"] >= 1 and search["exact"]
    assert any(label.startswith("int") for s in data["states"] for label in s["fingers"].values())
    assert set(data["states"][-1]["patches"]) == {"thumb", "index", "middle"}


def test_reachable_contacts_touch_the_object_within_joint_limits():
    """Every intermediate-contact candidate of the pool is within the finger's joint limits,
    lies on the ball's surface and re-measures as the same touching patch at its joint values."""
    from planner.contacts import collisions, contact_patches
    from planner.slots import reachable_contacts

    g = realize(load_grasp(ALLEGRO_SPHERE))
    hand, obj = g.hand, g.obj
    pool = reachable_contacts(hand, obj, "ring")
    assert len(pool) >= 10
    idx = list(hand.fingers["ring"].q_index)
    lo, hi = np.asarray(hand.lower)[idx], np.asarray(hand.upper)[idx]
    radius = obj.size[0]
    for points, normals, qf, _ in pool:
        assert np.all(qf >= lo - 1e-9) and np.all(qf <= hi + 1e-9)
        assert np.allclose(np.linalg.norm(points, axis=1), radius, atol=1.5e-3)
        assert np.all(np.einsum("ij,ij->i", normals, -points / np.linalg.norm(points, axis=1, keepdims=True)) > 0.95)
        q = np.array(hand.q_open, float)
        q[idx] = qf
        again = contact_patches(hand, q, obj, fingers=["ring"])["ring"]
        assert np.allclose(again[0], points, atol=1e-9)
        assert collisions(hand, q, obj, fingers=("ring",)) == []
    spread = np.ptp(np.array([p.mean(axis=0) for p, _, _, _ in pool]), axis=0)
    assert np.max(spread) > 0.015  # spread over the reachable surface, not one spot


def test_local_contacts_are_small_steps_from_the_anchor_and_near_counts_normals():
    """local_contacts: every contact is within the finger's joint limits, touches the ball
    (re-measured at its joint values) and lies a short step from the anchor contact
    (between the spacing and the radius, plus the closing's slide); the same call is cached.
    near: a contact 0.5 mm away is the same one unless its normal turned 10 deg or more;
    11 mm away it is another one."""
    from planner.contacts import contact_patches
    from planner.graph import Slot
    from planner.slots import LOCAL_RADIUS_M, MIN_SLOT_SPACING_M, local_contacts, near

    g = realize(load_grasp(ALLEGRO_SPHERE))
    hand, obj = g.hand, g.obj
    anchor = g.patches["ring"][0]
    steps = local_contacts(hand, obj, "ring", anchor)
    assert len(steps) >= 3 and local_contacts(hand, obj, "ring", anchor) is steps
    idx = list(hand.fingers["ring"].q_index)
    lo, hi = np.asarray(hand.lower)[idx], np.asarray(hand.upper)[idx]
    for points, normals, qf, _ in steps:
        assert np.all(qf >= lo - 1e-9) and np.all(qf <= hi + 1e-9)
        q = np.array(hand.q_open, float)
        q[idx] = qf
        assert np.allclose(contact_patches(hand, q, obj, fingers=["ring"])["ring"][0], points, atol=1e-9)
        d = np.min(np.linalg.norm(points[:, None, :] - anchor[None, :, :], axis=2))
        assert MIN_SLOT_SPACING_M - 0.006 <= d <= LOCAL_RADIUS_M + 0.006, d

    def one(p, n):
        return Slot("ring", "x", [p], [np.asarray(n, float) / np.linalg.norm(n)])

    a = one((0.0, 0.0, 0.0), (0.0, 0.0, 1.0))
    for deg, same in ((5.0, True), (9.5, True), (10.5, False), (30.0, False)):
        t = np.radians(deg)
        assert near(a, one((0.0005, 0.0, 0.0), (np.sin(t), 0.0, np.cos(t)))) is same, deg
    assert not near(a, one((0.011, 0.0, 0.0), (0.0, 0.0, 1.0)))


def test_holding_grasp_lets_a_finger_go_and_the_rounds_use_it(realized):
    """The bundled cylinder pair: holding_grasp(thumb) gives the other fingers contacts with
    which they hold the cylinder without the thumb: re-checked force closure, no two fingers
    colliding (the thumb at its open posture), every new contact from the finger's reach."""
    from planner.contacts import contact_patches
    from planner.graph import LIFTED
    from planner.slots import build_problem, holding_grasp, pairwise_collision_check

    a, b = PAIRS["cylinder"]
    initial, final = realized(a), realized(b)
    problem = build_problem(initial, final, PlanOptions(motion=False))
    grasp = holding_grasp(problem, initial.hand, initial.obj, "thumb", "patch")
    assert grasp and "thumb" not in grasp
    assert grasp_closure({f: (s.points, s.normals) for f, s in grasp.items()}, problem.friction).is_force_closure
    fingers = dict(grasp, thumb=None)
    check = pairwise_collision_check(initial.hand, {f: (s,) for f, s in grasp.items()} | {"thumb": ()})
    for f, g in itertools.combinations(fingers, 2):
        assert check(f, LIFTED if fingers[f] is None else 0, g, LIFTED if fingers[g] is None else 0), (f, g)
    hand = initial.hand
    assert any(s not in problem.slots[f] for f, s in grasp.items())
    for f, s in grasp.items():
        if s not in problem.slots[f]:  # a new contact: re-measured at its joint values, in limits
            assert s.label == f"int{len(problem.slots[f]) - sum(t.label in ('initial', 'final') for t in problem.slots[f])}"
            idx = list(hand.fingers[f].q_index)
            assert np.all(s.q >= np.asarray(hand.lower)[idx] - 1e-9) and np.all(s.q <= np.asarray(hand.upper)[idx] + 1e-9)
            q = np.array(hand.q_open, float)
            q[idx] = s.q
            assert np.allclose(contact_patches(hand, q, initial.obj, fingers=[f])[f][0], s.points, atol=1e-9)


def test_a_search_stopped_by_the_clock_names_the_fingers_left_to_move(capsys):
    """Even when nothing was refused (the time limit ended the search before any move was
    evaluated), the explanation names at least one finger and why the plan is missing."""
    from planner.cli import main
    from planner.resources import bundled_grasp

    code = main(["plan", str(bundled_grasp("icub/box_ir2m.yaml")), str(bundled_grasp("icub/box_parallel_extension.yaml")),
                 "--execution", "--time-limit", "0.001", "-q"])
    err = capsys.readouterr().err
    assert code == 1 and "still have to move" in err and "index" in err and "--time-limit" in err


JAMMED = Path(__file__).parent / "data" / "grasps"


def test_a_contact_no_finger_path_can_leave_ends_the_search_at_once():
    """An exp8 pair whose initial thumb, at full opposition, presses the ball with its
    proximal phalanx: no retreat of the thumb is free even with every other finger open
    (its opposition joint is at its limit), so the planner says so after the first failed
    gait instead of re-planning around each state (``repose=False``); the index, in the same
    grasp, can let go. With reposing the hand carries the object off the thumb first, and the
    thumb lifts after that move."""
    from planner.errors import NoSequenceError
    from planner.retreat import retreat_blocked

    gi = realize(load_grasp(JAMMED / "icub_thumb_jammed.yaml"), None)
    gf = realize(load_grasp(JAMMED / "icub_thumb_jammed_final.yaml"), None)
    hand = gi.hand
    q = np.asarray(gi.q)
    why = retreat_blocked(hand, gi.obj, q[list(hand.fingers["thumb"].q_index)], "thumb")
    assert why is not None and "thumb_proximal" in why and "thumb_0" in why
    assert retreat_blocked(hand, gi.obj, q[list(hand.fingers["index"].q_index)], "index") is None
    with pytest.raises(NoSequenceError, match="finger thumb must leave its initial contact, and no finger path can"):
        plan_regrasp(gi, gf, PlanOptions(repose=False))
    # the hand may move the object instead: carried 2 mm off the jammed thumb, the thumb can lift
    from planner.audit import audit_plan

    plan = plan_regrasp(gi, gf, PlanOptions()).plan
    assert [s.action for s in plan.steps].count("repose") == 2
    thumb = [s.action for s in plan.steps if s.finger == "thumb"]
    assert thumb[0] == "lift" and plan.steps.index(next(s for s in plan.steps if s.finger == "thumb")) > \
        plan.steps.index(next(s for s in plan.steps if s.action == "repose"))
    assert audit_plan(plan).ok, audit_plan(plan).problems


def test_the_step_table_lists_only_touching_fingers_as_removable(tmp_path, capsys):
    """A lifted or free finger is trivially removable; the table's removable column names the
    touching fingers whose contact can go, as the plan's states say."""
    from planner.cli import main
    from planner.plan import read_plan
    from planner.resources import bundled_grasp

    out = tmp_path / "p.json"
    assert main(["plan", str(bundled_grasp("icub/box_parallel_extension.yaml")),
                 str(bundled_grasp("icub/box_ir2m.yaml")), "--no-motion", "-o", str(out)]) == 0
    rows = [line.split() for line in capsys.readouterr().out.splitlines() if line[:4].strip().isdigit()]
    plan = read_plan(out)
    assert len(rows) == len(plan.steps)
    for row, step in zip(rows, plan.steps):
        st = plan.states[step.to_state]
        listed = set() if row[-1] == "-" else set(row[-1].split(","))
        assert listed == {f for f in st.removable if f in st.patches}, (row, st.removable)
        assert step.finger not in listed or step.action == "land"  # a lifted finger is not listed


def _box_pair():
    from planner.grasp import load_grasp
    from planner.realization import realize
    from planner.resources import bundled_grasp

    return tuple(realize(load_grasp(bundled_grasp(n))) for n in ("icub/box_parallel_extension.yaml", "icub/box_ir2m.yaml"))


def _stand_in_check(monkeypatch, refuse):
    """Replace the plan's physics check by one adding the problem ``refuse(plan)`` returns (None:
    the plan passes) and the simulator by one that passes every plan; returns the plans checked
    and the plans replayed."""
    import planner.regrasp as regrasp
    import planner.sim.verify as verify
    from planner.audit import AuditReport

    audited, replays = [], []

    def check(plan, hand=None, paths=True, verified=True):
        audited.append(plan)
        rep = AuditReport("stand-in")
        line = refuse(plan)
        if line is not None:
            rep.add(line)
        return rep

    def replay(plan, hand, directions, workers=None, meanwhile=None, **kw):
        if meanwhile is not None:  # (the physics check, run while the replays run)
            meanwhile()
        replays.append(plan)
        rows = tuple((n, True, "held", None, False, 0.0, 0.0) for n, _ in directions)
        return verify.Verification(True, rows, 0.0, "pybullet", (("pybullet", rows),))

    monkeypatch.setattr(regrasp, "audit_plan", check)
    monkeypatch.setattr(verify, "verify_plan", replay)
    return audited, replays


def _orders(plans) -> list[tuple]:
    """The sequences of some plans, each once, in order."""
    return list(dict.fromkeys(tuple(p.summary["order"]) for p in plans))


def _moves(plan) -> list[tuple]:
    """Each step of a plan as (state it leaves, action, finger, state it reaches), a state as
    its fingers' slot labels."""
    def state(i):
        return tuple(sorted(plan.states[i].fingers.items()))

    return [(state(s.from_state), s.action, s.finger, state(s.to_state)) for s in plan.steps]


def test_a_plan_the_physics_check_refuses_is_never_returned_and_its_replays_count_for_nothing(monkeypatch):
    """plan --execution runs the physics check `replay` and `verify` run on a plan file
    (planner.audit) while it replays the plan: a check refusing a state of every plan takes
    that state's moves out of the graph each time, until no sequence is left: the pair is
    refused, naming the check's problems, none of the replays (all passing) counted as a
    verification attempt; no plan is checked twice."""
    import planner.regrasp as regrasp
    from planner.errors import NoSequenceError
    from planner.options import PlanOptions

    a, b = _box_pair()
    line = "states[2]: finger thumb touches the object at the state's joints but the plan has it lifted (made up)"
    audited, replays = _stand_in_check(monkeypatch, lambda plan: line)
    with pytest.raises(NoSequenceError) as err:
        regrasp.plan_regrasp(a, b, PlanOptions.for_execution(motion=False, repose=False))
    assert audited and _orders(replays) == _orders(audited)
    assert "moves the plan's physics check refused" in str(err.value)
    assert "failed in the simulator" not in str(err.value)
    assert "states[2]: finger thumb touches" in str(err.value)
    orders = [tuple(_moves(p)) for p in audited]
    assert len(set(orders)) == len(orders)  # every refusal removed something: a new sequence each time


def test_a_move_the_physics_check_refuses_gives_way_to_the_next_sequence(monkeypatch):
    """The check refuses the first plan's step 1 (the path of its second step): the planner
    takes that move out and returns another sequence, the one the simulator then replays;
    the returned plan does not make the refused move from the same state."""
    import planner.regrasp as regrasp
    from planner.options import PlanOptions

    a, b = _box_pair()
    first = []

    def refuse(plan):
        if not first:
            first.append(plan)
            return "steps[1] (lift thumb): path waypoint 3: link thumb_distal 2.0 mm inside the object (made up)"
        return None

    audited, replays = _stand_in_check(monkeypatch, refuse)
    res = regrasp.plan_regrasp(a, b, PlanOptions.for_execution(motion=False, repose=False))
    assert len(audited) == 2 and _orders(replays) == _orders(audited)  # (the first one's replays ignored)
    assert res.plan.summary["order"] == audited[1].summary["order"]
    assert res.plan.summary["verification"]["attempts"] == 1
    assert _moves(first[0])[1] not in _moves(res.plan)
    assert res.plan.summary["verification"]["passed"]


def test_a_physics_check_problem_outside_the_moves_refuses_at_once(monkeypatch):
    """A problem no other sequence can mend (here the plan's parameters) refuses the pair at
    the first plan, with the check's words and the --no-verify hint."""
    import planner.regrasp as regrasp
    from planner.errors import NoSequenceError
    from planner.options import PlanOptions

    a, b = _box_pair()
    audited, replays = _stand_in_check(monkeypatch, lambda plan: "parameters.hold_factor: 1, below 2 (made up)")
    with pytest.raises(NoSequenceError) as err:
        regrasp.plan_regrasp(a, b, PlanOptions.for_execution(motion=False, repose=False))
    assert len(audited) == 1 and _orders(replays) == _orders(audited)
    assert "fails the physics check replay and verify run on a plan: parameters.hold_factor" in str(err.value)
    assert "--no-verify" in str(err.value)

