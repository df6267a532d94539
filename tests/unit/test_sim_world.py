"""Kinematics and ray casting of the simulated robot (pure logic)."""

from __future__ import annotations

import math

import pytest

from roslink_mqtt.sim.world import World


def test_drives_forward_and_turns() -> None:
    w = World()
    w.command(0.5, 0.0)
    for _ in range(100):
        w.step(0.01)
    assert w.pose.x == pytest.approx(0.5) and w.pose.y == pytest.approx(0.0)
    w.command(0.0, math.pi / 2)
    for _ in range(100):
        w.step(0.01)
    assert w.pose.yaw == pytest.approx(math.pi / 2)


def test_stops_at_walls_and_ignores_non_finite() -> None:
    w = World(half_size=1.0)
    w.command(10.0, 0.0)
    for _ in range(100):
        w.step(0.1)
    assert w.pose.x == pytest.approx(1.0 - w.robot_radius)
    w.command(math.nan, math.inf)
    assert (w.v, w.w) == (0.0, 0.0)


def test_rays_hit_walls() -> None:
    w = World(half_size=5.0)
    assert w.ray(0.0) == pytest.approx(5.0)
    assert w.ray(math.pi / 4) == pytest.approx(5.0 * math.sqrt(2))
    w.pose.x = 2.0
    assert w.ray(0.0) == pytest.approx(3.0) and w.ray(math.pi) == pytest.approx(7.0)
    assert len(w.scan(720)) == 720


def test_geodetic_moves_with_pose() -> None:
    w = World()
    lat0, lon0 = w.geodetic(24.0, 46.0)
    assert (lat0, lon0) == (24.0, 46.0)
    w.pose.y = 111.0
    lat, _ = w.geodetic(24.0, 46.0)
    assert lat - 24.0 == pytest.approx(0.000997, rel=1e-2)
