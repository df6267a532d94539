"""ROS message → ROSLink state payload, one hand-written function per preset.

Hand-written rather than generic because these run on every sensor message
and each is a handful of attribute reads. Non-finite ROS values (which JSON
cannot carry) become the documented "unknown" value of each field.
"""

from __future__ import annotations

import base64
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

Payload = dict[str, Any]


@dataclass(frozen=True, slots=True)
class StatePreset:
    name: str
    ros_types: tuple[str, ...]
    convert: Callable[[Any], Payload]


def _finite(value: float, unknown: float = 0.0) -> float:
    return value if math.isfinite(value) else unknown


def _usec(header: Any) -> int:
    usec: int = header.stamp.sec * 1_000_000 + header.stamp.nanosec // 1000  # builtin_interfaces/Time: ints
    return usec


def _rpy(q: Any) -> tuple[float, float, float]:
    """Roll, pitch, yaw (rad) of a quaternion."""
    x, y, z, w = q.x, q.y, q.z, q.w
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


def robot_status(msg: Any) -> Payload:  # sensor_msgs/BatteryState
    pct = msg.percentage
    return {
        "onboard_control_sensors_present": 0, "onboard_control_sensors_enabled": 0,
        "onboard_control_sensors_health": 0, "load": 0.0,
        "voltage_battery": _finite(msg.voltage),
        "current_battery": _finite(msg.current),
        "battery_remaining": round(pct * 100.0, 2) if math.isfinite(pct) else -1.0,
        "errors_count": 0,
    }


def _motion(stamp_header: Any, pose: Any, twist: Any | None) -> Payload:
    p = pose.position
    roll, pitch, yaw = _rpy(pose.orientation)
    lin = twist.linear if twist is not None else None
    ang = twist.angular if twist is not None else None
    return {
        "time_boot_ms": _usec(stamp_header) // 1000,
        "x": _finite(p.x), "y": _finite(p.y), "z": _finite(p.z),
        "vx": _finite(lin.x) if lin else 0.0, "vy": _finite(lin.y) if lin else 0.0,
        "vz": _finite(lin.z) if lin else 0.0,
        "wx": _finite(ang.x) if ang else 0.0, "wy": _finite(ang.y) if ang else 0.0,
        "wz": _finite(ang.z) if ang else 0.0,
        "roll": _finite(roll), "pitch": _finite(pitch), "yaw": _finite(yaw),
    }


def global_motion(msg: Any) -> Payload:  # Odometry, PoseStamped, PoseWithCovarianceStamped
    if hasattr(msg, "twist"):  # nav_msgs/Odometry
        return _motion(msg.header, msg.pose.pose, msg.twist.twist)
    pose = msg.pose.pose if hasattr(msg.pose, "pose") else msg.pose
    return _motion(msg.header, pose, None)


# sensor_msgs/NavSatStatus → MAVLink-style fix_type used by ROSLink
_FIX_TYPE = {-1: 1, 0: 3, 1: 4, 2: 6}


def gps_raw_info(msg: Any) -> Payload:  # sensor_msgs/NavSatFix
    ok = all(math.isfinite(v) for v in (msg.latitude, msg.longitude, msg.altitude))
    cov = msg.position_covariance
    known = msg.position_covariance_type != 0
    return {
        "time_usec": _usec(msg.header),
        "fix_type": _FIX_TYPE.get(msg.status.status, 0) if ok else 1,
        "lat": msg.latitude if ok else 0.0, "lon": msg.longitude if ok else 0.0, "alt": msg.altitude if ok else 0.0,
        "eph": _finite(math.sqrt(max(0.0, cov[0]))) if known else 0.0,
        "epv": _finite(math.sqrt(max(0.0, cov[8]))) if known else 0.0,
        "vel": 0.0, "cog": 0.0, "satellites_visible": 0,
    }


def range_finder_data(msg: Any) -> Payload:  # sensor_msgs/LaserScan
    lo, hi = msg.range_min, msg.range_max
    # NaN compares false, inf exceeds hi: both become null ("nothing hit").
    ranges = [r if lo <= r <= hi else None for r in msg.ranges.tolist()]
    intensities = msg.intensities.tolist()
    if not all(map(math.isfinite, intensities)):
        intensities = [v if math.isfinite(v) else 0.0 for v in intensities]
    return {
        "time_usec": _usec(msg.header),
        "range_min": _finite(lo), "range_max": _finite(hi),
        "angle_min": _finite(msg.angle_min), "angle_max": _finite(msg.angle_max),
        "angle_increment": _finite(msg.angle_increment),
        "time_increment": _finite(msg.time_increment), "scan_time": _finite(msg.scan_time),
        "ranges": ranges, "intensities": intensities,
    }


def image(msg: Any) -> Payload:  # sensor_msgs/CompressedImage
    return {"time_usec": _usec(msg.header), "width": 0, "height": 0, "format": msg.format or "jpeg",
            "data": base64.b64encode(msg.data.tobytes() if hasattr(msg.data, "tobytes") else bytes(msg.data))
            .decode("ascii")}


def occupancy_map(msg: Any) -> Payload:  # nav_msgs/OccupancyGrid
    info = msg.info
    return {"time_usec": _usec(msg.header), "width": info.width, "height": info.height,
            "resolution": _finite(info.resolution),
            "origin_x": _finite(info.origin.position.x), "origin_y": _finite(info.origin.position.y),
            "origin_yaw": _finite(_rpy(info.origin.orientation)[2]),
            "data": msg.data.tolist()}


STATE_PRESETS: dict[str, StatePreset] = {p.name: p for p in (
    StatePreset("robot_status", ("sensor_msgs/msg/BatteryState",), robot_status),
    StatePreset("global_motion", ("nav_msgs/msg/Odometry", "geometry_msgs/msg/PoseStamped",
                                  "geometry_msgs/msg/PoseWithCovarianceStamped"), global_motion),
    StatePreset("gps_raw_info", ("sensor_msgs/msg/NavSatFix",), gps_raw_info),
    StatePreset("range_finder_data", ("sensor_msgs/msg/LaserScan",), range_finder_data),
    StatePreset("image", ("sensor_msgs/msg/CompressedImage",), image),
    StatePreset("map", ("nav_msgs/msg/OccupancyGrid",), occupancy_map),
)}
