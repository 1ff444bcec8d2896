"""Force closure, the signed Ferrari-Canny metric and removable fingers (planner/closure.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import nnls
from scipy.spatial import ConvexHull, QhullError
from scipy.spatial.transform import Rotation

from planner.closure import (
    Closure,
    Friction,
    apply_contact_model,
    batch_grasp_closure,
    closure_from_wrenches,
    contact_wrenches,
    grasp_closure,
    removable_fingers,
)
from planner.errors import InputError

SOFT = Friction(mu=0.5, gamma=0.01, edges=5)


# --------------------------------------------------------------------------- helpers


def hull_baseline(W: np.ndarray) -> tuple[bool, float]:
    """Reference answer: qhull facets for force closure, NNLS for the outside distance."""
    try:
        offsets = ConvexHull(W).equations[:, -1]  # unit normals: distance = -offset
        if offsets.max() < -1e-12:
            return True, float(-offsets.max())
    except QhullError:
        pass  # rank-deficient: never force closure
    big = 1e4  # heavy row enforcing sum(lambda) = 1
    A = np.vstack([W.T, big * np.ones(len(W))])
    lam, _ = nnls(A, np.r_[np.zeros(6), big], maxiter=20 * len(W))
    return False, -float(np.linalg.norm(W.T @ lam))


def random_grasp(rng, n_fingers, n_points, radius=0.03, spread=0.004, tilt=0.1):
    """Fingers on a sphere-like object: patches of noisy points with roughly inward normals."""
    patches = {}
    for i in range(n_fingers):
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        points = radius * d + spread * rng.normal(size=(n_points, 3))
        normals = -d + tilt * rng.normal(size=(n_points, 3))
        patches[f"f{i}"] = (points, normals)
    return patches


def box_face_grasp(rng, n_fingers, n_points, half=0.02):
    """Fingers on faces of a box: coplanar patches with identical normals (degenerate hulls)."""
    patches = {}
    faces = rng.choice(6, size=n_fingers, replace=False)
    for i, face in enumerate(faces):
        axis, sign = divmod(int(face), 2)
        sign = 1.0 if sign else -1.0
        points = rng.uniform(-half, half, size=(n_points, 3))
        points[:, axis] = sign * half
        normals = np.zeros((n_points, 3))
        normals[:, axis] = -sign
        patches[f"f{i}"] = (points, normals)
    return patches


def stack(patches, friction):
    return np.vstack([contact_wrenches(p, n, friction) for p, n in patches.values()])


def six_sphere_contacts(radius=0.05):
    axes = np.vstack([np.eye(3), -np.eye(3)])
    return {f"c{i}": (radius * a[None, :], -a[None, :]) for i, a in enumerate(axes)}


def assert_same(c: Closure, reference: tuple[bool, float]):
    fc, metric = reference
    assert c.is_force_closure == fc
    assert c.metric == pytest.approx(metric, rel=1e-6, abs=1e-9)  # NNLS penalty: ~1e-12 abs


# --------------------------------------------------------------------------- friction and wrenches


@pytest.mark.parametrize(
    "kwargs",
    [dict(mu=-0.1, gamma=0.0), dict(mu=0.5, gamma=-1e-3), dict(mu=math.nan, gamma=0.0),
     dict(mu=0.5, gamma=math.inf), dict(mu=0.5, gamma=0.0, edges=2), dict(mu=0.5, gamma=0.0, edges=4.5)],
)
def test_friction_rejects_bad_values(kwargs):
    """Negative or non-finite coefficients and fewer than 3 (or fractional) edges raise InputError."""
    with pytest.raises(InputError):
        Friction(**kwargs)


def test_contact_wrenches_follow_the_soft_finger_cone():
    """Each point gives 2*edges rows with unit normal force, rim at mu, and torque p x f +/- gamma n."""
    rng = np.random.default_rng(0)
    p = rng.normal(size=(4, 3)) * 0.03
    n = rng.normal(size=(4, 3)) * 3.0  # not unit: must be normalized
    fr = Friction(0.4, 0.02, edges=6)
    W = contact_wrenches(p, n, fr)
    assert W.shape == (2 * 6 * 4, 6)
    un = n / np.linalg.norm(n, axis=1)[:, None]
    rows = W.reshape(4, 6, 2, 6)
    f = rows[..., :3]
    normal_part = np.einsum("iksj,ij->iks", f, un)
    np.testing.assert_allclose(normal_part, 1.0, atol=1e-12)
    tangential = f - normal_part[..., None] * un[:, None, None, :]
    np.testing.assert_allclose(np.linalg.norm(tangential, axis=-1), 0.4, atol=1e-12)
    torsion = np.array([1.0, -1.0])[None, None, :, None] * 0.02 * un[:, None, None, :]
    expected_tau = np.cross(p[:, None, None, :], f) + torsion
    np.testing.assert_allclose(rows[..., 3:], expected_tau, atol=1e-15)
    np.testing.assert_array_equal(W, contact_wrenches(p, n, fr))  # deterministic basis


@pytest.mark.parametrize(
    "points, normals, what",
    [
        (np.zeros((2, 3)), np.array([[0, 0, 1.0], [0, 0, 0]]), "zero length"),
        (np.zeros((2, 3)), np.zeros((3, 3)) + 1, "shape"),
        (np.zeros((2, 2)), np.ones((2, 2)), "shape"),
        (np.array([[np.nan, 0, 0]]), np.array([[0, 0, 1.0]]), "finite"),
        (np.array([[0, 0, 0.0]]), np.array([[0, np.inf, 1.0]]), "finite"),
    ],
)
def test_contact_wrenches_reject_bad_input(points, normals, what):
    """Zero-length normals, mismatched shapes and NaN/inf raise InputError saying what was wrong."""
    with pytest.raises(InputError, match=what):
        contact_wrenches(points, normals, SOFT)


@pytest.mark.parametrize(
    "W, what",
    [(np.ones((10, 5)), "shape"), (np.ones(6), "shape"), (np.full((8, 6), np.nan), "finite"),
     (np.array([[np.inf] + [0.0] * 5] * 8), "finite")],
)
def test_closure_from_wrenches_rejects_bad_input(W, what):
    """Wrench arrays that are not (k, 6) or hold NaN/inf raise InputError."""
    with pytest.raises(InputError, match=what):
        closure_from_wrenches(W)


def test_grasp_closure_rejects_bad_patches():
    """A patch that is not a (points, normals) pair, or a wrong friction object, raises InputError."""
    with pytest.raises(InputError, match="pair"):
        grasp_closure({"index": np.zeros((3, 3))}, SOFT)
    with pytest.raises(InputError, match="zero length"):
        grasp_closure({"index": (np.zeros((1, 3)), np.zeros((1, 3)))}, SOFT)
    with pytest.raises(InputError, match="Friction"):
        grasp_closure(six_sphere_contacts(), 0.5)


# --------------------------------------------------------------------------- analytic grasps


def test_cross_polytope_epsilon_is_one_over_sqrt6():
    """The wrenches +/- e_i form a cross-polytope whose facets are at distance 1/sqrt(6)."""
    W = np.vstack([np.eye(6), -np.eye(6)])
    c = closure_from_wrenches(W)
    assert c.is_force_closure and c.rank == 6
    assert c.metric == pytest.approx(1 / math.sqrt(6), rel=1e-12)


def test_hypercube_epsilon_is_half_width():
    """The 64 vertices of [-2, 2]^6 give epsilon 2, the distance to a face of the cube."""
    W = 2.0 * np.array(np.meshgrid(*[[-1.0, 1.0]] * 6)).reshape(6, -1).T
    assert closure_from_wrenches(W).metric == pytest.approx(2.0, rel=1e-12)


@pytest.mark.parametrize("delta", [0.3, 1e-4, 1e-7])
def test_shifted_cross_polytope_near_the_boundary(delta):
    """Shifting the cross-polytope by t e_1 gives epsilon (1-t)/sqrt(6) inside and -(t-1) outside."""
    base = np.vstack([np.eye(6), -np.eye(6)])
    shift = np.eye(6)[0]
    inside = closure_from_wrenches(base + (1 - delta) * shift)
    assert inside.is_force_closure
    assert inside.metric == pytest.approx(delta / math.sqrt(6), rel=1e-6)
    outside = closure_from_wrenches(base + (1 + delta) * shift)
    assert not outside.is_force_closure
    assert outside.metric == pytest.approx(-delta, rel=1e-6)


def test_origin_on_the_boundary_gives_exactly_zero():
    """A wrench set with the origin as a vertex (or on a facet) is not force closure, metric 0."""
    base = np.vstack([np.eye(6), -np.eye(6)])
    on_vertex = closure_from_wrenches(base + np.eye(6)[0])
    assert (on_vertex.is_force_closure, on_vertex.metric) == (False, 0.0)
    on_facet = closure_from_wrenches(base + np.ones(6) / 6.0)  # facet sum(x) = 1 passes through 0
    assert (on_facet.is_force_closure, on_facet.metric) == (False, 0.0)


def test_rank_deficient_sets_are_never_force_closure():
    """+/- e_i for five axes contain the origin but span 5-D: not force closure, metric 0, rank 5."""
    W = np.vstack([np.eye(6)[:5], -np.eye(6)[:5]])
    c = closure_from_wrenches(W)
    assert (c.is_force_closure, c.metric, c.rank) == (False, 0.0, 5)
    far = closure_from_wrenches(np.array([[2.0, 1, 0, 0, 0, 0], [2.0, -1, 0, 0, 0, 0]]))
    assert not far.is_force_closure and far.metric == pytest.approx(-2.0, rel=1e-12)
    assert closure_from_wrenches(np.zeros((0, 6))) == Closure(False, 0.0, 0)


def test_sphere_six_contacts_with_friction_is_force_closure():
    """Soft contacts at +/-x, +/-y, +/-z of a sphere are force closure; frictionless ones are not."""
    patches = six_sphere_contacts()
    assert grasp_closure(patches, SOFT).is_force_closure
    frictionless = grasp_closure(patches, Friction(0.0, 0.0))
    assert not frictionless.is_force_closure  # normals through the centre: no torque at all
    assert frictionless.rank == 3 and frictionless.metric == 0.0


@pytest.mark.parametrize(
    "mu, gamma, expected", [(0.5, 0.01, True), (0.5, 0.0, False), (0.0, 0.01, False), (0.0, 0.0, False)]
)
def test_antipodal_pair_needs_friction_and_torsion(mu, gamma, expected):
    """Two opposite soft contacts are force closure only with mu > 0 and gamma > 0."""
    patches = {"thumb": ([[0.04, 0, 0]], [[-1.0, 0, 0]]), "index": ([[-0.04, 0, 0]], [[1.0, 0, 0]])}
    c = grasp_closure(patches, Friction(mu, gamma))
    assert c.is_force_closure is expected
    if not expected:
        assert c.metric == 0.0  # the origin is in the (flat) hull: squeezing balances itself
    assert_same(c, hull_baseline(stack(patches, Friction(mu, gamma))))


def test_frictionless_box_with_four_contacts_per_face_is_force_closure():
    """Frictionless point contacts at the corners of a square on every box face immobilize it."""
    patches = {}
    half, off = 0.02, 0.01
    corners = np.array([[1, 1], [1, -1], [-1, 1], [-1, -1]]) * off
    for axis in range(3):
        others = [a for a in range(3) if a != axis]
        for sign in (1.0, -1.0):
            points = np.zeros((4, 3))
            points[:, axis] = sign * half
            points[:, others] = corners
            normals = np.zeros((4, 3))
            normals[:, axis] = -sign
            patches[f"{'xyz'[axis]}{'+' if sign > 0 else '-'}"] = (points, normals)
    frictionless = Friction(0.0, 0.0, edges=3)
    c = grasp_closure(patches, frictionless)
    assert c.is_force_closure
    assert_same(c, hull_baseline(stack(patches, frictionless)))
    one_face = grasp_closure({"x+": patches["x+"]}, frictionless)
    assert not one_face.is_force_closure


def test_contacts_on_one_face_are_never_force_closure_and_sit_at_distance_one():
    """A patch symmetric about a face centre has the normal force at distance exactly 1 from the hull."""
    rng = np.random.default_rng(3)
    xy = rng.uniform(-0.02, 0.02, size=(6, 2))
    xy = np.vstack([xy, -xy])  # symmetric about the face centre
    points = np.column_stack([xy, np.full(len(xy), 0.03)])
    normals = np.tile([0.0, 0.0, -1.0], (len(xy), 1))
    for fr in (SOFT, Friction(1.0, 0.05, edges=8), Friction(0.0, 0.0)):
        c = grasp_closure({"a": (points[:6], normals[:6]), "b": (points[6:], normals[6:])}, fr)
        assert not c.is_force_closure
        assert c.metric == pytest.approx(-1.0, rel=1e-9)


# --------------------------------------------------------------------------- baseline agreement


def test_agrees_with_qhull_on_random_grasps():
    """Booleans and signed metrics match qhull (and an NNLS distance) on 250 seeded random grasps."""
    rng = np.random.default_rng(2024)
    n_fc = 0
    for trial in range(250):
        fr = Friction(rng.uniform(0.0, 1.0), rng.uniform(0.0, 0.01), int(rng.integers(3, 7)))
        maker = box_face_grasp if trial % 5 == 4 else random_grasp
        patches = maker(rng, int(rng.integers(2, 6)), int(rng.integers(1, 5)))
        W = stack(patches, fr)
        reference = hull_baseline(W)
        n_fc += reference[0]
        c = closure_from_wrenches(W)
        assert c.is_force_closure == reference[0], trial
        assert c.metric == pytest.approx(reference[1], rel=1e-6, abs=1e-12), trial
    assert 50 < n_fc < 230  # both outcomes are exercised


def test_agrees_with_qhull_on_random_point_clouds():
    """Random 6-D point clouds around and beside the origin match qhull and the NNLS distance."""
    rng = np.random.default_rng(7)
    for trial in range(120):
        k = int(rng.integers(7, 60))
        W = rng.normal(size=(k, 6)) * rng.uniform(0.1, 2.0, size=6) + rng.normal(size=6) * 0.6
        assert_same(closure_from_wrenches(W), hull_baseline(W))


# --------------------------------------------------------------------------- invariances


def test_rotating_all_wrenches_keeps_answer_and_metric():
    """Rotating forces and torques by the same rotation (a frame change) keeps closure and metric."""
    rng = np.random.default_rng(11)
    for _ in range(15):
        W = stack(random_grasp(rng, int(rng.integers(2, 5)), 3), SOFT)
        R = Rotation.random(random_state=rng).as_matrix()
        big = np.zeros((6, 6))
        big[:3, :3] = big[3:, 3:] = R
        a, b = closure_from_wrenches(W), closure_from_wrenches(W @ big.T)
        assert a.is_force_closure == b.is_force_closure
        assert b.metric == pytest.approx(a.metric, rel=1e-7, abs=1e-12)


def test_rotating_contacts_keeps_answer_for_a_robust_grasp():
    """Rotating every contact about the origin keeps force closure and the metric within cone sampling."""
    rng = np.random.default_rng(12)
    patches = six_sphere_contacts()
    fine = Friction(0.5, 0.01, edges=64)  # fine cone: the cone's phase barely matters
    ref = grasp_closure(patches, fine)
    for _ in range(5):
        R = Rotation.random(random_state=rng).as_matrix()
        rotated = {f: (p @ R.T, n @ R.T) for f, (p, n) in patches.items()}
        c = grasp_closure(rotated, fine)
        assert c.is_force_closure
        assert c.metric == pytest.approx(ref.metric, rel=0.02)


def test_scaling_the_wrenches_scales_the_metric():
    """Multiplying every wrench by s > 0 keeps the answer and multiplies the metric by s."""
    rng = np.random.default_rng(19)
    for _ in range(10):
        W = stack(random_grasp(rng, int(rng.integers(2, 5)), 3), SOFT)
        base = closure_from_wrenches(W)
        for s in (1e-4, 1e3):
            scaled = closure_from_wrenches(s * W)
            assert scaled.is_force_closure == base.is_force_closure
            assert scaled.metric == pytest.approx(s * base.metric, rel=1e-8, abs=1e-13 * s)


def test_permuting_fingers_and_rows_keeps_result():
    """Reordering fingers (and wrench rows) gives the identical answer and metric."""
    rng = np.random.default_rng(13)
    for _ in range(10):
        patches = random_grasp(rng, 4, 3)
        reordered = dict(reversed(list(patches.items())))
        a, b = grasp_closure(patches, SOFT), grasp_closure(reordered, SOFT)
        assert a.is_force_closure == b.is_force_closure
        assert b.metric == pytest.approx(a.metric, rel=1e-9, abs=1e-14)
        W = stack(patches, SOFT)
        c = closure_from_wrenches(W[rng.permutation(len(W))])
        assert c.metric == pytest.approx(a.metric, rel=1e-9, abs=1e-14)


def test_adding_a_contact_never_breaks_closure_nor_lowers_the_metric():
    """Adding contacts can only grow the hull: closure is kept and the signed metric never drops."""
    rng = np.random.default_rng(14)
    for _ in range(30):
        patches = random_grasp(rng, int(rng.integers(2, 5)), 2)
        before = grasp_closure(patches, SOFT)
        extra = random_grasp(rng, 1, int(rng.integers(1, 3)))["f0"]
        after = grasp_closure({**patches, "extra": extra}, SOFT)
        assert after.metric >= before.metric - 1e-12
        if before.is_force_closure:
            assert after.is_force_closure


def test_removing_a_finger_never_creates_closure():
    """Dropping a finger can only shrink the hull: no closure appears and the metric never rises."""
    rng = np.random.default_rng(15)
    for _ in range(20):
        patches = random_grasp(rng, 4, 2)
        full = grasp_closure(patches, SOFT)
        for finger in patches:
            rest = grasp_closure({f: v for f, v in patches.items() if f != finger}, SOFT)
            assert rest.metric <= full.metric + 1e-12
            assert not (rest.is_force_closure and not full.is_force_closure)


def test_empty_patch_contributes_nothing():
    """A finger with zero points leaves the answer unchanged."""
    patches = six_sphere_contacts()
    a = grasp_closure(patches, SOFT)
    b = grasp_closure({**patches, "idle": (np.zeros((0, 3)), np.zeros((0, 3)))}, SOFT)
    assert a == b


# --------------------------------------------------------------------------- Algorithm 1 and batches


def test_removable_fingers_matches_the_definition():
    """A finger is removable exactly when the other fingers alone are force closure."""
    rng = np.random.default_rng(16)
    seen_some = 0
    for _ in range(25):
        patches = random_grasp(rng, int(rng.integers(3, 6)), 2)
        removable = removable_fingers(patches, SOFT)
        if not grasp_closure(patches, SOFT).is_force_closure:
            assert removable == frozenset()
            continue
        expected = {
            f for f in patches if grasp_closure({g: v for g, v in patches.items() if g != f}, SOFT).is_force_closure
        }
        assert removable == expected
        seen_some += bool(expected)
    assert seen_some > 0


def test_removable_fingers_antipodal_pair_plus_helper():
    """With a soft antipodal pair doing the holding, only the helper finger and idle fingers can go."""
    patches = {
        "thumb": ([[0.04, 0, 0]], [[-1.0, 0, 0]]),
        "index": ([[-0.04, 0, 0]], [[1.0, 0, 0]]),
        "middle": ([[0, 0.04, 0]], [[0, -1.0, 0]]),
        "ring": (np.zeros((0, 3)), np.zeros((0, 3))),
    }
    assert removable_fingers(patches, SOFT) == frozenset({"middle", "ring"})
    assert removable_fingers({"thumb": patches["thumb"], "ring": patches["ring"]}, SOFT) == frozenset()


def test_batch_matches_single_calls_and_shares_patches():
    """batch_grasp_closure returns, in order, what grasp_closure gives for each grasp (subsets warm-start)."""
    rng = np.random.default_rng(17)
    pool = random_grasp(rng, 6, 3)
    names = list(pool)
    grasps = []
    for _ in range(30):
        chosen = rng.choice(names, size=int(rng.integers(2, 6)), replace=False)
        grasps.append({str(f): pool[str(f)] for f in chosen})
    grasps.append(dict(grasps[0]))  # a repeated grasp
    grasps.append({})  # no contact at all
    results = batch_grasp_closure(grasps, SOFT)
    assert len(results) == len(grasps)
    for g, r in zip(grasps, results):
        single = grasp_closure(g, SOFT)
        assert (r.is_force_closure, r.rank) == (single.is_force_closure, single.rank)
        assert r.metric == pytest.approx(single.metric, rel=1e-9, abs=1e-14)  # warm starts reorder sums
    assert results[-1] == Closure(False, 0.0, 0)
    assert results[0] == results[-2]


def test_qhull_fallback_gives_the_same_answer(monkeypatch):
    """If the fast expansion reports a degenerate update, the exact qhull fallback answers the same."""
    import planner.hull as closure_module

    rng = np.random.default_rng(18)
    cases = [stack(random_grasp(rng, int(rng.integers(2, 5)), 3), SOFT) for _ in range(8)]
    fast = [closure_from_wrenches(W) for W in cases]

    def degenerate(*args, **kwargs):
        raise closure_module._Degenerate

    monkeypatch.setattr(closure_module, "_expand", degenerate)
    for W, expected in zip(cases, fast):
        slow = closure_from_wrenches(W)
        assert slow.is_force_closure == expected.is_force_closure
        assert slow.metric == pytest.approx(expected.metric, rel=1e-9, abs=1e-12)


def test_symmetric_fine_cone_grasp_needs_no_fallback(monkeypatch):
    """A highly symmetric grasp (64-edge cones, many coplanar wrenches) stays on the fast exact path."""
    import planner.hull as closure_module

    def no_fallback(*args, **kwargs):
        raise AssertionError("qhull fallback used")

    monkeypatch.setattr(closure_module, "_qhull_fallback", no_fallback)
    fine = Friction(0.5, 0.01, edges=64)
    c = grasp_closure(six_sphere_contacts(), fine)
    assert c.is_force_closure and c.metric > 0


def test_outside_distance_on_a_shared_face_converges_in_few_steps(monkeypatch):
    """The library box grasp with 3-edge cones and the thumb lifted: many wrenches of the
    three fingers lie on the hull face nearest the origin. The distance matches the NNLS
    baseline and Wolfe's algorithm stops after a handful of corral solves (it used to
    cycle, adding and dropping equally distant rows, for ~25 000 solves)."""
    import planner.hull as closure_module
    from planner.grasp import load_grasp
    from planner.realization import realize
    from pathlib import Path

    g = realize(load_grasp(Path(__file__).resolve().parents[1] / "grasps/icub/box_parallel_extension.yaml"))
    fr = Friction(g.friction.mu, g.friction.gamma, edges=3)
    W = stack({f: pe for f, pe in g.patches.items() if f != "thumb"}, fr)
    solves = {"n": 0}
    lstsq = np.linalg.lstsq

    def counting(*args, **kwargs):
        solves["n"] += 1
        return lstsq(*args, **kwargs)

    monkeypatch.setattr(closure_module.np.linalg, "lstsq", counting)
    c = closure_from_wrenches(W)
    monkeypatch.undo()
    assert_same(c, hull_baseline(W))
    assert c.metric < -0.01
    assert solves["n"] < 200


def test_removable_with_a_single_touching_finger():
    """A lone finger whose patch alone is force closure is not removable; empty patches are."""
    d = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=float)
    fr = Friction(mu=0.5, gamma=0.004)
    patches = {"wrap": (0.03 * d, -d), "idle": (np.zeros((0, 3)), np.zeros((0, 3)))}
    assert grasp_closure(patches, fr).is_force_closure
    assert removable_fingers(patches, fr) == frozenset({"idle"})


# --------------------------------------------------------------------------- contact models


def test_mean_contact_model_is_one_point_per_finger_with_unit_mean_normal():
    """"mean": the patch's mean point and its normalized mean normal; "patch": unchanged."""
    rng = np.random.default_rng(7)
    pts = rng.normal(size=(9, 3)) * 0.003 + [0.01, 0.0, 0.02]
    nrm = np.array([0.0, 0.0, -1.0]) + rng.normal(size=(9, 3)) * 0.1
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    mean = apply_contact_model({"index": (pts, nrm)}, "mean")["index"]
    assert mean[0].shape == (1, 3) and mean[1].shape == (1, 3)
    assert np.allclose(mean[0][0], pts.mean(axis=0))
    assert np.allclose(mean[1][0], nrm.mean(axis=0) / np.linalg.norm(nrm.mean(axis=0)))
    same = apply_contact_model({"index": (pts, nrm)}, "patch")["index"]
    assert np.array_equal(same[0], pts) and np.array_equal(same[1], nrm)


