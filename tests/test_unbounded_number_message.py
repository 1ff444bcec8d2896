"""A non-finite number where any finite one goes says "expected a finite number", not "in
[-inf, inf]" (a plan's states[0].closure.metric: inf said "expected a finite number in
[-inf, inf], got inf")."""

import math

import pytest

from planner.errors import SpecError
from planner.fileio import Reader


@pytest.mark.parametrize("value", [math.inf, -math.inf, math.nan])
def test_unbounded_number_message(value):
    with pytest.raises(SpecError) as err:
        Reader("plan.yaml", value, "states[0].closure.metric", ranged=True).number()
    assert "expected a finite number, got" in str(err.value) and "inf," not in str(err.value).split("got")[0]


def test_a_bounded_number_still_names_its_range():
    with pytest.raises(SpecError, match=r"expected a finite number in \[-100, 100\], got nan"):
        Reader("plan.yaml", math.nan, "q", ranged=True).number(-100, 100)
