"""``estop --all`` (cli/estop_cmd.py) against a stand-in client: the stops go out as soon as the robots' retained
heartbeats have come, a robot seen later is stopped too, and a robot the user may not stop ends the wait on time.
The real command runs against real bridges in tests/integration/test_one_driver.py."""

from __future__ import annotations

import time

from roslink_mqtt.cli.estop_cmd import QUIET, stop_every_robot_seen


class Heartbeats:
    """robots() grows as heartbeats "arrive" at given times; emergency_stop_all records each call."""

    def __init__(self, arrivals: dict[str, float], stoppable: set[str]) -> None:
        self.start, self.arrivals, self.stoppable = time.monotonic(), arrivals, stoppable
        self.calls: list[tuple[float, list[str]]] = []

    def robots(self) -> list[str]:
        now = time.monotonic() - self.start
        return [r for r, at in self.arrivals.items() if at <= now]

    def emergency_stop_all(self, reason: str, *, robots: list[str], timeout: float) -> dict[str, str]:
        self.calls.append((time.monotonic() - self.start, list(robots)))
        return {r: "acknowledged" for r in robots if r in self.stoppable}


def test_stops_go_out_once_the_burst_is_over_and_late_robots_are_stopped_too() -> None:
    client = Heartbeats({"a": 0.0, "b": 0.01, "late": 0.6}, stoppable={"a", "b", "late"})
    reports = stop_every_robot_seen(client, "test", wait=1.0, timeout=0.5)  # type: ignore[arg-type]
    assert sorted(reports) == ["a", "b", "late"]
    (first_at, first), (late_at, late) = client.calls
    assert first == ["a", "b"] and first_at < 0.01 + QUIET + 0.2  # not after the whole wait
    assert late == ["late"] and 0.6 <= late_at < 0.8


def test_a_robot_that_may_not_be_stopped_does_not_hold_the_command() -> None:
    client = Heartbeats({"a": 0.0, "not-mine": 0.0}, stoppable={"a"})
    began = time.monotonic()
    reports = stop_every_robot_seen(client, "test", wait=0.5, timeout=0.5)  # type: ignore[arg-type]
    assert list(reports) == ["a"] and len(client.calls) == 1
    assert time.monotonic() - began < 1.0