def test_mean_contact_model_loses_the_moment_of_a_wide_patch():
    """Two opposed flat patches (pinching a block) resist a torque about the pinch axis by
    their extent even without torsional friction; their mean points cannot (thesis fig. 13)."""
    square = np.array([[x, y] for x in (-0.01, 0.01) for y in (-0.01, 0.01)], float)
    top = np.c_[square, np.full(4, 0.02)]
    patches = {"a": (top, np.tile([0.0, 0.0, -1.0], (4, 1))),
               "b": (top * [1, 1, -1], np.tile([0.0, 0.0, 1.0], (4, 1)))}
    hard = Friction(mu=0.5, gamma=0.0, edges=8)
    assert grasp_closure(patches, hard).is_force_closure
    mean = grasp_closure(apply_contact_model(patches, "mean"), hard)
    assert not mean.is_force_closure and mean.rank < 6


def test_contact_model_bad_name_and_cancelling_normals_are_refused():
    from planner.errors import UnknownNameError

    p = np.zeros((2, 3))
    with pytest.raises(UnknownNameError, match="mean, patch"):
        apply_contact_model({"index": (p, np.array([[0, 0, 1.0]] * 2))}, "average")
    with pytest.raises(InputError, match="cancel"):
        apply_contact_model({"index": (p, np.array([[0, 0, 1.0], [0, 0, -1.0]]))}, "mean")


