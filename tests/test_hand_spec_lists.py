"""A hand.yaml's finger lists (joints, close_joints, contact_links) are refused empty or with
a joint named twice, naming the file, the key and the valid choices (an empty close_joints
list was accepted and `check` ended in an IndexError in the closing procedure)."""

from pathlib import Path

import pytest

from planner.errors import SpecError
from planner.hand import ROBOTS_DIR, Hand

SPEC = """schema_version: 1
urdf: URDF
palm_frame: palm
fingers:
  index: {joints: [index_0, index_1, index_2, index_3], tip_frame: index_tip}
  thumb: {joints: [thumb_0, thumb_1, thumb_2, thumb_3], tip_frame: thumb_tip}
"""
INDEX = "joints: [index_0, index_1, index_2, index_3], tip_frame: index_tip"


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "hand.yaml"
    path.write_text(text.replace("URDF", str((ROBOTS_DIR / "icub_right" / "icub_right.urdf").resolve())))
    return path


@pytest.mark.parametrize("index, key, words", [
    ("joints: [], tip_frame: index_tip", "fingers.index.joints", "empty list"),
    ("joints: [index_0, index_1, index_1, index_3], tip_frame: index_tip", "fingers.index.joints",
     "'index_1' is named twice"),
    (INDEX + ", close_joints: []", "fingers.index.close_joints", "joints are index_0, index_1, index_2, index_3"),
    (INDEX + ", close_joints: [index_1, index_1]", "fingers.index.close_joints", "'index_1' is named twice"),
    (INDEX + ", contact_links: []", "fingers.index.contact_links",
     "links are index_proximal, index_intermediate, index_distal"),
])
def test_empty_or_repeated_finger_lists_are_refused(tmp_path, index, key, words):
    with pytest.raises(SpecError) as err:
        Hand.load(_write(tmp_path, SPEC.replace(INDEX, index)))
    assert err.value.key == key
    assert words in str(err.value)
    assert str(tmp_path) in str(err.value)


def test_the_lists_left_out_still_default_to_the_whole_finger(tmp_path):
    finger = Hand.load(_write(tmp_path, SPEC)).fingers["index"]
    assert finger.close_joints == finger.joints
    assert finger.contact_links == ("index_proximal", "index_intermediate", "index_distal")
