"""No velocity leaving the bridge is ever NaN, infinite or beyond the limit (property test)."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from roslink_mqtt.bridge.safety import UnsafeCommand, clamp, clamp_components
from roslink_mqtt.config import VelocityLimits

anything = st.floats(allow_nan=True, allow_infinity=True) | st.integers(-(10**20), 10**20)


@given(st.tuples(anything, anything, anything), st.tuples(anything, anything, anything),
       st.floats(0, 100), st.floats(0, 100))
def test_output_is_finite_and_within_limits(linear, angular, lin_limit, ang_limit) -> None:
    limits = VelocityLimits(lin_limit, ang_limit)
    try:
        lin, ang, _ = clamp_components(linear, angular, limits)
    except UnsafeCommand:
        assert not all(math.isfinite(v) for v in (*linear, *angular))
        return
    assert all(math.isfinite(v) and abs(v) <= lin_limit for v in lin)
    assert all(math.isfinite(v) and abs(v) <= ang_limit for v in ang)


def test_clamp_examples() -> None:
    assert clamp(0.2, 0.5) == 0.2
    assert clamp(9.0, 0.5) == 0.5
    assert clamp(-9, 0.5) == -0.5
    for bad in (math.nan, math.inf, -math.inf, True, "1"):
        with pytest.raises(UnsafeCommand):
            clamp(bad, 1.0)
    _, _, cut = clamp_components((0.1, 0, 0), (0, 0, 0.2), VelocityLimits(0.5, 1.0))
    assert not cut
    _, _, cut = clamp_components((0.9, 0, 0), (0, 0, 0.2), VelocityLimits(0.5, 1.0))
    assert cut
