"""A finger's tip_frame and pad.link must move with that finger's joints: another finger's
frame or the palm was accepted by `hand check` (0 errors), and every contact of the finger
was then refused in the grasp file as out of reach. Now the hand.yaml is refused, naming the
key and the finger's own links (frames)."""

from pathlib import Path

import pytest

from planner.errors import SpecError
from planner.hand import ROBOTS_DIR, Hand

SPEC = """schema_version: 1
urdf: URDF
palm_frame: palm
fingers:
  index: {joints: [index_0, index_1, index_2, index_3], tip_frame: index_tip}
  thumb: {joints: [thumb_0, thumb_1, thumb_2, thumb_3], tip_frame: thumb_tip,
          pad: {link: thumb_distal, point: [0.0103, 0.0, 0.0065], normal: [0.0, 0.0, 1.0]}}
"""


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "hand.yaml"
    path.write_text(text.replace("URDF", str((ROBOTS_DIR / "icub_right" / "icub_right.urdf").resolve())))
    return path


@pytest.mark.parametrize("old, new, key, words", [
    ("link: thumb_distal", "link: index_distal", "fingers.thumb.pad.link", "links are thumb_base, thumb_proximal"),
    ("link: thumb_distal", "link: palm", "fingers.thumb.pad.link", "'palm' is not a link of finger thumb"),
    ("tip_frame: index_tip", "tip_frame: thumb_tip", "fingers.index.tip_frame", "index_distal"),
    ("tip_frame: index_tip", "tip_frame: palm", "fingers.index.tip_frame", "does not move with finger index"),
])
def test_a_tip_or_pad_of_another_finger_is_refused(tmp_path, old, new, key, words):
    with pytest.raises(SpecError) as err:
        Hand.load(_write(tmp_path, SPEC.replace(old, new, 1)))
    assert err.value.key == key
    assert words in str(err.value) and str(tmp_path) in str(err.value)


def test_the_finger_own_tip_and_pad_load(tmp_path):
    hand = Hand.load(_write(tmp_path, SPEC))
    assert hand.fingers["thumb"].pad_link == "thumb_distal" and hand.fingers["index"].tip_frame == "index_tip"
