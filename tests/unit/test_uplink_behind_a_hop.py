"""The uplink sender behind a hop that hides the queue (roslink_mqtt/bridge/uplink_sender.py): what a paced lane
still holds in paho has not left the robot, and while the path steers the lane writes at its allowance. ROS-free;
the links are stand-ins with real, never connected paho clients (the sender reads their queues)."""

from __future__ import annotations

import time

import pytest

from roslink_mqtt.bridge.uplink_sender import Uplink
from tests.unit.test_uplink_sender_offline import Link

pytestmark = pytest.mark.unit

MAP = 4_000_000  # bytes: one OccupancyGrid in one message


def behind_a_hop() -> tuple[Uplink, Link]:
    """A sender whose path answers in 40 ms while its TCP connection's own round trip is 0.1 ms: a hop."""
    main, state = Link("main"), Link("state")
    sender = Uplink(main, state)  # type: ignore[arg-type] - the links' surface the sender uses
    sender.path.tcp_rtt = 0.0001
    now = time.monotonic()
    sender.path.probe_sent(now - 0.04, 0)
    sender.path.probe_answered(now)
    assert sender.path.behind_a_hop
    return sender, state


def test_a_map_waiting_in_paho_is_not_on_its_way() -> None:
    """A 4 MB map handed to the state lane's paho, written at the lane's pace: the path meter's byte clock does
    not count it as sent (counted, the path looked four megabytes faster than it is, and the next probes let
    everything through), and the room for a pose is the path's whole budget."""
    sender, state = behind_a_hop()
    with sender.lock:
        sender.handed += MAP
        state.client._out_packet.append({"to_process": MAP})  # paho holds it unsent (paho_unsent reads this)
        assert sender._left() == 0
        now = time.monotonic()
        assert sender._path_room(now) == sender.path.budget(now)
        assert sender._blocked(sender.main, 0, 300) is None  # a pose goes


def test_paced_lanes_write_at_their_allowance_only_while_the_path_steers() -> None:
    sender, state = behind_a_hop()
    lane = sender.lanes[1]
    with sender.lock:
        sender._refill(lane, time.monotonic())
    assert lane.pacer.rate == pytest.approx(sender.meter.allowance(lane.index, sender._tiers, rate=sender.rate()))
    sender.path.tcp_rtt = 0.039  # the TCP round trip is the path's: a modem, no hop; the socket steers alone
    with sender.lock:
        sender._refill(lane, time.monotonic())
    assert lane.pacer.rate is None
