"""Finger paths (planner.motion) on the iCub hand, re-checked independently with coal.

The re-check does not use the motion module's collision scene: it poses the hand with
``hand.collision_objects`` at every waypoint and at points in between (joint steps of at
most 5 mrad, which moves any point of a finger by well under 1 mm), and measures signed
distances with ``coal.distance``. Link pairs that already overlap at q = 0 or at the open
posture (shapes joined by design, e.g. consecutive phalanges) are not checked.
"""

import subprocess
import sys
import textwrap
from pathlib import Path

import coal
import numpy as np
import pytest

from planner.errors import InputError, MotionError, UnknownNameError
from planner.hand import Hand
from planner.finger_scene import DEFAULT_CLEARANCE_M, DEFAULT_TOUCH_TOL_M
from planner.motion import available_planners, plan_finger_move, plan_gait_step
from planner.objects import make_object
from planner.realization import realize_contact

RECHECK_RAD = 0.005


@pytest.fixture(scope="module")
def hand():
    return Hand.load("icub_right")


def _pose(position):
    T = np.eye(4)
    T[:3, 3] = position
    return T


@pytest.fixture(scope="module")
def obstacle():
    """A small box in the sweep of the index finger flexing from flat to upright."""
    return make_object("box", (0.015, 0.03, 0.015), _pose([0.065, -0.026, 0.035]))


@pytest.fixture(scope="module")
def held_box():
    """A box over the palm that the index and the thumb can touch."""
    return make_object("box", (0.05, 0.05, 0.03), _pose([0.045, -0.01, 0.03]))


def _tf_matrix(tf):
    T = np.eye(4)
    T[:3, :3] = tf.getRotation()
    T[:3, 3] = tf.getTranslation()
    return T


def _coal_tf(T):
    return coal.Transform3s(np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3]))


def _distance(g1, T1, g2, T2):
    return coal.distance(g1, _coal_tf(T1), g2, _coal_tf(T2), coal.DistanceRequest(), coal.DistanceResult())


def _bodies(hand, q):
    return [(link, finger, geom, _tf_matrix(tf)) for link, finger, geom, tf in hand.state(q).collision_objects()]


@pytest.fixture(scope="module")
def overlapping_pairs(hand):
    """Link pairs that overlap at q = 0 or at the open posture: not collisions."""
    pairs = set()
    for q in (np.clip(np.zeros(len(hand.joint_names)), hand.lower, hand.upper), np.asarray(hand.q_open)):
        bodies = _bodies(hand, q)
        for i, (la, _, ga, Ta) in enumerate(bodies):
            for lb, _, gb, Tb in bodies[i + 1:]:
                if la != lb and _distance(ga, Ta, gb, Tb) < 1e-6:
                    pairs.add(frozenset((la, lb)))
    return pairs


def _full(q_ref, idx, path):
    out = np.repeat(np.asarray(q_ref, float)[None], len(path), axis=0)
    out[:, idx] = path
    return out


def _fine(path):
    """Subdivide a joint path so that no joint moves more than RECHECK_RAD per step."""
    rows = [path[0]]
    for a, b in zip(path[:-1], path[1:]):
        n = max(1, int(np.ceil(np.max(np.abs(b - a)) / RECHECK_RAD)))
        rows.extend(a + (b - a) * t for t in np.arange(1, n + 1) / n)
    return np.array(rows)


def _worst(hand, obj, q_ref, finger, path, overlapping_pairs):
    """(min finger-object distance, max finger penetration into palm/other/own links)."""
    idx = list(hand.fingers[finger].q_index)
    T_palm_obj = np.asarray(obj.T_palm_obj)
    d_obj, depth = np.inf, 0.0
    for q in _full(q_ref, idx, _fine(path)):
        bodies = _bodies(hand, q)
        moving = [b for b in bodies if b[1] == finger]
        for link, _, geom, T in moving:
            d_obj = min(d_obj, _distance(geom, T, obj.geometry, T_palm_obj))
            for other, _, g2, T2 in bodies:
                if other == link or frozenset((link, other)) in overlapping_pairs:
                    continue
                depth = max(depth, -_distance(geom, T, g2, T2))
    return d_obj, depth


