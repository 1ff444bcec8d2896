"""Smoke test of the experiments: the fastest one, in --quick mode, into a temporary directory."""

import csv

import pytest


def test_exp1_quick_writes_csv_and_png(tmp_path, capsys):
    from experiments import exp1_cone_edges

    summary = exp1_cone_edges.main(["--quick", "--workers", "1", "--no-progress", "--out", str(tmp_path)])
    rows = list(csv.DictReader(open(tmp_path / "exp1_cone_edges.csv")))
    assert [int(r["edges"]) for r in rows][:3] == [3, 4, 5]
    assert sorted({r["contact_model"] for r in rows}) == ["mean", "patch"]
    assert sum(r["contact_model"] == "mean" and int(r["wrenches"]) == 2 * int(r["edges"]) * 5 for r in rows) == 12
    assert all(r["force_closure"] == "True" for r in rows)
    assert (tmp_path / "exp1_cone_edges.png").stat().st_size > 1000
    assert summary["metric_reference"] > 0
    assert "exp1 cone edges" in capsys.readouterr().out


def test_dask_option_without_dask_is_one_line_error(monkeypatch):
    import sys

    from experiments.common import parser, run_tasks

    monkeypatch.setitem(sys.modules, "dask.distributed", None)  # import fails as if not installed
    args = parser("x").parse_args(["--dask-scheduler", "tcp://127.0.0.1:1", "--no-progress"])
    with pytest.raises(SystemExit, match="pip install 'dask\\[distributed\\]'"):
        run_tasks(abs, [1, -2], args)


def test_dask_scheduler_runs_the_same_sweep_as_local_processes(tmp_path):
    """exp1 --quick on a real Dask cluster (scheduler on TCP, two worker processes) gives the
    same metrics and removable sets as in-process."""
    from dask.distributed import LocalCluster

    from experiments import exp1_cone_edges

    def table(out):
        return [(r["contact_model"], r["edges"], r["metric"], r["removable"])
                for r in csv.DictReader(open(out / "exp1_cone_edges.csv"))]

    common = ["--quick", "--no-progress"]
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        exp1_cone_edges.main(common + ["--dask-scheduler", cluster.scheduler_address, "--out", str(tmp_path / "dask")])
    exp1_cone_edges.main(common + ["--workers", "1", "--out", str(tmp_path / "local")])
    rows = table(tmp_path / "dask")
    assert len(rows) == 24  # (11 edge counts + the reference) x 2 contact models
    assert rows == table(tmp_path / "local")


def test_local_workers_get_one_blas_thread_and_parent_env_is_restored(monkeypatch):
    import os

    from experiments.common import BLAS_THREAD_VARS, parser, run_tasks

    for k in BLAS_THREAD_VARS:
        monkeypatch.delenv(k, raising=False)
    monkeypatch.setenv("MKL_NUM_THREADS", "3")  # a user's own setting is kept
    args = parser("x").parse_args(["--workers", "2", "--no-progress"])
    assert run_tasks(os.getenv, list(BLAS_THREAD_VARS), args) == ["1", "1", "3"]
    assert "OPENBLAS_NUM_THREADS" not in os.environ and os.environ["MKL_NUM_THREADS"] == "3"


def test_local_pool_keeps_task_order():
    from experiments.common import parser, run_tasks

    args = parser("x").parse_args(["--workers", "2", "--no-progress"])
    assert run_tasks(abs, [-3, 1, -2], args) == [3, 1, 2]


def test_exp7_quick_replays_one_pair_per_direction(tmp_path, capsys):
    """exp7 --quick on one pair (palm down and up): one CSV row per direction with the
    planning, replay and closure-agreement columns, and the summary PNG."""
    from experiments import exp7_execution

    summary = exp7_execution.main(["--quick", "--max-pairs", "1", "--directions", "2", "--no-progress",
                                   "--out", str(tmp_path)])
    rows = list(csv.DictReader(open(tmp_path / "exp7_execution.csv")))
    assert [r["direction"] for r in rows] == ["palm_down", "palm_up"]
    for col in ("pair", "hand", "family", "variant", "mode", "valid_input", "planned", "plan_time_s", "passed",
                "max_drift_mm", "max_drift_deg", "closure_agree", "closure_reached", "replay_time_s", "verdict"):
        assert col in rows[0], col
    assert all(r["pair"] == "icub/cylinder" and r["family"] == "cylinder" and r["planned"] == "True" for r in rows)
    assert all(r["passed"] in ("True", "False") and int(r["closure_agree"]) <= int(r["closure_reached"]) for r in rows)
    assert (tmp_path / "exp7_execution.png").stat().st_size > 1000
    assert summary["pairs"] == 1 and summary["planned"] == "1/1"
    assert "exp7 execution" in capsys.readouterr().out


