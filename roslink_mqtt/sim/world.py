"""Pure kinematics and sensing of the simulated robot (no ROS, so it is unit-testable).

A unicycle in a square room: it integrates commanded velocities, stops at the
walls and casts laser rays against them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

EARTH_RADIUS = 6_378_137.0  # m, WGS-84 equatorial


@dataclass
class Pose:
    x: float = 0.0
    y: float = 0.0
    yaw: float = 0.0


@dataclass
class World:
    half_size: float = 5.0  # the room spans ±half_size in x and y
    robot_radius: float = 0.2
    pose: Pose = field(default_factory=Pose)
    v: float = 0.0  # commanded forward speed, m/s
    w: float = 0.0  # commanded turn rate, rad/s
    max_speed: float = 1.0  # m/s the motors can do: faster commands are driven at this speed (a parameter)

    def __post_init__(self) -> None:
        if self.pose is None:  # World(pose=None), the old default spelled out, still gets a fresh pose
            self.pose = Pose()

    def command(self, v: float, w: float) -> None:
        v = v if math.isfinite(v) else 0.0
        self.v = max(-self.max_speed, min(self.max_speed, v))
        self.w = w if math.isfinite(w) else 0.0

    def step(self, dt: float) -> None:
        """Advance by ``dt`` seconds; the robot stops at the walls instead of passing them."""
        p = self.pose
        p.yaw = math.atan2(math.sin(p.yaw + self.w * dt), math.cos(p.yaw + self.w * dt))
        limit = self.half_size - self.robot_radius
        p.x = min(limit, max(-limit, p.x + self.v * math.cos(p.yaw) * dt))
        p.y = min(limit, max(-limit, p.y + self.v * math.sin(p.yaw) * dt))

    def reset(self) -> None:
        self.pose = Pose()
        self.v = self.w = 0.0

    def ray(self, angle: float) -> float:
        """Distance from the robot to the wall along ``angle`` (robot frame)."""
        p = self.pose
        a = p.yaw + angle
        dx, dy = math.cos(a), math.sin(a)
        hits = []
        if dx > 1e-12:
            hits.append((self.half_size - p.x) / dx)
        elif dx < -1e-12:
            hits.append((-self.half_size - p.x) / dx)
        if dy > 1e-12:
            hits.append((self.half_size - p.y) / dy)
        elif dy < -1e-12:
            hits.append((-self.half_size - p.y) / dy)
        return min(hits)

    def scan(self, beams: int, angle_min: float = -math.pi, angle_max: float | None = None) -> list[float]:
        if angle_max is None:
            angle_max = math.pi - 2 * math.pi / beams
        step = (angle_max - angle_min) / max(1, beams - 1)
        return [self.ray(angle_min + i * step) for i in range(beams)]

    def geodetic(self, lat0: float, lon0: float) -> tuple[float, float]:
        """Latitude/longitude of the robot, with the room's centre at (lat0, lon0)."""
        p = self.pose
        lat = lat0 + math.degrees(p.y / EARTH_RADIUS)
        lon = lon0 + math.degrees(p.x / (EARTH_RADIUS * math.cos(math.radians(lat0))))
        return lat, lon