# --------------------------------------------------------------------------- grip force against a load


def _antipodal(r=0.02):
    return {"a": (np.array([[r, 0.0, 0.0]]), np.array([[-1.0, 0.0, 0.0]])),
            "b": (np.array([[-r, 0.0, 0.0]]), np.array([[1.0, 0.0, 0.0]]))}


def test_grip_force_antipodal_pair_holds_a_weight_with_friction():
    """Two antipodal fingers carry a weight W across their axis by friction: each needs
    W / (2 mu) of normal force (up to the inscribed polygon: at most W / (2 mu cos(pi/e)))."""
    from planner.closure import min_grip_force

    for mu, weight in ((0.5, 1.0), (0.9, 0.3)):
        t = min_grip_force(_antipodal(), Friction(mu, 0.01, edges=5), [0, 0, -weight, 0, 0, 0], cone_sides=64)
        assert weight / (2 * mu) - 1e-9 <= t <= weight / (2 * mu * math.cos(math.pi / 64)) + 1e-9


def test_grip_force_for_a_moment_about_the_contact_axis_is_torsion_only():
    """A moment M about the line through both contacts is resisted only by torsional
    friction: t = M / (2 gamma) exactly; without torsion no forces exist (inf)."""
    from planner.closure import min_grip_force

    assert min_grip_force(_antipodal(), Friction(0.5, 0.01), [0, 0, 0, 0.01, 0, 0]) == pytest.approx(0.5, rel=1e-9)
    assert min_grip_force(_antipodal(), Friction(0.5, 0.0), [0, 0, 0, 0.01, 0, 0]) == math.inf