def test_exp7_pair_list_covers_families_hands_and_sizes():
    """The full sweep has at least 40 pairs over spheres, boxes, cylinders and the thin rod,
    on both hands, in several sizes (meshes join when grasps/*/mesh_*.yaml pairs exist)."""
    from experiments import exp7_execution
    from experiments.common import load_spec

    tasks = exp7_execution.pair_tasks(quick=False)
    assert len(tasks) >= 40
    fams = {exp7_execution.family(exp7_execution.scaled(load_spec(t["initial"]), t["mode"], t["scale"], (0, 0, 1)).object)
            for t in tasks}
    assert {"sphere", "box", "cylinder", "rod"} <= fams
    assert {load_spec(t["initial"]).hand_ref for t in tasks} >= {"icub_right", "allegro_right"}
    for pair in {t["pair"] for t in tasks}:  # several sizes of every object
        assert len({(t["mode"], t["scale"]) for t in tasks if t["pair"] == pair}) >= 3, pair
    assert len(exp7_execution.pair_tasks(quick=True)) in (3, 4)


def test_exp7_heavy_set_scales_mass_and_budget_together():
    """--heavy adds every library pair once per factor; `heavier` multiplies the object's
    mass and nothing else, and refuses a grasp without mass_kg with the grasp's name."""
    from dataclasses import replace

    from experiments import exp7_execution as e7
    from experiments.common import load_spec

    plain, heavy = e7.pair_tasks(quick=False), e7.pair_tasks(quick=False, heavy=True)
    extra = [t for t in heavy if t["mode"] == "mass"]
    assert len(heavy) == len(plain) + len(extra) == len(plain) + len(e7.LIBRARY) * len(e7.HEAVY_FACTORS)
    assert sorted({t["scale"] for t in extra}) == sorted(e7.HEAVY_FACTORS)
    spec = load_spec(extra[0]["initial"])
    h = e7.heavier(spec, 4.0)
    assert h.object.mass_kg == pytest.approx(4.0 * spec.object.mass_kg)
    assert h.object.replaced(mass_kg=spec.object.mass_kg) == spec.object and h.fingers == spec.fingers
    with pytest.raises(ValueError, match="mass_kg"):
        e7.heavier(replace(spec, object=spec.object.replaced(mass_kg=None)), 2.0)


def test_exp8_quick_plans_a_synthesized_pair_three_ways(tmp_path, capsys):
    """exp8 --quick: grasps synthesized at one fixed pose, one pair planned with defaults, with the
    graph only and in execution mode; one CSV row with a reason for every mode that failed."""
    from experiments import exp8_random_pairs as exp8

    summary = exp8.main(["--quick", "--workers", "1", "--directions", "1", "--no-progress", "--out", str(tmp_path),
                         "--execution-set", "1", "--save-plans", str(tmp_path / "plans")])
    rows = list(csv.DictReader(open(tmp_path / "exp8_random_pairs.csv")))
    assert len(rows) == 1 and summary["pairs"] == 1
    r = rows[0]
    assert r["hand"] == "allegro_right" and r["family"] == "sphere" and r["initial"] != r["final"]
    assert r["execution_set"] == "1" and r["planned_for"] == "palm_down"
    saved = sorted(p.name for p in (tmp_path / "plans").iterdir())  # a plan file exactly when execution planned one
    assert saved == (["allegro_right_sphere_r30_1.json"] if r["execution_solved"] == "True" else [])
    for mode in exp8.MODES:
        assert r[f"{mode}_solved"] in ("True", "False") and float(r[f"{mode}_time_s"]) > 0
        assert (r[f"{mode}_solved"] == "True") == (r.get(f"{mode}_why", "") == "")  # a failure says why
    assert (r["reason"] == "") == (r["default_solved"] == r["execution_solved"] == "True" and r.get("exec_all") == "True")
    synth = list(csv.DictReader(open(tmp_path / "exp8_random_pairs_synth.csv")))
    assert len({s["pose"] for s in synth}) == 1 and len(synth) == 2  # one fixed pose, two finger sets
    assert (tmp_path / "exp8_random_pairs.png").stat().st_size > 1000
    assert "exp8 random pairs" in capsys.readouterr().out


