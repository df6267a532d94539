"""The sim's navigation controller (roslink_mqtt/sim/steer.py) brings the robot to any pose in its room, within
the tolerance and the heading, at bounded speeds, in bounded time."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from roslink_mqtt.sim.steer import Steering, wrap

pytestmark = pytest.mark.unit
coord = st.floats(-4.5, 4.5)
angle = st.floats(-math.pi, math.pi)


@settings(max_examples=60, deadline=None)
@given(coord, coord, angle, coord, coord, st.one_of(st.none(), angle))
def test_it_arrives_at_any_pose_within_bounds(x: float, y: float, yaw: float, gx: float, gy: float,
                                              gtheta: float | None) -> None:
    steering, dt = Steering(), 0.02
    for _ in range(int(60 / dt)):  # a minute of sim time at most
        v, w, arrived = steering.command(x, y, yaw, gx, gy, gtheta)
        assert 0.0 <= v <= steering.max_speed + 1e-9 and abs(w) <= steering.max_turn + 1e-9
        if arrived:
            break
        x, y, yaw = x + v * math.cos(yaw) * dt, y + v * math.sin(yaw) * dt, wrap(yaw + w * dt)
    else:
        pytest.fail(f"not there after a minute: at {x:.2f}, {y:.2f}, {yaw:.2f}")
    assert math.hypot(gx - x, gy - y) <= steering.tolerance
    if gtheta is not None:
        assert abs(wrap(gtheta - yaw)) <= 0.08
