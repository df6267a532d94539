"""Session-wide test setup.

DDS must stay on this machine: the loopback-only ROS environment and a fresh
ROS_DOMAIN_ID are set before anything imports rclpy, and every subprocess a
test starts inherits them.
"""

from __future__ import annotations

import signal
from pathlib import Path

from roslink_mqtt.ros_env import apply_local_ros_env
from tests.support.measure import MEASUREMENTS

ROS_ENV = apply_local_ros_env()

# Tests stop the programs they start with Ctrl-C (SIGINT), as a user would. A shell that runs the suite as a
# background job starts it with SIGINT ignored, and an ignored signal stays ignored in every child (Python then
# installs no KeyboardInterrupt handler): take SIGINT back here, so children start with its default again.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

# Each folder is a kind of test, and its marker: `pytest tests/unit` (or `-m unit`) runs the pure logic in seconds,
# without ROS or a broker (tests/unit/conftest.py refuses an rclpy import there).
FOLDER_MARKERS = ("unit", "integration", "security", "browser")


def pytest_collection_modifyitems(config, items) -> None:
    import pytest

    tests = Path(__file__).parent
    for item in items:
        folder = item.path.relative_to(tests).parts[0] if item.path.is_relative_to(tests) else ""
        if folder in FOLDER_MARKERS:
            item.add_marker(getattr(pytest.mark, folder))


def pytest_terminal_summary(terminalreporter) -> None:
    if MEASUREMENTS:
        terminalreporter.section("measured safety timings")
        for name, seconds, deadline in MEASUREMENTS:
            terminalreporter.write_line(f"{name:<48} {seconds * 1000:7.0f} ms   (deadline {deadline * 1000:.0f} ms)")