def test_exp8_synthesis_crash_loses_one_finger_set_not_the_sweep(monkeypatch):
    """A finger set whose synthesis raises (e.g. a solver failure) finds nothing, its error is
    kept and named in the summary; the pose search goes on to the next set, the other sets'
    grasps are kept."""
    from types import SimpleNamespace

    import planner.synthesis
    from experiments import exp8_random_pairs as exp8
    from planner.errors import PlannerError

    pose = {"object": {"position": [0.0, 0.0, 0.1], "quat_xyzw": [0.0, 0.0, 0.0, 1.0]}}

    def fake(hand, block, fingers, n, *, fixed, seed, max_attempts, **kw):
        if fingers == ["a", "b", "c"]:  # the largest set: the pose search and the fixed-pose synthesis crash
            raise PlannerError("grip force LP failed (HiGHS status 4)\nfor 3 finger(s)")
        g = SimpleNamespace(data=dict(pose, fingers=fingers, seed=seed), grasp=SimpleNamespace(metric=0.5))
        return SimpleNamespace(grasps=[g] * n, attempts=7, seconds=0.1)

    monkeypatch.setattr(planner.synthesis, "synthesize", fake)
    out = exp8.synth_task({"hand": "allegro_right", "object": "x", "block": {"shape": "sphere", "size": [0.02]},
                           "sets": ["a,b,c", "a,b"], "per_set": 2, "seed": 5})
    assert out["pose_from"] == "a,b" and out["pose"] == [[0.0, 0.0, 0.1], [0.0, 0.0, 0.0, 1.0]]
    assert out["errors"] == ["pose a,b,c: PlannerError: grip force LP failed (HiGHS status 4) for 3 finger(s)",
                             "a,b,c: PlannerError: grip force LP failed (HiGHS status 4) for 3 finger(s)"]
    assert out["synth"] == [{"fingers": "a,b,c", "found": 0, "error": out["errors"][1]},
                            {"fingers": "a,b", "found": 2, "attempts": 7, "seconds": 0.1}]
    assert [(g["fingers"], g["rank"]) for g in out["grasps"]] == [("a,b", 0), ("a,b", 1), ("a,b", 2)]
    s = exp8.summarize([], [out])
    assert s["objects with a pose"] == "1/1" and s["synthesis crashes (finger set lost)"].count("allegro_right x") == 2


