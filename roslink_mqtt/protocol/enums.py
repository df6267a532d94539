"""ROSLink enumerations (robot types, system status, flight modes).

Values follow the ROSLink paper, which borrows them from MAVLink so that
existing ground-station vocabulary carries over.
"""

from enum import IntEnum


class RobotType(IntEnum):
    GENERIC = 0
    GROUND = 1
    QUADROTOR = 2
    FIXED_WING = 3
    HUMANOID = 4
    MANIPULATOR = 5
    UNDERWATER = 6


class SystemStatus(IntEnum):
    """Robot state carried in the heartbeat's ``system_status`` field."""

    UNINIT = 0
    BOOT = 1
    CALIBRATING = 2
    STANDBY = 3
    ACTIVE = 4
    CRITICAL = 5
    EMERGENCY = 6
    POWEROFF = 7
    OFFLINE = 8  # written by the broker from the bridge's last-will


class FlightMode(IntEnum):
    """Modes a robot may report in the heartbeat and accept in ``set_mode``."""

    MANUAL = 0
    STABILIZE = 1
    GUIDED = 2
    AUTO = 3
    LOITER = 4
    RETURN_TO_LAUNCH = 5
    LAND = 6
    TAKEOFF = 7


class AckResult(IntEnum):
    """Outcome in an acknowledgement (message 109)."""

    ACCEPTED = 0
    REJECTED = 1
    FAILED = 2
    FAILSAFE = 3