def _assert_path_ok(hand, obj, q_ref, finger, path, overlapping_pairs, *, object_min_m):
    f = hand.fingers[finger]
    idx = list(f.q_index)
    assert path.ndim == 2 and path.shape[1] == len(f.joints)
    assert np.all(path >= np.asarray(hand.lower)[idx] - 1e-9)
    assert np.all(path <= np.asarray(hand.upper)[idx] + 1e-9)
    assert np.max(np.abs(np.diff(path, axis=0))) <= 0.01 + 1e-9
    d_obj, depth = _worst(hand, obj, q_ref, finger, path, overlapping_pairs)
    assert d_obj >= object_min_m, f"finger reaches {d_obj * 1000:.2f} mm from the object"
    assert depth <= DEFAULT_TOUCH_TOL_M, f"finger penetrates the hand by {depth * 1000:.2f} mm"


def _index_move(hand):
    idx = list(hand.fingers["index"].q_index)
    q_start = np.array(hand.q_open, dtype=float)
    q_goal = q_start.copy()
    q_goal[idx] = [0.0, 1.5, 0.0, 0.0]  # flat -> pointing up (+z)
    return q_start, q_goal, idx


def test_planner_table_and_unknown_name(hand, obstacle):
    """The table holds the usual OMPL planners; an unknown name lists the valid ones."""
    names = available_planners()
    for name in ("rrtconnect", "rrt", "rrtstar", "kpiece", "bitstar"):
        assert name in names
    assert "prm" not in names and "prmstar" not in names  # threaded: not reproducible nor work-bounded
    q_start, q_goal, _ = _index_move(hand)
    with pytest.raises(UnknownNameError) as err:
        plan_finger_move(hand, obstacle, q_start, q_goal, "index", planner="rrtconect")
    assert "rrtconnect" in str(err.value) and "bitstar" in str(err.value)


def test_bad_inputs(hand, obstacle):
    """Unknown fingers, wrong shapes and configurations outside the limits are refused."""
    q_start, q_goal, idx = _index_move(hand)
    with pytest.raises(UnknownNameError):
        plan_finger_move(hand, obstacle, q_start, q_goal, "pinky")
    with pytest.raises(InputError):
        plan_finger_move(hand, obstacle, q_start[:-1], q_goal, "index")
    beyond = q_goal.copy()
    beyond[idx[1]] = 3.0
    with pytest.raises(InputError):
        plan_finger_move(hand, obstacle, q_start, beyond, "index")


def test_free_move_is_the_straight_line(hand):
    """Away from the object the path is the joint-space segment, sampled every 0.01 rad."""
    far = make_object("box", (0.02, 0.02, 0.02), _pose([0.0, 0.0, 0.2]))
    q_start, q_goal, idx = _index_move(hand)
    path = plan_finger_move(hand, far, q_start, q_goal, "index")
    np.testing.assert_array_equal(path[0], q_start[idx])
    np.testing.assert_array_equal(path[-1], q_goal[idx])
    direction = (q_goal[idx] - q_start[idx]) / np.linalg.norm(q_goal[idx] - q_start[idx])
    offsets = path - q_start[idx]
    residual = offsets - np.outer(offsets @ direction, direction)
    assert np.max(np.abs(residual)) < 1e-12
    assert len(path) == int(np.ceil(1.5 / 0.01)) + 1