def test_exp8_pairs_replay_rows_and_reasons(tmp_path, capsys):
    """Pairs: distinct grasps, never the same two twice, across finger sets first, seeded.
    Replay rows: pass per generic direction, all / sideways, the first failing verdict; the
    pass over the directions the plan was made for (--execution-set) and its first failure."""
    from pathlib import Path
    from types import SimpleNamespace

    from experiments import exp8_random_pairs as exp8
    from planner.errors import NoSequenceError

    grasps = [{"fingers": f} for f in ("a", "a", "b", "b", "c")]
    pairs = exp8.draw_pairs(grasps, 6, seed=3)
    assert pairs == exp8.draw_pairs(grasps, 6, seed=3) and len(pairs) == 6
    assert all(i != j for i, j in pairs) and len({frozenset(p) for p in pairs}) == 6
    assert all(grasps[i]["fingers"] != grasps[j]["fingers"] for i, j in pairs)  # 8 cross-set pairs exist
    assert len(exp8.draw_pairs(grasps[:2], 5, seed=0)) == 1

    def rep(ok, verdict="PASS"):
        return SimpleNamespace(passed=ok, max_drift_deg=1.0 if ok else 40.0, verdict=verdict)

    names = ["palm_down", "palm_up", "side_+y", "side_-y", "side_+z", "side_-z", "off"]
    fake = [(n, rep(n != "side_-y", "FAIL: dropped at step 2" if n == "side_-y" else "PASS"), 0.5) for n in names]
    orig = exp8.replay_all
    exp8.replay_all = lambda plan, hand, n: fake
    try:
        row = exp8.replay_row({}, None, 7)
    finally:
        exp8.replay_all = orig
    assert row["exec_palm_down"] and row["exec_palm_up"] and row["exec_off"] and not row["exec_side_2"]
    assert not row["exec_all"] and not row["exec_sideways"] and row["replay_s"] == 3.5
    assert row["replay_fail"] == "replay side_2: FAIL: dropped at step 2"
    assert row["verdict_side_2"] == "FAIL: dropped at step 2" and row["verdict_off"] == "PASS"
    assert "exec_planned_for" not in row  # no planned-for directions given: no column
    exp8.replay_all = lambda plan, hand, n: fake
    try:  # planned for palm down and up (set 2): the sideways failure is not a planned-for one
        two = exp8.replay_row({}, None, 7, ["palm_down", "palm_up"])
        six = exp8.replay_row({}, None, 7, names[:6])
    finally:
        exp8.replay_all = orig
    assert two["exec_planned_for"] and two["planned_for_fail"] == "" and not two["exec_all"]
    assert not six["exec_planned_for"] and six["planned_for_fail"] == "replay side_2: FAIL: dropped at step 2"
    assert exp8.options("execution", 0, gravity_set=1).gravity_set == 1 and exp8.options("execution", 0).gravity_set == 6
    assert exp8.plan_path(Path("d"), "icub_right", "box 30x40x50", 2) == Path("d/icub_right_box_30x40x50_2.json")
    summary = exp8.summarize([{"pair": "p", "hand": "h", "family": "f", "default_solved": True, "graph_solved": False,
                               "execution_solved": True, "mean_fc": True, "default_time_s": 1.0, "graph_time_s": 0.1,
                               "execution_time_s": 2.0, "execution_set": 6, "planned_for": "palm_down",
                               "reason": six["replay_fail"], **six, "exec_planned_for": False, "plan_file": "d/p.json"}])
    assert summary["execution: pass every planned-for direction"] == "0/1 (0.0 %)"
    assert summary["hand h"].endswith("pass planned-for 0, palm down 1, off 1")
    assert summary["execution replay failures in planned-for directions"] == \
        "p: replay side_2: FAIL: dropped at step 2 [d/p.json]"
    (tmp_path / "f").write_text("x")
    with pytest.raises(SystemExit) as exc:  # a file where the plans' folder should be: refused before any work
        exp8.main(["--save-plans", str(tmp_path / "f"), "--out", str(tmp_path)])
    assert exc.value.code == 2 and "is not a directory" in capsys.readouterr().err
    assert (tmp_path / "f").read_text() == "x"
    err = NoSequenceError("no finger-gaiting sequence: ...; the time limit of 10 s was reached",
                          report={"never_removable": ["thumb"], "landing_blocked": {"ring": {}}})
    assert exp8._why(err) == "never removable: thumb; cannot land: ring; time limit reached"
    assert exp8._why(NoSequenceError("the final grasp 'x' is not force closure with the 'mean' contact model "
                                     "(metric -0.01)")) == "final grasp not force closure with mean contacts"
    assert exp8.reason({"replay_fail": "replay side_2: x"}, {"execution": "cannot land: ring"}) == \
        "execution: cannot land: ring"


def test_quick_runs_never_write_over_the_committed_results():
    """--quick writes to experiments/results/quick unless --out says otherwise; full runs to
    experiments/results (the committed numbers)."""
    from experiments.common import QUICK_RESULTS, RESULTS, parser

    assert parser("x").parse_args(["--quick"]).out == QUICK_RESULTS != RESULTS
    assert parser("x").parse_args([]).out == RESULTS
    assert parser("x").parse_args(["--quick", "--out", "elsewhere"]).out.name == "elsewhere"


