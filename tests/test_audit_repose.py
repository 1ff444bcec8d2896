"""`regrasp verify` (planner.audit) on schema 4 plans: a reposing step (the object moved along
``object_path`` with every holding finger following it) is checked waypoint by waypoint, and
every state is checked with the object at its own pose. A plan the planner wrote passes; an
edited one, resealed with a fresh digest, fails naming the step, the waypoint and the check."""

from __future__ import annotations

import copy
import json
from dataclasses import replace

import numpy as np
import pytest

from planner.audit import REPOSE_FOLLOW_TOL_M, audit_plan
from planner.cli import main
from planner.plan import read_plan
from planner.plan_data import integrity_record, write_plan

SHIFT_M = 0.002  # the object moved 2 mm along the palm's x


@pytest.fixture(scope="module")
def plan_data(tmp_path_factory):
    """A plan of one reposing step: the bundled Allegro four-finger box grasp, its object moved
    2 mm (`planner.repose.repose`, assembled by `planner.pose_search.compose`)."""
    from planner import pose_search
    from planner.closure import GRIP_CONE_SIDES
    from planner.grasp import load_grasp
    from planner.options import PlanOptions, gravity_directions_of
    from planner.realization import realize
    from planner.repose import repose
    from planner.resources import bundled_grasp

    g = realize(load_grasp(bundled_grasp("allegro/box_four_finger.yaml")))
    opts = PlanOptions.for_execution(motion=False, verify=False)
    T = np.array(g.obj.T_palm_obj, float)
    T[0, 3] += SHIFT_M
    r = repose(g, T, opts)
    if hasattr(pose_search, "Leg"):  # a leg: fingers lifted first (none here), then the move
        leg = pose_search.Leg
        plan = pose_search.compose(g, r.end, opts, leg(g, [], r, r.end), None, leg(r.end, [], None, r.end), T)
    else:
        plan = pose_search.compose(g, r.end, opts, r, None, None, T)
    params = dict(plan.parameters)
    if not params.get("gravity_directions"):  # as plan_regrasp records them
        d = gravity_directions_of(opts, g.hand)
        params["gravity_directions"] = [{"name": n, "gravity": list(v)} for n, v in d] or None
        params["grip_cone_sides"] = GRIP_CONE_SIDES if d else None
    path = tmp_path_factory.mktemp("repose") / "repose.json"
    write_plan(replace(plan, parameters=params), path)
    return path, json.loads(path.read_text())


def _reseal(data: dict, path) -> None:
    data["integrity"] = integrity_record(data)
    path.write_text(json.dumps(data))


def _repose_index(data) -> int:
    return next(k for k, s in enumerate(data["steps"]) if s["action"] == "repose")


def test_the_plan_has_a_reposing_step_and_passes(plan_data, capsys):
    path, data = plan_data
    assert data["schema_version"] == 4
    k = _repose_index(data)
    step = data["steps"][k]
    assert step["finger"] == "object" and len(step["object_path"]) == len(step["path"]) >= 3
    assert data["states"][step["to_state"]].get("object_pose") is not None
    rep = audit_plan(read_plan(path))
    assert rep.ok, rep.problems
    assert rep.checked["reposing waypoints"] == len(step["path"])
    assert rep.checked["reposing contacts"] == 4
    assert main(["verify", str(path)]) == 0
    assert "plan verified" in capsys.readouterr().out


def _problems(data, tmp_path, name="bad.json") -> list[str]:
    bad = tmp_path / name
    _reseal(data, bad)
    return audit_plan(read_plan(bad)).problems


def test_an_object_pose_moved_3_mm_is_refused_naming_the_step(plan_data, tmp_path, capsys):
    path, data = plan_data
    d = copy.deepcopy(data)
    k = _repose_index(d)
    w = len(d["steps"][k]["object_path"]) // 2  # a middle waypoint: the ends are tied to the states
    d["steps"][k]["object_path"][w][2] += 0.003
    problems = _problems(d, tmp_path)
    assert problems
    assert any(p.startswith(f"steps[{k}] (repose object): path waypoint {w}:") and "does not stay fixed" in p
               for p in problems), problems
    assert any(p.startswith(f"steps[{k}] (repose object): object path waypoint") and "jumps" in p for p in problems)
    bad = tmp_path / "bad.json"
    assert main(["verify", str(bad)]) == 1
    assert f"steps[{k}] (repose object)" in capsys.readouterr().out


def test_a_finger_that_does_not_follow_is_refused(plan_data, tmp_path):
    """A joint of a holding finger frozen at its start value along the move: that finger's
    contact slips on the moving object."""
    path, data = plan_data
    d = copy.deepcopy(data)
    k = _repose_index(d)
    step = d["steps"][k]
    col = step["joints"].index(next(j for j in step["joints"] if abs(step["path"][-1][step["joints"].index(j)]
                                                                      - step["path"][0][step["joints"].index(j)]) > 1e-3))
    # the largest-moving joint held back by 0.15 rad in the middle of the move
    w = len(step["path"]) // 2
    step["path"][w][col] += 0.15
    problems = _problems(d, tmp_path)
    assert any(p.startswith(f"steps[{k}] (repose object): path waypoint {w}:") and "from the object point it holds"
               in p for p in problems), problems


