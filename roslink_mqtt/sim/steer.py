"""How the simulated robot drives itself to a pose (its navigation action's controller): turn toward the goal,
drive while roughly facing it, slow down on the way in, then turn to the goal's heading if it has one.

Pure logic (no ROS): :class:`Steering` answers one velocity command per control step. A stand-in for Nav2's
planner and controller, good enough to drive a VDA 5050 order across the sim's empty room.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

TURN_FIRST = 0.6  # rad: facing further away than this, the robot turns on the spot before it drives
HEADING_DONE = 0.08  # rad: close enough to the goal's heading


def wrap(angle: float) -> float:
    return math.atan2(math.sin(angle), math.cos(angle))


@dataclass(frozen=True, slots=True)
class Steering:
    max_speed: float = 0.5  # m/s
    max_turn: float = 1.2  # rad/s
    tolerance: float = 0.1  # m: arrived
    gain: float = 1.0  # 1/s: speed per metre left, and turn rate per radian of heading error

    def command(self, x: float, y: float, yaw: float, gx: float, gy: float,
                gtheta: float | None) -> tuple[float, float, bool]:
        """``(v, w, arrived)`` from the pose ``(x, y, yaw)`` toward ``(gx, gy)`` and heading ``gtheta``."""
        dx, dy = gx - x, gy - y
        distance = math.hypot(dx, dy)
        if distance > self.tolerance:
            error = wrap(math.atan2(dy, dx) - yaw)
            w = max(-self.max_turn, min(self.max_turn, self.gain * 2.0 * error))
            if abs(error) > TURN_FIRST:
                return 0.0, w, False
            v = min(self.max_speed, self.gain * distance) * math.cos(error)
            return max(v, 0.05), w, False
        if gtheta is None:
            return 0.0, 0.0, True
        error = wrap(gtheta - yaw)
        if abs(error) <= HEADING_DONE:
            return 0.0, 0.0, True
        return 0.0, max(-self.max_turn, min(self.max_turn, self.gain * 2.0 * error)), False

    def remaining(self, x: float, y: float, gx: float, gy: float) -> float:
        return math.hypot(gx - x, gy - y)
