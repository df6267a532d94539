"""No velocity leaving the bridge is ever NaN, infinite or beyond the limit (property test).

Limits bound speed: by default the Euclidean norm of the linear and of the angular vector (issue 12, item 8);
``per_axis`` clamps each component.
"""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from roslink_mqtt.bridge.core.safety import UnsafeCommand, clamp, clamp_components, clamp_norm
from roslink_mqtt.config import VelocityLimits

anything = st.floats(allow_nan=True, allow_infinity=True) | st.integers(-(10**20), 10**20)
vector = st.tuples(anything, anything, anything)
limit = st.floats(0, 100) | st.sampled_from([0.0, 5e-324, 1e-300, 0.5, 1e300])
modes = st.sampled_from(["norm", "per_axis"])


@given(vector, vector, limit, limit, modes)
def test_output_is_finite_and_within_limits(linear, angular, lin_limit, ang_limit, mode) -> None:
    limits = VelocityLimits(lin_limit, ang_limit, mode)
    try:
        lin, ang, cut = clamp_components(linear, angular, limits)
    except UnsafeCommand:
        assert not all(math.isfinite(v) for v in (*linear, *angular))
        return
    assert all(math.isfinite(v) for v in (*lin, *ang))
    if mode == "norm":
        assert math.hypot(*lin) <= lin_limit and math.hypot(*ang) <= ang_limit
    else:
        assert all(abs(v) <= lin_limit for v in lin) and all(abs(v) <= ang_limit for v in ang)
    assert cut == (lin != tuple(map(float, linear)) or ang != tuple(map(float, angular)))


@given(vector, limit)
def test_norm_clamp_keeps_direction(v, lim) -> None:
    try:
        out = clamp_norm(v, lim)
    except UnsafeCommand:
        return
    v = tuple(map(float, v))
    if math.hypot(*v) <= lim:
        assert out == v  # within the limit: untouched
        return
    # scaled down whole: every component keeps its sign (or becomes 0), none grows, ratios are kept
    for a, b in zip(v, out, strict=True):
        assert abs(b) <= abs(a) and (b == 0 or math.copysign(1, a) == math.copysign(1, b))
    big = max(range(3), key=lambda i: abs(v[i]))
    if abs(out[big]) > 1e-290:  # far from subnormals, where precision runs out
        for a, b in zip(v, out, strict=True):
            assert math.isclose(b / out[big], a / v[big], rel_tol=1e-9, abs_tol=1e-12)


def test_norm_limits_the_combined_speed() -> None:
    lin, ang, cut = clamp_components((0.5, 0.5, 0.5), (0, 0, 1.0), VelocityLimits(0.5, 1.5))
    assert cut and math.isclose(math.hypot(*lin), 0.5) and math.isclose(lin[0], 0.5 / math.sqrt(3))
    assert ang == (0.0, 0.0, 1.0)
    lin, _, _ = clamp_components((3.0, 4.0, 0.0), (0, 0, 0), VelocityLimits(1.0, 1.0))
    assert math.isclose(lin[0], 0.6) and math.isclose(lin[1], 0.8) and lin[2] == 0.0
    # huge finite components do not overflow on the way
    lin, _, _ = clamp_components((1.7e308, -1.7e308, 1.7e308), (0, 0, 0), VelocityLimits(0.5, 1.0))
    assert math.hypot(*lin) <= 0.5 and lin[0] > 0 > lin[1]


def test_per_axis_keeps_the_component_clamp() -> None:
    lin, _, cut = clamp_components((0.9, 0.5, -0.9), (0, 0, 0), VelocityLimits(0.5, 1.0, "per_axis"))
    assert cut and lin == (0.5, 0.5, -0.5)


def test_clamp_examples() -> None:
    assert clamp(0.2, 0.5) == 0.2
    assert clamp(9.0, 0.5) == 0.5
    assert clamp(-9, 0.5) == -0.5
    for bad in (math.nan, math.inf, -math.inf, True, "1", 10**400):
        with pytest.raises(UnsafeCommand):
            clamp(bad, 1.0)
    with pytest.raises(UnsafeCommand):
        clamp_norm((0.0, 10**400, 0.0), 1.0)
    _, _, cut = clamp_components((0.1, 0, 0), (0, 0, 0.2), VelocityLimits(0.5, 1.0))
    assert not cut
    _, _, cut = clamp_components((0.9, 0, 0), (0, 0, 0.2), VelocityLimits(0.5, 1.0))
    assert cut
