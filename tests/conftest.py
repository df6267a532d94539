"""Session-wide test setup.

DDS must stay on this machine: the loopback-only ROS environment and a fresh
ROS_DOMAIN_ID are set before anything imports rclpy, and every subprocess a
test starts inherits them.
"""

from __future__ import annotations

from roslink_mqtt.ros_env import apply_local_ros_env

ROS_ENV = apply_local_ros_env()

MEASUREMENTS: list[tuple[str, float, float]] = []

# Pure logic: no processes, no sockets, no ROS. `pytest -m unit` runs these in seconds.
UNIT_MODULES = frozenset({
    "test_bridge_settings_config", "test_broker_acl", "test_broker_ratelimit", "test_config", "test_docs",
    "test_failsafe_logic", "test_late_commands", "test_protocol_malformed", "test_protocol_roundtrip",
    "test_safety", "test_sdk_docs", "test_sdk_unit", "test_sequence", "test_sim_world", "test_throttle",
    "test_topics", "test_limits_logic", "test_bridge_claim", "test_control_lease", "test_broker_logging",
})


def pytest_collection_modifyitems(config, items) -> None:
    import pytest

    for item in items:
        if item.path.stem in UNIT_MODULES:
            item.add_marker(pytest.mark.unit)


def record_measurement(name: str, seconds: float, deadline: float) -> None:
    """Keep a timing for the closing summary (tests print what they measured)."""
    MEASUREMENTS.append((name, seconds, deadline))


def pytest_terminal_summary(terminalreporter) -> None:
    if MEASUREMENTS:
        terminalreporter.section("measured safety timings")
        for name, seconds, deadline in MEASUREMENTS:
            terminalreporter.write_line(f"{name:<48} {seconds * 1000:7.0f} ms   (deadline {deadline * 1000:.0f} ms)")