def test_detour_around_the_object(hand, obstacle, overlapping_pairs):
    """The straight joint line hits the box; the planned path goes around it with clearance."""
    q_start, q_goal, idx = _index_move(hand)
    straight = np.linspace(q_start[idx], q_goal[idx], 151)
    d_straight, _ = _worst(hand, obstacle, q_start, "index", straight, overlapping_pairs)
    assert d_straight < -0.003  # deep in the box

    path = plan_finger_move(hand, obstacle, q_start, q_goal, "index", seed=3)
    np.testing.assert_array_equal(path[0], q_start[idx])
    np.testing.assert_array_equal(path[-1], q_goal[idx])
    # waypoints keep the clearance; between them (finer than the planner checks) no contact
    _assert_path_ok(hand, obstacle, q_start, "index", path, overlapping_pairs, object_min_m=0.0)
    idx_path = _full(q_start, idx, path)
    T_palm_obj = np.asarray(obstacle.T_palm_obj)
    d_waypoints = min(
        _distance(geom, T, obstacle.geometry, T_palm_obj)
        for q in idx_path[:: max(1, len(idx_path) // 40)]
        for _, finger, geom, T in _bodies(hand, q)
        if finger == "index"
    )
    assert d_waypoints >= DEFAULT_CLEARANCE_M - 1e-9


def test_same_seed_same_path(hand, obstacle):
    """Planning twice with one seed gives the identical path."""
    q_start, q_goal, _ = _index_move(hand)
    a = plan_finger_move(hand, obstacle, q_start, q_goal, "index", seed=11)
    b = plan_finger_move(hand, obstacle, q_start, q_goal, "index", seed=11)
    np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("planner", [p for p in available_planners() if p not in ("rrtconnect",)])
def test_every_planner_finds_the_detour(hand, obstacle, planner):
    """Each registered planner solves the detour and ends exactly at the goal. The budget is
    generous: a planner returns at its first solution, and the slowest (lbkpiece, prmstar)
    need tens of thousands of checks here."""
    q_start, q_goal, idx = _index_move(hand)
    path = plan_finger_move(hand, obstacle, q_start, q_goal, "index", planner=planner, max_checks=400_000)
    np.testing.assert_array_equal(path[-1], q_goal[idx])
    assert np.max(np.abs(np.diff(path, axis=0))) <= 0.01 + 1e-9


def test_goal_inside_the_object_raises(hand):
    """A goal that puts the finger inside the object is a MotionError, not a path."""
    q_start, q_goal, idx = _index_move(hand)
    T_palm_link = hand.state(q_goal).link_pose("index_distal")
    block = make_object("box", (0.03, 0.03, 0.03), _pose(T_palm_link[:3, 3]))
    with pytest.raises(MotionError, match="goal"):
        plan_finger_move(hand, block, q_start, q_goal, "index", max_checks=100)


def test_no_path_within_budget_raises(hand, obstacle):
    """When the planner runs out of work the caller gets a MotionError naming the planner
    and the budget."""
    q_start, q_goal, _ = _index_move(hand)
    # the detour needs hundreds of collision checks
    with pytest.raises(MotionError, match="rrtconnect found no collision-free path in 5 collision checks"):
        plan_finger_move(hand, obstacle, q_start, q_goal, "index", max_checks=5)


def test_the_work_bound_not_the_clock_decides(hand, obstacle, monkeypatch):
    """A path is bounded by collision checks, not by time: with every check made 100 times
    slower (a busy machine), the same seed gives the same path, and a budget one check short
    of what the search needs fails the same way fast or slow."""
    import time

    from planner import finger_scene

    q_start, q_goal, _ = _index_move(hand)
    calls = []
    original = finger_scene.FingerScene.is_valid

    def counted(self, q, clearance_m):
        calls.append(1)
        return original(self, q, clearance_m)

    monkeypatch.setattr(finger_scene.FingerScene, "is_valid", counted)
    fast = plan_finger_move(hand, obstacle, q_start, q_goal, "index", seed=5)
    needed = len(calls)

    def slow(self, q, clearance_m):
        time.sleep(2e-4)
        return original(self, q, clearance_m)

    monkeypatch.setattr(finger_scene.FingerScene, "is_valid", slow)
    np.testing.assert_array_equal(plan_finger_move(hand, obstacle, q_start, q_goal, "index", seed=5), fast)
    with pytest.raises(MotionError, match="collision checks"):
        plan_finger_move(hand, obstacle, q_start, q_goal, "index", seed=5, max_checks=max(1, needed // 4))


CONTACTS = {
    "index": ([0.002, -0.025, -0.003], [0.013, -0.025, -0.012]),
    # the second thumb contact wraps the thumb round an edge: the lift pushes every
    # phalanx near the object away, not only the contact point
    "thumb": ([-0.021, 0.01, 0.015], [-0.023, -0.015, 0.015]),
}


@pytest.fixture(scope="module")
def contact_qs(hand, held_box):
    out = {}
    for finger, points in CONTACTS.items():
        qs = []
        for p in points:
            q, patch = realize_contact(hand, held_box, finger, np.array(p), np.asarray(hand.q_open))
            assert patch is not None
            qs.append(q)
        out[finger] = qs
    return out


@pytest.mark.parametrize("finger", sorted(CONTACTS))
def test_gait_step_lift_move_land(hand, held_box, contact_qs, overlapping_pairs, finger):
    """Lift, move and land join up, start at contact A, end exactly at contact B, stay clear."""
    q_a, q_b = contact_qs[finger]
    idx = list(hand.fingers[finger].q_index)
    gait = plan_gait_step(hand, held_box, q_a, q_b, finger)
    lift, move, land = gait["lift"], gait["move"], gait["land"]
    np.testing.assert_array_equal(lift[0], q_a[idx])
    np.testing.assert_array_equal(lift[-1], move[0])
    np.testing.assert_array_equal(move[-1], land[0])
    np.testing.assert_array_equal(land[-1], q_b[idx])
    np.testing.assert_array_equal(gait["q_lifted"][idx], move[0])
    np.testing.assert_array_equal(gait["q_approach"][idx], move[-1])
    for path in (lift, move, land):  # touching is allowed only within the tolerance
        _assert_path_ok(hand, held_box, q_a, finger, path, overlapping_pairs, object_min_m=-DEFAULT_TOUCH_TOL_M)
    # the move keeps the clearance, so the lifted and approach configurations are clear
    for end in (move[:1], move[-1:]):
        d_end, _ = _worst(hand, held_box, q_a, finger, end, overlapping_pairs)
        assert d_end >= DEFAULT_CLEARANCE_M - 1e-9


def test_lift_backs_off_along_the_given_normal(hand, held_box, contact_qs):
    """With an explicit normal the index contact point backs off along it (out of the -y face)."""
    q_a = contact_qs["index"][1]
    idx = list(hand.fingers["index"].q_index)
    n_in_palm = np.array([0.0, 1.0, 0.0])  # pushing into the box's -y face
    lift = plan_gait_step(hand, held_box, q_a, None, "index", n_a_palm=n_in_palm)["lift"]
    q_end = np.array(q_a, float)
    q_end[idx] = lift[-1]
    # the contact point: the finger point nearest to the object, fixed on its link
    T_palm_obj = np.asarray(held_box.T_palm_obj)
    best = None
    for link, finger, geom, T in _bodies(hand, q_a):
        if finger != "index":
            continue
        res = coal.DistanceResult()
        d = coal.distance(geom, _coal_tf(T), held_box.geometry, _coal_tf(T_palm_obj), coal.DistanceRequest(), res)
        if best is None or d < best[0]:
            best = (d, link, np.array(res.getNearestPoint1()))
    _, link, p_palm = best
    T0, T1 = hand.state(q_a).link_pose(link), hand.state(q_end).link_pose(link)
    p_link = T0[:3, :3].T @ (p_palm - T0[:3, 3])
    motion = (T1[:3, :3] @ p_link + T1[:3, 3]) - p_palm
    along = motion @ -n_in_palm
    assert along >= 0.004
    assert np.linalg.norm(motion - along * -n_in_palm) < 0.5 * along


def test_free_ends(hand, held_box, contact_qs, overlapping_pairs):
    """A finger ending free goes to its open posture (no land); one starting free has no lift."""
    q_a, q_b = contact_qs["index"]
    idx = list(hand.fingers["index"].q_index)
    q_open = np.asarray(hand.q_open, float)[idx]
    to_free = plan_gait_step(hand, held_box, q_a, None, "index")
    assert "land" not in to_free
    np.testing.assert_array_equal(to_free["move"][-1], q_open)
    from_free = plan_gait_step(hand, held_box, None, q_b, "index", q_others=q_a)
    assert "lift" not in from_free
    np.testing.assert_array_equal(from_free["move"][0], q_open)
    np.testing.assert_array_equal(from_free["land"][-1], q_b[idx])
    _assert_path_ok(hand, held_box, q_a, "index", from_free["move"], overlapping_pairs, object_min_m=0.0)
    with pytest.raises(InputError):
        plan_gait_step(hand, held_box, None, None, "index")


def test_planning_prints_nothing():
    """A process planning with OMPL prints nothing (no OMPL log, no nanobind leak report) unless verbose."""
    code = textwrap.dedent(
        """
        import numpy as np
        from planner.hand import Hand
        from planner.objects import make_object
        from planner.motion import plan_finger_move
        hand = Hand.load("icub_right")
        T = np.eye(4); T[:3, 3] = [0.065, -0.026, 0.035]
        obj = make_object("box", (0.015, 0.03, 0.015), T)
        q0 = np.array(hand.q_open, float); q1 = q0.copy(); q1[:4] = [0.0, 1.5, 0.0, 0.0]
        path = plan_finger_move(hand, obj, q0, q1, "index", planner="bitstar")
        try:
            plan_finger_move(hand, obj, q0, q1, "index", planner="rrt", max_checks=5)
        except Exception:
            pass
        print("QUIET-END", flush=True)
        plan_finger_move(hand, obj, q0, q1, "index", verbose=True)
        """
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    quiet, _, verbose = done.stdout.partition("QUIET-END\n")
    assert quiet == ""
    assert "RRTConnect" in verbose  # verbose=True lets OMPL's log through
    assert done.stderr == ""


# ------------------------------------------------------------- mesh objects

MESHES = Path(__file__).resolve().parent.parent / "grasps" / "meshes"


@pytest.fixture(scope="module")
def held_box_mesh(held_box):
    """``held_box`` as a triangle mesh: the library's gridded 35 x 80 x 30 mm box mesh
    scaled to 50 x 50 x 30 mm, at the same pose (a coal BVHModel, not a coal Box)."""
    scale = np.array(held_box.size) / np.array([0.035, 0.08, 0.03])
    mesh = make_object("mesh", scale, held_box.T_palm_obj, mesh_path=MESHES / "box_35x80x30.obj")
    assert isinstance(mesh.geometry, coal.BVHModelBase)
    return mesh


def test_mesh_box_collision_queries_agree_with_the_primitive_box(hand, held_box, held_box_mesh, contact_qs):
    """The finger-object queries of the motion planner (signed distances and validity with a
    tolerated penetration, a contact clearance or a move clearance) give the same answers for
    a box mesh as for the primitive box, at seeded configurations around the contacts: some
    clear, some touching, some sunk in by more than the touch tolerance."""
    from planner.finger_scene import FingerScene

    rng = np.random.default_rng(7)
    margins = (-DEFAULT_TOUCH_TOL_M, -0.0003, 0.0, DEFAULT_CLEARANCE_M)
    depths = []
    for finger, qs in sorted(contact_qs.items()):
        idx = list(hand.fingers[finger].q_index)
        lo, hi = np.asarray(hand.lower)[idx], np.asarray(hand.upper)[idx]
        prim = FingerScene(hand, held_box, qs[0], finger, DEFAULT_TOUCH_TOL_M)
        mesh = FingerScene(hand, held_box_mesh, qs[0], finger, DEFAULT_TOUCH_TOL_M)
        for q in qs:
            for _ in range(12):
                qf = np.clip(q[idx] + rng.normal(scale=0.06, size=len(idx)), lo, hi)
                d_prim = [d for d, *_ in prim.object_distances(qf)]
                d_mesh = [d for d, *_ in mesh.object_distances(qf)]
                np.testing.assert_allclose(d_mesh, d_prim, atol=1e-7)
                depths.append(min(d_prim))
                for m in margins:
                    if min(abs(d - m) for d in d_prim) > 1e-6:  # not on the fence
                        assert mesh.is_valid(qf, m) == prim.is_valid(qf, m), (finger, qf, m)
    depths = np.array(depths)
    assert (depths < -DEFAULT_TOUCH_TOL_M).any() and ((depths > -DEFAULT_TOUCH_TOL_M) & (depths < 0)).any()
    assert (depths > DEFAULT_CLEARANCE_M).any()


@pytest.mark.parametrize("finger", sorted(CONTACTS))
def test_gait_step_on_a_mesh_holds_against_the_primitive(hand, held_box, held_box_mesh, contact_qs,
                                                         overlapping_pairs, finger):
    """Lift, move and land planned around the box mesh (the lift used to raise coal's
    "Negative security margin" error for meshes) re-check clear of the primitive box."""
    q_a, q_b = contact_qs[finger]
    idx = list(hand.fingers[finger].q_index)
    gait = plan_gait_step(hand, held_box_mesh, q_a, q_b, finger)
    np.testing.assert_array_equal(gait["lift"][0], q_a[idx])
    np.testing.assert_array_equal(gait["land"][-1], q_b[idx])
    for path in (gait["lift"], gait["move"], gait["land"]):
        _assert_path_ok(hand, held_box, q_a, finger, path, overlapping_pairs, object_min_m=-DEFAULT_TOUCH_TOL_M)
    d_move, _ = _worst(hand, held_box, q_a, finger, gait["move"], overlapping_pairs)
    assert d_move >= DEFAULT_CLEARANCE_M - 1e-6


def test_gait_step_on_a_non_convex_mesh(hand, overlapping_pairs):
    """A non-convex mesh (the library's plus-shaped prism) keeps its own triangles for the
    tolerated-penetration checks: the thumb lifts off one contact and lands on another, and
    the paths re-check clear of both arms of the cross (primitive boxes) within the tolerance."""
    T = _pose([0.045, -0.01, 0.03])
    prism = make_object("mesh", (1.0,), T, mesh_path=MESHES / "cross_prism.obj")
    arms = [make_object("box", size, T) for size in ((0.05, 0.016, 0.02), (0.016, 0.05, 0.02))]
    q_open = np.asarray(hand.q_open)
    q_a, patch_a = realize_contact(hand, prism, "thumb", np.array([-0.021, 0.004, 0.01]), q_open)
    q_b, patch_b = realize_contact(hand, prism, "thumb", np.array([-0.012, -0.008, 0.01]), q_open)
    assert patch_a is not None and patch_b is not None
    idx = list(hand.fingers["thumb"].q_index)
    gait = plan_gait_step(hand, prism, q_a, q_b, "thumb")
    np.testing.assert_array_equal(gait["lift"][0], q_a[idx])
    np.testing.assert_array_equal(gait["land"][-1], q_b[idx])
    for path in (gait["lift"], gait["move"], gait["land"]):
        for arm in arms:
            _assert_path_ok(hand, arm, q_a, "thumb", path, overlapping_pairs, object_min_m=-DEFAULT_TOUCH_TOL_M)
    for arm in arms:
        d_move, _ = _worst(hand, arm, q_a, "thumb", gait["move"], overlapping_pairs)
        assert d_move >= DEFAULT_CLEARANCE_M - 1e-6


@pytest.mark.parametrize("fails_alone", [True, False])
def test_a_move_not_found_even_without_the_other_fingers_is_not_planned_again(monkeypatch, hand, held_box, contact_qs,
                                                                              fails_alone):
    """`plan_gait_step(..., failed_moves=memo)`: the index's move off its contact is not found
    among the other fingers (a stand-in planner). It is planned once more between the same two
    postures with no other finger; not found there either, the same gait with the other fingers
    elsewhere fails at once with that reason, and the planner is not asked; found there, the
    other state's move is planned (the other fingers may have been in the way) and not tried
    alone again. The same postures at another object pose are another move."""
    import planner.motion as motion

    q_a, _ = contact_qs["index"]
    asked = []

    def stand_in(scene, a, b, **kw):
        asked.append((scene.others, a.tobytes(), b.tobytes()))
        if scene.others or fails_alone:
            raise MotionError(f"no path{'' if scene.others else ' alone'}")
        return np.array([a, b])

    monkeypatch.setattr(motion, "_plan_move", stand_in)
    memo: dict = {}
    elsewhere = np.array(q_a, dtype=float)
    thumb = list(hand.fingers["thumb"].q_index)
    elsewhere[thumb] = np.asarray(hand.q_open, dtype=float)[thumb]  # another state: the thumb lifted
    for q_others in (q_a, elsewhere):
        with pytest.raises(MotionError) as err:
            plan_gait_step(hand, held_box, q_a, None, "index", q_others=q_others, failed_moves=memo)
        if fails_alone:
            assert str(err.value) == "no path alone (not found with no other finger in the way either: not tried " \
                                     "again between these postures)"
        else:
            assert str(err.value) == "no path"
    assert [others for others, _, _ in asked] == ([True, False] if fails_alone else [True, False, True])
    assert len({(a, b) for _, a, b in asked}) == 1  # the same two postures every time
    # another object pose: not the remembered move
    moved = make_object("box", (0.05, 0.05, 0.03), _pose([0.045, -0.01, 0.0305]))
    with pytest.raises(MotionError):
        plan_gait_step(hand, moved, q_a, None, "index", failed_moves=memo)
    assert [others for others, _, _ in asked[-2:]] == [True, False] and len(asked) == (4 if fails_alone else 5)
