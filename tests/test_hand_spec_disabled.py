"""`disabled_collisions:` given as one name instead of a list of pairs is refused as such
(it was read letter by letter: "expected [link_a, link_b], got 'p'")."""

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


@pytest.mark.parametrize("value, words", [
    ("palm", "expected a list of [link_a, link_b] pairs, got 'palm'"),
    ("{palm: index_distal}", "expected a list of [link_a, link_b] pairs"),
    ("[[palm]]", "expected [link_a, link_b], got ['palm']"),
])
def test_disabled_collisions_not_a_list_of_pairs(tmp_path, value, words):
    path = tmp_path / "hand.yaml"
    path.write_text(SPEC.replace("URDF", str((ROBOTS_DIR / "icub_right" / "icub_right.urdf").resolve()))
                    + f"disabled_collisions: {value}\n")
    with pytest.raises(SpecError) as err:
        Hand.load(path)
    assert err.value.key == "disabled_collisions" and words in str(err.value)
