"""Velocity safety: nothing non-finite or beyond the configured limits reaches ``cmd_vel``.

Applied to every Twist the bridge publishes — preset or generic rule — so no
mapping can bypass it. Pure functions on numbers; the ROS glue is in
:func:`make_safe_twist`.

Limits bound the *speed*, i.e. the Euclidean norm of the linear and of the
angular vector (``limits.mode: norm``, the default): clamping each component
on its own lets ``lx = ly = lz = 0.5`` through as 0.87 m/s under a 0.5 m/s
limit. A vector over the limit is scaled down whole, so the robot still goes
where it was told, only slower. ``per_axis`` keeps the old component clamp
for robots whose axes are limited independently.
"""

from __future__ import annotations

import math
from typing import Any

from ...config import VelocityLimits
from ...config.model import LIMIT_PER_AXIS

VELOCITY_TYPES = ("geometry_msgs/msg/Twist", "geometry_msgs/msg/TwistStamped")
STANDSTILL = VelocityLimits(0.0, 0.0)  # limits under which anything but zero is "cut"

Vector = tuple[float, float, float]


class UnsafeCommand(ValueError):
    """A velocity that must not be forwarded (non-finite, or not a number at all)."""


def _finite(value: Any) -> float:
    """``value`` as a finite float; UnsafeCommand for NaN, infinities, bools, non-numbers and huge integers."""
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        raise UnsafeCommand(f"velocity {value!r} is not a finite number")
    try:
        number = float(value)
    except OverflowError:  # an integer beyond float range
        raise UnsafeCommand(f"velocity {value!r} is out of range") from None
    if not math.isfinite(number):
        raise UnsafeCommand(f"velocity {value!r} is not a finite number")
    return number


def clamp(value: float, limit: float) -> float:
    """``value`` clamped into ±``limit``; raises UnsafeCommand if not finite."""
    return max(-limit, min(limit, _finite(value)))


def clamp_norm(vector: tuple[float, float, float], limit: float) -> Vector:
    """``vector`` scaled down, direction kept, so that its Euclidean norm is at most ``limit``.

    Raises UnsafeCommand if any component is not finite. Computed on the
    vector divided by its largest component, so huge finite inputs cannot
    overflow; the result is nudged down by an ulp if rounding left it above.
    """
    x, y, z = (_finite(c) for c in vector)
    if math.hypot(x, y, z) <= limit:
        return x, y, z
    big = max(abs(x), abs(y), abs(z))  # > 0: the norm exceeds a limit >= 0
    unit = (x / big, y / big, z / big)
    factor = limit / math.hypot(*unit)
    out = (unit[0] * factor, unit[1] * factor, unit[2] * factor)
    while math.hypot(*out) > limit:
        factor = math.nextafter(factor, 0.0)
        out = (unit[0] * factor, unit[1] * factor, unit[2] * factor)
    return out


def clamp_components(linear: tuple[float, float, float], angular: tuple[float, float, float],
                     limits: VelocityLimits) -> tuple[Vector, Vector, bool]:
    """Apply ``limits`` (by norm, or per axis); the flag says whether anything was cut (worth telling the user)."""
    if limits.mode == LIMIT_PER_AXIS:
        lx, ly, lz = (clamp(v, limits.linear) for v in linear)
        ax, ay, az = (clamp(v, limits.angular) for v in angular)
        lin, ang = (lx, ly, lz), (ax, ay, az)
    else:
        lin, ang = clamp_norm(linear, limits.linear), clamp_norm(angular, limits.angular)
    return lin, ang, lin != tuple(map(float, linear)) or ang != tuple(map(float, angular))


def make_safe_twist(msg: Any, limits: VelocityLimits) -> str | None:
    """Clamp a geometry_msgs Twist (or TwistStamped) in place; what was cut (for the sender), None if nothing was.

    Raises UnsafeCommand when any component is NaN or infinite: such a command
    is refused whole, never "repaired".
    """
    twist = msg.twist if hasattr(msg, "twist") else msg
    lin, ang = twist.linear, twist.angular
    asked = ((lin.x, lin.y, lin.z), (ang.x, ang.y, ang.z))
    (lin.x, lin.y, lin.z), (ang.x, ang.y, ang.z), cut = clamp_components(*asked, limits)
    if not cut:
        return None
    sent = ((lin.x, lin.y, lin.z), (ang.x, ang.y, ang.z))
    how = " per axis" if limits.mode == LIMIT_PER_AXIS else ""
    parts = [f"{what} speed {math.hypot(*before):.3g} {unit} cut to {math.hypot(*after):.3g} {unit} "
             f"(limit {limit:g} {unit}{how})"
             for what, unit, limit, before, after in (("linear", "m/s", limits.linear, asked[0], sent[0]),
                                                      ("angular", "rad/s", limits.angular, asked[1], sent[1]))
             if tuple(map(float, before)) != after]
    return "clamped to the robot's limits: " + "; ".join(parts)


class ClampNotices:
    """Which velocity streams were told that the robot clamps them: the first clamped twist of a stream is, the
    others are not (a 10 Hz stream over the limit is one notice, not ten a second).

    A stream is one sender's commands on one velocity input (a sender: the user and the program, by its client id —
    two `pub` runs one after the other are two streams, each told); it ends with a zero twist, or with a pause
    longer than ``pause`` (the dead-man's ``command_timeout``: after it the robot has stopped anyway). Pure logic:
    the endpoint calls :meth:`tell` for every velocity command it carries out, under its lock.
    """

    KEPT = 256  # streams remembered before the ended ones are forgotten (client ids are new with every program)

    def __init__(self, pause: float) -> None:
        self.pause = pause
        self._streams: dict[tuple[str, ...], float] = {}  # (user, client id, input) → last twist of a told stream

    def tell(self, stream: tuple[str, ...], now: float, *, clamped: bool, standstill: bool) -> bool:
        """Whether this twist's clamping is news to its sender (bounded: :data:`KEPT` streams, then only the live
        ones)."""
        last = self._streams.get(stream)
        if standstill:
            self._streams.pop(stream, None)
            return False
        told = last is not None and now - last <= self.pause
        if told or clamped:
            self._streams[stream] = now
            if len(self._streams) > self.KEPT:
                self._streams = {k: t for k, t in self._streams.items() if now - t <= self.pause}
                if len(self._streams) > self.KEPT:  # a flood of client ids, all live: forget them (at worst a
                    self._streams = {stream: now}  # sender hears of its clamping again), never rebuild per twist
        return clamped and not told


def is_standstill(msg: Any) -> bool:
    """Whether a Twist (or TwistStamped) commands no motion at all: a stop, which is never dropped as late."""
    twist = msg.twist if hasattr(msg, "twist") else msg
    lin, ang = twist.linear, twist.angular
    return not any((lin.x, lin.y, lin.z, ang.x, ang.y, ang.z))
