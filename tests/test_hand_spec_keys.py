"""Unknown keys of a hand.yaml (top level, a finger, its pad) are refused, naming the file,
the key and the valid keys, as a grasp file's are: a misspelt `close_joint:` or
`close_towards:` was ignored, and the finger then closed every joint upward without a word.
`units:` other than metres and radians is refused (it was ignored too)."""

from pathlib import Path

import pytest

from planner.errors import SpecError
from planner.hand import ROBOTS_DIR, Hand

SPEC = """schema_version: 1
units: {length: m, angle: rad}
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
    ("palm_frame: palm", "palm_frame: palm\nopen_posture: {thumb_0: 0.3}", "open_posture",
     "valid keys are schema_version, name, units, urdf"),
    ("tip_frame: index_tip}", "tip_frame: index_tip, close_joint: [index_1]}", "fingers.index.close_joint",
     "valid keys are joints, close_joints, close_toward, contact_links, tip_frame, pad"),
    ("normal: [0.0, 0.0, 1.0]}", "normal: [0.0, 0.0, 1.0], radius: 0.006}", "fingers.thumb.pad.radius",
     "valid keys are link, point, normal"),
    ("length: m", "length: mm", "units.length", "m and angles in rad, got 'mm'"),
    ("angle: rad", "angle: deg", "units.angle", "got 'deg'"),
    ("angle: rad", "angle: rad, mass: kg", "units.mass", "valid keys are length, angle"),
])
def test_unknown_keys_and_other_units_are_refused(tmp_path, old, new, key, words):
    with pytest.raises(SpecError) as err:
        Hand.load(_write(tmp_path, SPEC.replace(old, new, 1)))
    assert err.value.key == key
    assert words in str(err.value) and str(tmp_path) in str(err.value)


def test_the_bundled_and_a_written_spec_load(tmp_path):
    assert Hand.load(_write(tmp_path, SPEC)).fingers["thumb"].pad_link == "thumb_distal"
    for name in ("icub_right", "allegro_right"):
        Hand.load(name)
