"""Temporal contact filter (thesis section VII) on synthetic noisy streams like Table I."""

import numpy as np
import pytest

from planner.errors import InputError
from planner.sim.contact_filter import ContactFilter

FINGERS = ("index", "middle", "ring", "little", "thumb")
GROUND = ("box_base", "ground")


def _c(finger, x=0.0):
    """One contact of a fingertip with the object: key, points (1,3), normals (1,3)."""
    return (f"right_{finger}_fingertip", "object"), [[x, 0.0, 0.0]], [[0.0, 0.0, 1.0]]


def _sample(*names):
    out = []
    for name in names:
        if name == "ground":
            out.append((GROUND, [[0, 0, -1.0]], [[0, 0, 1.0]]))
        else:
            out.append(_c(name))
    return out


# Thesis Table I: bodies in collision per sample, no finger moved.
TABLE_I = [
    (),
    ("ground",),
    (),
    ("index", "ground"),
    ("index", "ground", "ring", "middle"),
    ("index",),
    ("middle", "ring"),
    (),
    ("index", "ring", "middle"),
    ("ring", "little"),
    ("index", "ground", "ring", "middle", "thumb"),
    ("little",),
    ("index", "ring", "middle", "thumb"),
    ("ground", "ring", "thumb"),
    ("index", "ground", "ring", "middle", "thumb", "little"),
]


def _on_object(key):
    return key[1] == "object"


def test_table_i_stream_accumulates_all_fingers_and_ignores_ground():
    """Fed the Table I stream, the filter ends with all five fingertips and no ground contact,
    although no single raw sample before the last one has them all."""
    filt = ContactFilter(k_missing=5, relevant=_on_object)
    raw_max = 0
    for names in TABLE_I:
        out = filt.update(_sample(*names))
        assert GROUND not in out
        raw_max = max(raw_max, len([n for n in names if n != "ground"]))
    fingers = {key[0] for key in out}
    assert fingers == {f"right_{f}_fingertip" for f in FINGERS}
    # from sample 11 on (thumb appears) the filtered set has >= 4 fingers in every sample
    filt.reset()
    counts = [len(filt.update(_sample(*names))) for names in TABLE_I]
    assert min(counts[10:]) >= 4
    assert counts[-1] == 5


def test_removal_after_exactly_k_misses():
    """A contact survives k-1 consecutive misses and is removed at the k-th."""
    k = 4
    filt = ContactFilter(k_missing=k)
    key = _c("index")[0]
    filt.update([_c("index")])
    for miss in range(1, k):
        out = filt.update([])
        assert key in out and out[key].missing == miss
    assert key not in filt.update([])
    # it comes back with a fresh counter when sampled again
    out = filt.update([_c("index")])
    assert out[key].missing == 0 and out[key].seen == 1


def test_k_one_is_the_raw_stream():
    """With k_missing=1 the filtered set equals each raw sample."""
    filt = ContactFilter(k_missing=1, relevant=_on_object)
    for names in TABLE_I:
        out = filt.update(_sample(*names))
        assert {key[0] for key in out} == {f"right_{n}_fingertip" for n in names if n != "ground"}


def test_new_sample_replaces_points_and_normals():
    """A kept contact takes the points of its newest sample; several entries of one key merge."""
    filt = ContactFilter(k_missing=3)
    key = _c("thumb")[0]
    filt.update([_c("thumb", x=0.01)])
    out = filt.update([_c("thumb", x=0.02), _c("thumb", x=0.03)])
    np.testing.assert_allclose(out[key].points[:, 0], [0.02, 0.03])
    assert out[key].points.shape == (2, 3) and out[key].normals.shape == (2, 3)
    assert not out[key].points.flags.writeable
    out = filt.update([])  # a miss keeps the last points
    np.testing.assert_allclose(out[key].points[:, 0], [0.02, 0.03])


def test_patches_group_by_finger():
    """patches() groups kept contacts by a key -> name map and skips None."""
    filt = ContactFilter(k_missing=2)
    filt.update([_c("index", 0.01), (("right_index_proximal", "object"), [[0, 1, 0]], [[0, -1, 0]]),
                 (("palm", "object"), [[0, 0, 0]], [[0, 0, 1]])])
    patches = filt.patches(lambda key: key[0].split("_")[1] if key[0] != "palm" else None)
    assert set(patches) == {"index"}
    points, normals = patches["index"]
    assert points.shape == (2, 3) and normals.shape == (2, 3)


@pytest.mark.parametrize("p_drop", [0.3, 0.5])
def test_random_dropouts_filtered_presence_at_least_99_percent(p_drop):
    """With seeded dropouts of probability p, every true contact is in >= 99% of filtered
    samples (after its first appearance), while raw samples miss many of them."""
    rng = np.random.default_rng(1234)
    k = 12
    n_samples = 3000
    filt = ContactFilter(k_missing=k, relevant=_on_object)
    present_f = {f: 0 for f in FINGERS}
    present_r = {f: 0 for f in FINGERS}
    counted = {f: 0 for f in FINGERS}
    started = set()
    raw_complete = 0
    for _ in range(n_samples):
        seen = [f for f in FINGERS if rng.random() >= p_drop]
        names = list(seen) + (["ground"] if rng.random() < 0.5 else [])
        out = filt.update(_sample(*names))
        started.update(seen)
        raw_complete += len(seen) == len(FINGERS)
        kept = {key[0] for key in out}
        for f in started:
            counted[f] += 1
            present_f[f] += f"right_{f}_fingertip" in kept
            present_r[f] += f in seen
    for f in FINGERS:
        assert present_f[f] / counted[f] >= 0.99, (f, present_f[f] / counted[f])
        assert present_r[f] / counted[f] <= 1.0 - p_drop + 0.05
    assert raw_complete / n_samples < 0.2  # the raw stream rarely has all five fingers


def test_removed_contact_disappears_after_lift():
    """A finger that really lifts leaves the filtered set k samples after its last contact."""
    k = 6
    filt = ContactFilter(k_missing=k)
    for _ in range(10):
        filt.update(_sample("index", "thumb"))
    history = [len(filt.update(_sample("thumb"))) for _ in range(k + 2)]
    assert history[: k - 1] == [2] * (k - 1)
    assert history[k - 1:] == [1] * 3


def test_bad_arguments():
    """k_missing must be a positive integer and point/normal counts must match."""
    with pytest.raises(InputError):
        ContactFilter(k_missing=0)
    with pytest.raises(InputError):
        ContactFilter(k_missing=2.5)
    filt = ContactFilter(k_missing=2)
    with pytest.raises(InputError):
        filt.update([(("a", "object"), [[0, 0, 0], [1, 0, 0]], [[0, 0, 1]])])