def test_grip_force_scales_with_the_load_and_never_grows_with_an_added_finger():
    from planner.closure import min_grip_force

    rng = np.random.default_rng(11)
    checked = 0
    for _ in range(30):
        patches = random_grasp(rng, 4, 3)
        load = np.r_[rng.normal(size=3), 0.02 * rng.normal(size=3)]
        t = min_grip_force(patches, SOFT, load)
        if not math.isfinite(t):
            continue
        checked += 1
        assert min_grip_force(patches, SOFT, 3.0 * load) == pytest.approx(3.0 * t, rel=1e-6)
        more = dict(patches, extra=random_grasp(rng, 1, 3)["f0"])
        assert min_grip_force(more, SOFT, load) <= t * (1 + 1e-7) + 1e-12
        assert min_grip_force(patches, SOFT, np.zeros(6)) == 0.0
    assert checked >= 10


def test_grip_force_agrees_with_an_independent_check_of_its_forces():
    """Re-check the LP's answer independently: with every finger limited to t the load is
    balanced (feasible), with every finger limited to 0.99 t it is not (scipy linprog on
    the explicit wrench rows)."""
    from scipy.optimize import linprog

    from planner.closure import GRIP_CONE_SIDES, min_grip_force

    rng = np.random.default_rng(5)
    patches = random_grasp(rng, 4, 4)
    load = np.array([0.0, 0.0, -0.5, 0.0, 0.0, 0.0])
    t = min_grip_force(patches, SOFT, load)
    assert 0 < t < math.inf

    def feasible(limit):  # the grip LP's own 16-sided cone polygon, whatever SOFT.edges is
        fine = Friction(SOFT.mu, SOFT.gamma, GRIP_CONE_SIDES)
        blocks = [contact_wrenches(p, n, fine) for p, n in patches.values()]
        W = np.vstack(blocks)
        A_ub = np.zeros((len(blocks), len(W)))
        start = 0
        for i, b in enumerate(blocks):
            A_ub[i, start:start + len(b)] = 1.0
            start += len(b)
        res = linprog(np.zeros(len(W)), A_ub=A_ub, b_ub=np.full(len(blocks), limit), A_eq=W.T, b_eq=-load,
                      bounds=[(0, None)] * len(W), method="highs")
        return res.status == 0

    assert feasible(t * 1.0001) and not feasible(t * 0.99)


