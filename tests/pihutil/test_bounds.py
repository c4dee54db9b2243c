"""pihutil.bounds: a Bound takes the numbers of its interval and nothing else, whatever the type of what it is given
(a float, an integer of any size, a bool, text, NaN, infinity)."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from pihutil.bounds import EPISODES, TIMEOUT_S, Bound


@given(st.one_of(st.integers(), st.floats(allow_nan=True, allow_infinity=True), st.booleans(), st.text(max_size=3),
                 st.none()))
def test_contains_answers_for_anything_and_only_inside(value) -> None:
    for bound in (EPISODES, TIMEOUT_S, Bound(0.0, math.inf, infinite=True)):
        inside = bound.contains(value)
        if inside:
            assert isinstance(value, (int, float)) and not isinstance(value, bool)
            assert (value > bound.low if bound.low_open else value >= bound.low) and value <= bound.high


@pytest.mark.parametrize("value", [10**400, -(10**400), 2**64])
def test_a_huge_integer_is_outside_not_an_overflow(value) -> None:
    assert not EPISODES.contains(value) and not TIMEOUT_S.contains(value)
