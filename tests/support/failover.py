"""Failover checks shared by the Mosquitto-pair and RabbitMQ-cluster tests: an operator that keeps driving, and
the kill → stopped → moving again measurement."""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Callable
from typing import Any

from roslink_mqtt.client import RobotClient
from roslink_mqtt.client.errors import NotConnectedError
from tests.support.measure import record_measurement

BACK_WITHIN = 5.0  # issue 18: commands flow again within 5 s of losing a node
STOPPED_WITHIN = 1.0


def moving(m: Any) -> bool:
    return m.linear.x > 0


def zero(m: Any) -> bool:
    return m.linear.x == 0 and m.angular.z == 0


def drive(client: RobotClient, robot: str, stop: threading.Event) -> threading.Thread:
    """A 10 Hz twist stream that keeps going through an outage (an operator holding the stick)."""
    def loop() -> None:
        while not stop.wait(0.1):
            try:
                client.twist(robot, lx=0.2)
            except NotConnectedError:  # down: until the client is on the next node
                pass
    thread = threading.Thread(target=loop, daemon=True)
    thread.start()
    return thread


def kill_and_measure(cmd_vel: Any, kill: Callable[[], None], what: str) -> tuple[float, float]:
    """Kill, then the seconds until the robot stopped and until it moved again; recorded, printed, asserted."""
    fault = time.monotonic()
    kill()
    stopped_at, _ = cmd_vel.wait_for(zero, timeout=5, after=fault)
    moving_at, _ = cmd_vel.wait_for(moving, timeout=BACK_WITHIN + 10, after=stopped_at)
    stopped, back = stopped_at - fault, moving_at - fault
    record_measurement(f"{what}: killed → robot stopped", stopped, STOPPED_WITHIN)
    record_measurement(f"{what}: killed → commands flow again via the next node", back, BACK_WITHIN)
    print(f"failover ({what}): stopped {stopped * 1000:.0f} ms after the kill, moving again after "
          f"{back * 1000:.0f} ms", file=sys.stderr)
    assert stopped <= STOPPED_WITHIN
    assert back <= BACK_WITHIN, f"commands flowed again only {back:.1f} s after the kill"
    return stopped, back