def test_grip_force_rejects_a_bad_load():
    from planner.closure import min_grip_force

    for bad in ([1, 2, 3], [0, 0, math.nan, 0, 0, 0], "down"):
        with pytest.raises(InputError, match="load"):
            min_grip_force(_antipodal(), SOFT, bad)


def _tangent_load(phi, weight):
    """A weight W in the common tangent plane (y-z) of the antipodal pair, at angle phi."""
    return [0.0, weight * math.cos(phi), weight * math.sin(phi), 0.0, 0.0, 0.0]


def test_grip_force_converges_to_the_analytic_value_as_the_cone_polygon_refines():
    """Two opposed soft fingers holding a weight W along their common tangent need exactly
    f_n = W / (2 mu) each (circular cone). The grip LP's inscribed N-gon answer lies in
    [W / (2 mu), W / (2 mu cos(pi / N))] for every load direction in the tangent plane, so
    its error is bounded by a quantity that vanishes as N grows; the default 16 sides stay
    within cos(pi/16) (2 %)."""
    from planner.closure import GRIP_CONE_SIDES, min_grip_force

    mu, weight = 0.6, 0.4
    exact = weight / (2 * mu)
    worst = {}
    for sides in (3, 5, 7, 8, 16, 33, 64, 256):
        errors = []
        for phi in np.linspace(0.0, 2 * math.pi, 13)[:-1] + 0.1:
            t = min_grip_force(_antipodal(), Friction(mu, 0.002, edges=5), _tangent_load(phi, weight), cone_sides=sides)
            assert exact * (1 - 1e-9) <= t <= exact / math.cos(math.pi / sides) * (1 + 1e-9), (sides, phi, t)
            errors.append(t / exact - 1)
        worst[sides] = max(errors)
    assert worst[256] < 1e-4 < worst[3]  # converges, and the coarse polygon really is off
    assert worst[256] <= worst[64] <= worst[16] <= worst[5]
    t16 = min_grip_force(_antipodal(), Friction(mu, 0.002), _tangent_load(0.3, weight))
    assert GRIP_CONE_SIDES == 16 and exact <= t16 * (1 + 1e-12) <= exact / math.cos(math.pi / 16) * (1 + 1e-9)


