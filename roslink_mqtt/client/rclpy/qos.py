"""``rclpy.qos`` names for the SDK, so ``from rclpy.qos import QoSProfile`` code moves over by one import.

MQTT has no history depth or durability per publisher; what carries over is
reliability: ``RELIABLE`` publishes at MQTT QoS 1 (the broker acknowledges
every message), ``BEST_EFFORT`` at QoS 0 (cheapest, may be lost — right for a
stream that repeats itself, like a 10 Hz twist). A plain depth (``10``), the
rclpy default, keeps the SDK's choice per command: QoS 0 for twist streams,
QoS 1 for everything else. Real rclpy profiles are understood too (by their
reliability's name), so shared code may build them either way.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum
from typing import Any

from ..errors import InvalidArgument, InvalidType


class ReliabilityPolicy(IntEnum):
    """Same names and values as ``rclpy.qos.ReliabilityPolicy``."""

    SYSTEM_DEFAULT = 0
    RELIABLE = 1
    BEST_EFFORT = 2


class HistoryPolicy(IntEnum):
    """Accepted for source compatibility; MQTT keeps no per-publisher history."""

    SYSTEM_DEFAULT = 0
    KEEP_LAST = 1
    KEEP_ALL = 2


@dataclass(frozen=True, kw_only=True)
class QoSProfile:
    depth: int = 10
    reliability: ReliabilityPolicy = ReliabilityPolicy.RELIABLE
    history: HistoryPolicy = HistoryPolicy.KEEP_LAST

    def __post_init__(self) -> None:
        if isinstance(self.depth, bool) or not isinstance(self.depth, int) or self.depth < 0:
            raise InvalidArgument(f"QoSProfile depth must be an integer >= 0, got {self.depth!r}")


qos_profile_sensor_data = QoSProfile(depth=5, reliability=ReliabilityPolicy.BEST_EFFORT)
qos_profile_system_default = QoSProfile(reliability=ReliabilityPolicy.SYSTEM_DEFAULT)

_MQTT_QOS = {"RELIABLE": 1, "BEST_EFFORT": 0}


def mqtt_qos(profile: Any) -> int | None:
    """MQTT QoS for a profile (ours or rclpy's), None to keep the per-command default.

    A depth alone (an int) and SYSTEM_DEFAULT say nothing about reliability.
    Anything else is a mistake worth hearing about now, not a silent default.
    """
    if isinstance(profile, int) and not isinstance(profile, bool):
        if profile < 0:
            raise InvalidArgument(f"QoS depth must be >= 0, got {profile}")
        return None
    reliability = getattr(profile, "reliability", None)
    if reliability is None:
        raise InvalidType(f"expected a QoS depth (int) or a QoSProfile, got {type(profile).__name__}")
    name = getattr(reliability, "name", str(reliability)).upper()
    if name in ("SYSTEM_DEFAULT", "UNKNOWN"):
        return None
    if name not in _MQTT_QOS:
        raise InvalidArgument(f"unknown reliability {reliability!r}: use RELIABLE or BEST_EFFORT")
    return _MQTT_QOS[name]