def test_object_path_not_at_the_states_poses_is_refused(plan_data, tmp_path):
    """The end state's pose and the path's last pose moved together 3 mm (read_plan ties them
    to 1e-6): the last state's contacts are then off the object and the last jump too long."""
    path, data = plan_data
    d = copy.deepcopy(data)
    k = _repose_index(d)
    to = d["steps"][k]["to_state"]
    d["steps"][k]["object_path"][-1][2] += 0.003
    d["states"][to]["object_pose"]["position"][2] += 0.003
    problems = _problems(d, tmp_path)
    assert any(p.startswith(f"steps[{k}] (repose object): object path waypoint") for p in problems), problems
    assert any(p.startswith(f"states[{to}]") for p in problems), problems


def test_joint_limits_along_a_reposing_move(plan_data, tmp_path):
    path, data = plan_data
    d = copy.deepcopy(data)
    k = _repose_index(d)
    d["steps"][k]["path"][1][0] = 10.0
    problems = _problems(d, tmp_path)
    assert any(p.startswith(f"steps[{k}] (repose object): path waypoint 1:") and "joint limits" in p
               for p in problems), problems


def test_reposing_summary_is_recomputed(plan_data, tmp_path):
    path, data = plan_data
    d = copy.deepcopy(data)
    assert abs(d["summary"]["reposing"]["object_path_mm"] - SHIFT_M * 1e3) < 1e-3
    d["summary"]["reposing"]["object_path_mm"] = 25.0
    d["summary"]["reposing"]["moves"] = 2
    problems = _problems(d, tmp_path)
    assert any(p.startswith("summary.reposing.object_path_mm: the file says 25.0") for p in problems), problems
    assert any(p.startswith("summary.reposing.moves") for p in problems), problems


def test_follow_tolerance_is_the_planners_own():
    from planner.repose import FOLLOW_TOL_M

    assert 2 * FOLLOW_TOL_M <= REPOSE_FOLLOW_TOL_M < 1e-3


def test_the_view_moves_the_object_along_the_reposing_step(plan_data):
    """The page draws every state's object at its pose and a reposing step's frames move it
    from the from-state's pose to the to-state's."""
    from planner.view import plan_page_data

    path, data = plan_data
    _, page = plan_page_data(read_plan(path), path)
    k = _repose_index(data)
    step = page["steps"][k]
    a, b = page["states"][step["from"]]["obj"], page["states"][step["to"]]["obj"]
    assert len(step["obj"]) == len(step["frames"])
    assert np.allclose(step["obj"][0], a, atol=1e-5) and np.allclose(step["obj"][-1], b, atol=1e-5)
    # meshcat's column-major 4x4: the translation is entries 12-14; the object moved SHIFT_M along x
    assert abs((b[12] - a[12]) - SHIFT_M) < 1e-4
    xs = [T[12] for T in step["obj"]]
    assert all(x1 >= x0 - 1e-9 for x0, x1 in zip(xs, xs[1:]))  # monotonic along the straight path


def test_waypoints_with_the_object_still_may_re_posture_but_keep_each_contact(plan_data, tmp_path):
    """Waypoints after the object stopped (the planner's re-posturing of a finger that touches
    the same point with another posture, `planner.pose_search._reposture`) are checked for
    contact where they touch, not against the contact fixed in the link: copies of the last
    waypoint pass; one with a holding finger's largest-moving joint opened 0.15 rad is refused
    as a re-posturing waypoint whose link no longer touches its point."""
    path, data = plan_data
    d = copy.deepcopy(data)
    k = _repose_index(d)
    step = d["steps"][k]
    last_q, last_T = step["path"][-1], step["object_path"][-1]
    step["path"][-1:] = [list(last_q)] * 3
    step["object_path"][-1:] = [list(last_T)] * 3
    assert _problems(d, tmp_path, "still.json") == []
    col = max(range(len(step["joints"])), key=lambda c: abs(step["path"][-1][c] - step["path"][0][c]))
    step["path"][-2] = list(last_q)
    step["path"][-2][col] -= 0.15
    w = len(step["path"]) - 2
    problems = _problems(d, tmp_path, "rolled.json")
    assert any(p.startswith(f"steps[{k}] (repose object): path waypoint {w} (the object still, the fingers "
                            f"re-posturing)") for p in problems), problems


def test_waypoints_with_the_object_still_before_the_move_are_checked_where_they_touch(plan_data, tmp_path):
    """The same check before the object starts moving (a move back to the final grasp,
    reversed, re-postures first): copies of the first waypoint pass; one of them with a
    holding finger's largest-moving joint opened 0.15 rad is refused as a re-posturing
    waypoint, and still waypoints at both ends pass together."""
    path, data = plan_data
    d = copy.deepcopy(data)
    k = _repose_index(d)
    step = d["steps"][k]
    first_q, first_T = step["path"][0], step["object_path"][0]
    step["path"][:1] = [list(first_q)] * 3
    step["object_path"][:1] = [list(first_T)] * 3
    assert _problems(d, tmp_path, "still_first.json") == []
    both = copy.deepcopy(d)
    both["steps"][k]["path"][-1:] = [list(step["path"][-1])] * 3
    both["steps"][k]["object_path"][-1:] = [list(step["object_path"][-1])] * 3
    assert _problems(both, tmp_path, "still_both.json") == []
    col = max(range(len(step["joints"])), key=lambda c: abs(step["path"][-1][c] - step["path"][0][c]))
    step["path"][1] = list(first_q)
    step["path"][1][col] -= 0.15
    problems = _problems(d, tmp_path, "rolled_first.json")
    assert any(p.startswith(f"steps[{k}] (repose object): path waypoint 1 (the object still, the fingers "
                            f"re-posturing)") for p in problems), problems