#: A thin-rod tripod: three point contacts on a 6 mm rod (axis z) and a 10 g weight in an
#: oblique direction; with the closure's own 5-edge polygon the grip LP needed 1.26 N (and
#: the closure metric drops to 9e-5), with 4, 6, 8 or 64 edges 0.11-0.14 N (issue 13).
_ROD_ANGLES_DEG = (104.84, 213.72, 304.12)
_ROD_Z_M = (-0.00691, 0.01343, 0.01051)
_ROD_GRAVITY = np.array([-0.4137, 0.9030, 0.1161])


def _rod_tripod(radius=0.003):
    patches = {}
    for i, (a, z) in enumerate(zip(np.radians(_ROD_ANGLES_DEG), _ROD_Z_M)):
        d = np.array([math.cos(a), math.sin(a), 0.0])
        patches[f"f{i}"] = (np.array([radius * d + [0, 0, z]]), -d[None, :])
    load = np.r_[0.01 * 9.81 * _ROD_GRAVITY / np.linalg.norm(_ROD_GRAVITY), np.zeros(3)]
    return patches, load


def _grip_explicit_cone(patches, mu, gamma, load, sides):
    """Independent grip LP: per contact, forces sum_k a_k (n + mu d_k) on an inscribed N-gon
    of its own (random rotation of the tangent frame) and a torsion s n with |s| <= gamma
    sum_k a_k; per finger sum_k a_k <= t; minimize t (scipy HiGHS)."""
    from scipy.optimize import linprog

    rng = np.random.default_rng(0)
    cols, torsion, finger_of = [], [], []
    for fi, (pts, nrm) in enumerate(patches.values()):
        for p, n in zip(np.atleast_2d(pts), np.atleast_2d(nrm)):
            n = n / np.linalg.norm(n)
            t1 = np.cross(n, rng.normal(size=3))
            t1 /= np.linalg.norm(t1)
            t2 = np.cross(n, t1)
            phase = rng.uniform(0, 2 * math.pi)
            for k in range(sides):
                th = phase + 2 * math.pi * k / sides
                f = n + mu * (math.cos(th) * t1 + math.sin(th) * t2)
                cols.append(np.r_[f, np.cross(p, f)])
                finger_of.append(fi)
            torsion.append((len(cols) - sides, len(cols), np.r_[np.zeros(3), n]))
    nf, na, ns = len(patches), len(cols), len(torsion)
    nv = na + ns + 1  # a, s, t
    A_eq = np.zeros((6, nv))
    A_eq[:, :na] = np.array(cols).T
    for j, (_, _, col) in enumerate(torsion):
        A_eq[:, na + j] = col
    A_ub = []
    for fi in range(nf):
        row = np.zeros(nv)
        row[:na] = [1.0 if f == fi else 0.0 for f in finger_of]
        row[-1] = -1.0
        A_ub.append(row)
    for j, (a, b, _) in enumerate(torsion):
        for sign in (1.0, -1.0):
            row = np.zeros(nv)
            row[a:b] = -gamma
            row[na + j] = sign
            A_ub.append(row)
    c = np.zeros(nv)
    c[-1] = 1.0
    bounds = [(0, None)] * na + [(None, None)] * ns + [(0, None)]
    res = linprog(c, A_ub=np.array(A_ub), b_ub=np.zeros(len(A_ub)), A_eq=A_eq, b_eq=-np.asarray(load, float),
                  bounds=bounds, method="highs")
    assert res.status == 0
    return float(res.x[-1])