def test_exp10_reach_cause_groups_the_reposing_refusals():
    from experiments.exp10_reposing import reach_cause

    assert reach_cause("reposing, 0.9 mm / 0.9 deg along the object's path (waypoint 1/9): thumb cannot keep its "
                       "contact on the object (off by 2.23 mm; at their limits: joint_12.0)") == "finger at a joint limit"
    assert reach_cause("... (waypoint 1/9): middle cannot keep its contact on the object (off by 0.57 mm)") == \
        "finger cannot follow (joints free)"
    assert reach_cause("... (waypoint 5/21): collision link_15.0_tip - object 0.55 mm deep") == "link into the object"
    assert reach_cause("... (waypoint 3/28): fingers collide (middle - ring)") == "hand self-collision"
    assert reach_cause("... (waypoint 2/11): palm_up: holds 0x its weight (needs 2x)") == \
        "no valid state (closure or load)"


def test_exp10_reach_measures_how_far_each_grasp_carries_the_object(tmp_path, capsys):
    """The Allegro small-sphere pair: its final grasp carries the object all the way back to the
    initial grasp's pose, the initial grasp's thumb stops at once at its joint limits; the CSV
    says so, and the full move re-done independently ends at the initial pose."""
    import numpy as np

    from experiments.exp10_reposing import DEFAULT_PAIRS, main
    from planner.grasp import load_grasp
    from planner.options import PlanOptions
    from planner.realization import realize
    from planner.repose import repose

    out = tmp_path / "reach.csv"
    s = main(["--reach", "--label", "t", "--only", "^allegro_right_sphere_small$", "--out", str(out), "--quiet"])
    rows = list(csv.DictReader(out.open()))
    assert len(rows) == 1 and s["pairs"] == 1
    r = rows[0]
    assert float(r["reach_b_to_a"]) == 1.0 and r["cause_b"] == ""
    assert float(r["reach_a_to_b"]) < 1.0 and r["cause_a"] == "finger at a joint limit"
    assert r["meet"] == "True" and s["a pose on the path both grasps reach"] == 1
    # the fingers' own path: the final grasp's drive reaches the initial pose too, and they meet
    assert float(r["drive_b_to_a"]) == 1.0 and r["drive_cause_b"] == "" and r["drives_meet"] == "True"
    ga = realize(load_grasp(DEFAULT_PAIRS / "allegro_right_sphere_small_initial.yaml"))
    gb = realize(load_grasp(DEFAULT_PAIRS / "allegro_right_sphere_small_final.yaml"))
    move = repose(gb, ga.obj.T_palm_obj, PlanOptions.for_execution())
    assert np.allclose(move.end.obj.T_palm_obj, ga.obj.T_palm_obj, atol=1e-9)
    assert set(move.fingers) == set(gb.patches) - {"palm"}


def test_exp10_v2_cell_is_synthesized_execution_ready_and_reproducible(tmp_path):
    """One v2 cell (iCub sphere, small offset): three synthesized grasps that execution mode
    accepts as end grasps, pose B within the class's offsets, the control's thumb at least 5 mm
    from grasp A's, and the same bytes when the cell is generated again."""
    from experiments.exp10_reposing import CLASSES, CONTROL_THUMB_MOVE_M
    from experiments.exp10_v2 import ROLES, generate_cell
    from planner.grasp import load_grasp, load_hand
    from planner.realization import execution_refusal, realize

    hand = load_hand("icub_right")
    texts = []
    for d in (tmp_path / "a", tmp_path / "b"):
        (d / "meshes").mkdir(parents=True)
        row = generate_cell(hand, "sphere", "small", 0, d, log=lambda *a: None)
        assert row["status"] == "ok"
        texts.append([(d / row[r]).read_text() for r in ROLES])
    assert texts[0] == texts[1]
    (t_lo, t_hi), (r_lo, r_hi) = CLASSES["small"]
    assert t_lo <= row["pose_mm"] <= t_hi and r_lo <= row["pose_deg"] <= r_hi
    assert row["control_thumb_move_mm"] >= CONTROL_THUMB_MOVE_M * 1e3
    for r in ROLES:
        g = realize(load_grasp(tmp_path / "b" / row[r]))
        assert g.ok and execution_refusal(g) is None
