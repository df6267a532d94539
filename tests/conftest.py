"""Session-wide test setup.

DDS must stay on this machine: the loopback-only ROS environment and a fresh
ROS_DOMAIN_ID are set before anything imports rclpy, and every subprocess a
test starts inherits them.
"""

from __future__ import annotations

from roslink_mqtt.ros_env import apply_local_ros_env

ROS_ENV = apply_local_ros_env()

MEASUREMENTS: list[tuple[str, float, float]] = []


def record_measurement(name: str, seconds: float, deadline: float) -> None:
    """Keep a timing for the closing summary (tests print what they measured)."""
    MEASUREMENTS.append((name, seconds, deadline))


def pytest_terminal_summary(terminalreporter) -> None:
    if MEASUREMENTS:
        terminalreporter.section("measured safety timings")
        for name, seconds, deadline in MEASUREMENTS:
            terminalreporter.write_line(f"{name:<48} {seconds * 1000:7.0f} ms   (deadline {deadline * 1000:.0f} ms)")