def test_grip_force_does_not_depend_on_the_closure_cone_edges():
    """The thin-rod tripod of issue 13: with friction edges 4, 5, 6 or 8 the grip LP gives the
    same answer (its own 16-gon), within the cone bound of an independent fine LP:
    t(mu) <= t16 <= t(mu cos(pi/16)); the closure's 5-edge polygon used to give ~10x that."""
    from planner.closure import min_grip_force

    patches, load = _rod_tripod()
    mu, gamma = 0.9, 0.004
    answers = {e: min_grip_force(patches, Friction(mu, gamma, edges=e), load) for e in (4, 5, 6, 8)}
    assert len(set(answers.values())) == 1, answers
    t16 = answers[5]
    # independent bracket: a circumscribed fine polygon under-estimates the exact t(mu), an
    # inscribed one with mu cos(pi/16) over-estimates t(mu cos(pi/16))
    lower = _grip_explicit_cone(patches, mu / math.cos(math.pi / 256), gamma, load, 256)
    upper = _grip_explicit_cone(patches, mu * math.cos(math.pi / 16), gamma, load, 256)
    assert lower * (1 - 1e-6) <= t16 <= upper * (1 + 1e-6), (lower, t16, upper)
    assert 0.10 < t16 < 0.13
    old5 = min_grip_force(patches, Friction(mu, gamma, edges=5), load, cone_sides=None)
    assert old5 > 5 * upper  # the artefact this guards against (cone_sides=None: the old behaviour)


def test_grip_force_rejects_a_bad_cone_side_count():
    from planner.closure import min_grip_force

    for bad in (2, 0, 4.5, True, "16"):
        with pytest.raises(InputError, match="cone_sides"):
            min_grip_force(_antipodal(), SOFT, [0, 0, -1, 0, 0, 0], cone_sides=bad)
