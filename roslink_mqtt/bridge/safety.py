"""Velocity safety: nothing non-finite or beyond the configured limits reaches ``cmd_vel``.

Applied to every Twist the bridge publishes — preset or generic rule — so no
mapping can bypass it. Pure functions on numbers; the ROS glue is in
:func:`make_safe_twist`.
"""

from __future__ import annotations

import math
from typing import Any

from ..config import VelocityLimits

VELOCITY_TYPES = ("geometry_msgs/msg/Twist", "geometry_msgs/msg/TwistStamped")
STANDSTILL = VelocityLimits(0.0, 0.0)  # limits under which anything but zero is "cut"


class UnsafeCommand(ValueError):
    """A velocity that must not be forwarded (non-finite)."""


def clamp(value: float, limit: float) -> float:
    """``value`` clamped into ±``limit``; raises UnsafeCommand if not finite."""
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value):
        raise UnsafeCommand(f"velocity {value!r} is not a finite number")
    return max(-limit, min(limit, float(value)))


def clamp_components(linear: tuple[float, float, float], angular: tuple[float, float, float],
                     limits: VelocityLimits) -> tuple[tuple[float, ...], tuple[float, ...], bool]:
    """Clamp each component; the flag says whether anything was cut (worth telling the user)."""
    lin = tuple(clamp(v, limits.linear) for v in linear)
    ang = tuple(clamp(v, limits.angular) for v in angular)
    return lin, ang, lin != tuple(map(float, linear)) or ang != tuple(map(float, angular))


def make_safe_twist(msg: Any, limits: VelocityLimits) -> bool:
    """Clamp a geometry_msgs Twist (or TwistStamped) in place; True if it was cut.

    Raises UnsafeCommand when any component is NaN or infinite: such a command
    is refused whole, never "repaired".
    """
    twist = msg.twist if hasattr(msg, "twist") else msg
    lin, ang = twist.linear, twist.angular
    (lin.x, lin.y, lin.z), (ang.x, ang.y, ang.z), cut = clamp_components(
        (lin.x, lin.y, lin.z), (ang.x, ang.y, ang.z), limits)
    return cut
