"""The uplink scheduler and link meter (roslink_mqtt/bridge/core/uplink.py): pure logic, no sockets, no ROS."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from roslink_mqtt.bridge.core.uplink import (
    INITIAL_RATE,
    MIN_BUDGET,
    MIN_RATE,
    PROBE,
    TARGET_DELAY,
    WINDOW,
    LinkMeter,
    Outgoing,
    UplinkScheduler,
)
from roslink_mqtt.config import Priority
from roslink_mqtt.config.model import default_latest_only, default_priority


def _msg(topic: str, n: int, qos: int = 0, retain: bool = False) -> Outgoing:
    return Outgoing(topic, str(n).encode(), qos, retain, float(n))


def _drain(s: UplinkScheduler, below: int | None = None) -> list[tuple[str, bytes]]:
    out = []
    while (taken := s.take(below)) is not None:
        out.append((taken[0].name, taken[1].payload))
    return out


def test_latest_wins_a_superseded_pose_is_never_sent_and_the_slot_keeps_its_place() -> None:
    s = UplinkScheduler()
    motion = s.stream("state/global_motion", Priority.MOTION, latest_only=True)
    scan = s.stream("state/range_finder_data", Priority.STATE, latest_only=True)
    gps = s.stream("state/gps_raw_info", Priority.STATE, latest_only=True)
    assert s.offer(scan, _msg(scan.name, 1)) is False
    s.offer(gps, _msg(gps.name, 2))
    for n in range(3, 8):
        s.offer(motion, _msg(motion.name, n))
    assert s.offer(scan, _msg(scan.name, 8)) is True  # replaces 1, still ahead of gps
    assert _drain(s) == [(motion.name, b"7"), (scan.name, b"8"), (gps.name, b"2")]
    assert (motion.offered, motion.sent, motion.superseded) == (5, 1, 4)
    assert (scan.superseded, gps.superseded) == (1, 0)
    assert s.waiting_bytes == 0 and not s


def test_ordered_streams_keep_every_message_in_order_and_never_drop_silently() -> None:
    s = UplinkScheduler(max_ordered=3)
    status = s.stream("state/robot_status", Priority.STATE, latest_only=False)
    for n in range(5):
        s.offer(status, _msg(status.name, n, qos=1, retain=True))
    assert _drain(s) == [(status.name, b"2"), (status.name, b"3"), (status.name, b"4")]
    assert status.dropped == 2 and status.superseded == 0 and status.sent == 3  # counted, reported in state/link


def test_classes_go_in_order_and_streams_of_a_class_take_turns() -> None:
    s = UplinkScheduler()
    bulk = s.stream("state/map", Priority.BULK, latest_only=True)
    a = s.stream("state/a", Priority.STATE, latest_only=False)
    b = s.stream("state/b", Priority.STATE, latest_only=False)
    motion = s.stream("state/global_motion", Priority.MOTION, latest_only=True)
    s.offer(bulk, _msg(bulk.name, 0))
    for n in (1, 2, 3):
        s.offer(a, _msg(a.name, n))
    s.offer(b, _msg(b.name, 4))
    s.offer(motion, _msg(motion.name, 5))
    assert s.has_waiting(below=Priority.BULK)
    assert _drain(s, below=Priority.BULK) == [(motion.name, b"5"), (a.name, b"1"), (b.name, b"4"), (a.name, b"2"),
                                              (a.name, b"3")]
    assert not s.has_waiting(below=Priority.BULK) and s.has_waiting()
    assert _drain(s) == [(bulk.name, b"0")]


def test_a_lost_connection_drops_what_waits_counting_ordered_losses() -> None:
    s = UplinkScheduler()
    pose = s.stream("state/global_motion", Priority.MOTION, latest_only=True)
    status = s.stream("state/robot_status", Priority.STATE, latest_only=False)
    image = s.stream("state/image", Priority.BULK, latest_only=True)
    s.offer(pose, _msg(pose.name, 1))
    s.offer(status, _msg(status.name, 2))
    s.offer(image, _msg(image.name, 3))
    assert s.drop_all(Priority.BULK) == 1 and s.has_waiting() and not s.has_waiting(below=Priority.MOTION)
    assert s.drop_all() == 2 and not s and s.waiting_bytes == 0
    assert status.dropped == 1 and pose.dropped == 0  # a pose is stale anyway: only ordered streams count a loss


@given(st.lists(st.tuples(st.integers(0, 5), st.booleans(), st.integers(0, 3)), max_size=200))
def test_whatever_is_offered_each_stream_sends_in_order_and_bytes_add_up(ops: list[tuple[int, bool, int]]) -> None:
    s = UplinkScheduler(max_ordered=4)
    streams = [s.stream(f"state/{i}", Priority(1 + i % 3), latest_only=i % 2 == 0) for i in range(6)]
    sent: dict[str, list[int]] = {}
    for n, (i, take, takes) in enumerate(ops):
        s.offer(streams[i], _msg(streams[i].name, n))
        if take:
            for name, payload in _drain(s)[:takes]:
                sent.setdefault(name, []).append(int(payload))
        assert s.waiting_bytes == sum(len(m.payload) for st_ in streams for m in st_.waiting)
    for name, payload in _drain(s):
        sent.setdefault(name, []).append(int(payload))
    for stream in streams:
        got = sent.get(stream.name, [])
        assert got == sorted(got)  # per-topic order, as MQTT promises
        assert stream.offered == stream.sent + stream.superseded + stream.dropped


def test_defaults_poses_are_motion_images_and_maps_bulk_retained_and_qos1_are_ordered() -> None:
    assert default_priority("global_motion", "nav_msgs/msg/Odometry") is Priority.MOTION
    assert default_priority(None, "nav_msgs/msg/Odometry") is Priority.MOTION
    assert default_priority(None, "sensor_msgs/msg/CompressedImage") is Priority.BULK
    assert default_priority("map", "nav_msgs/msg/OccupancyGrid") is Priority.BULK
    assert default_priority("range_finder_data", "sensor_msgs/msg/LaserScan") is Priority.STATE
    assert default_latest_only(False, 0) and not default_latest_only(True, 0) and not default_latest_only(False, 1)


def test_message_size_counts_the_mqtt_header() -> None:
    assert Outgoing("a/b", b"x" * 10, 0, False, 0.0).size == 2 + 2 + 3 + 10
    assert Outgoing("a/b", b"x" * 200, 1, False, 0.0).size == 1 + 2 + 2 + 3 + 2 + 200


# -- the meter ----------------------------------------------------------------------------------------------
def _run(meter: LinkMeter, rates: tuple[float, ...], limited: bool, seconds: float, start: float = 0.0,
         acked: tuple[int, ...] | None = None) -> tuple[float, tuple[int, ...]]:
    """``seconds`` of samples every 10 ms, each lane delivering its rate."""
    t, counters = start, list(acked or (0,) * len(rates))
    while t < start + seconds:
        t += 0.01
        counters = [c + int(r * 0.01) for c, r in zip(counters, rates, strict=True)]
        meter.sample(t, tuple(counters), limited, 0.08)
    return t, tuple(counters)


def test_the_meter_follows_a_link_that_limits_down_and_up() -> None:
    meter = LinkMeter()
    assert meter.budget == int(INITIAL_RATE * TARGET_DELAY)  # before any measurement
    t, acked = _run(meter, (5_000, 3_000), True, 2.0)  # 64 kbit/s in all, over two lanes
    assert meter.rate == pytest.approx(8_000, rel=0.1)
    assert meter.budget == max(MIN_BUDGET, int(meter.rate * (0.08 + TARGET_DELAY)))
    t, acked = _run(meter, (25_000, 100_000), True, 2.0, t, acked)  # 1 Mbit/s
    assert meter.rate == pytest.approx(125_000, rel=0.1)


def test_a_quiet_robot_does_not_talk_its_link_down_but_more_delivered_raises_the_estimate() -> None:
    meter = LinkMeter(rate=125_000.0)
    t, acked = _run(meter, (1_000,), False, 3.0)  # sends little: a lower bound only
    assert meter.rate == 125_000.0
    _run(meter, (500_000,), False, 1.0, t, acked)
    assert meter.rate == pytest.approx(500_000, rel=0.1)


def test_one_moment_without_a_full_network_makes_a_window_no_capacity_measurement() -> None:
    meter = LinkMeter(rate=125_000.0)
    meter.sample(0.0, (0,), True)
    meter.sample(0.1, (100,), False)  # held back by a lane's allowance, or nothing waited: says nothing of capacity
    assert meter.sample(WINDOW + 0.01, (200,), True) is not None
    assert meter.rate == 125_000.0 and not meter.measured


def test_later_lanes_get_what_the_earlier_ones_leave_and_a_little_more_to_probe() -> None:
    meter = LinkMeter(rate=16_000.0)
    _run(meter, (9_000, 7_000, 0), False, 0.5)  # main (control + motion), state, bulk
    assert meter.lane_rates == [pytest.approx(9_000, rel=0.05), pytest.approx(7_000, rel=0.05), 0.0]
    assert meter.allowance(1) == pytest.approx(PROBE * 16_000 - 9_000, rel=0.05)
    assert meter.allowance(2) == pytest.approx(PROBE * 16_000 - 16_000, rel=0.1)
    meter.lane_rates = [30_000.0, 0.0, 0.0]
    assert meter.allowance(1) == MIN_RATE  # never shut out completely: the budget always reopens
    meter.lane_rates, meter.lane_demand = [2_000.0, 3_000.0, 0.0], [2_000.0, 35_000.0, 90_000.0]
    assert meter.allowance(2) == MIN_RATE  # what state asks for comes first, even while bulk holds it back


def test_a_new_connection_starts_a_new_counter_and_keeps_the_rate() -> None:
    meter = LinkMeter()
    t, _ = _run(meter, (8_000,), True, 1.0)
    rate = meter.rate
    assert meter.sample(t + 0.01, (10,), True) is None  # the counter went back: a new connection
    assert meter.sample(t + 0.02, (10, 0), True) is None  # a lane came: a new window
    meter.reset()
    assert meter.rate == rate


def test_lanes_of_one_tier_share_what_the_tiers_before_them_leave() -> None:
    meter = LinkMeter(rate=100_000.0)
    meter.lane_rates, meter.lane_demand = [10_000.0, 20_000.0, 0.0, 0.0], [10_000.0, 20_000.0, 500_000.0, 4_000.0]
    tiers = (0, 1, 2, 2)  # main, state, camera, map
    left = PROBE * 100_000 - 30_000  # what main and state leave the bulk tier
    assert meter.allowance(3, tiers) == pytest.approx(left / 2)  # the map is not starved by the camera's demand
    assert meter.allowance(2, tiers) == pytest.approx(left - 4_000)  # the camera gets all the map leaves
    assert meter.allowance(1, tiers) == pytest.approx(PROBE * 100_000 - 10_000)


def test_a_tier_is_shared_max_min() -> None:
    meter = LinkMeter(rate=100_000.0)
    tiers = (0, 1, 1, 1)  # main; the state lane (a scan), a camera, a second camera
    meter.lane_rates, meter.lane_demand = [5_000.0, 30_000.0, 0.0, 0.0], [5_000.0, 30_000.0, 0.0, 0.0]
    assert meter.allowance(2, tiers, probe=1.0) == pytest.approx(95_000 - 30_000)  # idle peers take nothing
    meter.lane_demand[2] = meter.lane_demand[3] = 10_000.0
    assert meter.allowance(2, tiers, probe=1.0) == pytest.approx(95_000 - 30_000 - 10_000)
    meter.lane_demand[3] = 90_000.0  # hungry peers: the rest is split evenly
    assert meter.allowance(2, tiers, probe=1.0) == pytest.approx((95_000 - 30_000) / 2)
    meter.lane_demand[1] = 90_000.0
    assert meter.allowance(2, tiers, probe=1.0) == pytest.approx(95_000 / 3)
    assert meter.allowance(1, tiers, probe=1.0) == pytest.approx(95_000 - 10_000 - 42_500)


def test_ready_streams_in_service_order_and_taking_from_one() -> None:
    s = UplinkScheduler()
    cam = s.stream("state/camera", Priority.BULK, latest_only=True)
    log = s.stream("state/log", Priority.STATE, latest_only=False)
    pose = s.stream("state/pose", Priority.MOTION, latest_only=True)
    s.offer(cam, _msg(cam.name, 1))
    s.offer(log, _msg(log.name, 2))
    s.offer(log, _msg(log.name, 3))
    s.offer(pose, _msg(pose.name, 4))
    assert [x.name for x in s.ready()] == [pose.name, log.name, cam.name]
    assert s.take_from(log).payload == b"2" and [x.name for x in s.ready()] == [pose.name, log.name, cam.name]
    assert s.drop(log) == 1 and log.dropped == 1 and [x.name for x in s.ready()] == [pose.name, cam.name]
    assert s.drop(cam) == 1 and cam.dropped == 0  # a latest-only stream's waiting message is simply stale
    assert s.waiting_bytes == 1


def test_a_stream_that_says_what_it_wants_is_counted_at_that_even_while_others_take_the_room() -> None:
    meter = LinkMeter(rate=32_000.0)
    tiers = (0, 1, 1)  # main; a scan that wants more than the link; a camera that got little room so far
    meter.lane_rates, meter.lane_demand = [3_000.0, 27_000.0, 2_000.0], [3_000.0, 35_000.0, 2_000.0]
    assert meter.allowance(1, tiers, probe=1.0) == pytest.approx(29_000 - 2_000)  # the scan takes all it leaves
    assert meter.allowance(1, tiers, probe=1.0, wants=(0.0, 0.0, 11_000.0)) == pytest.approx(29_000 - 11_000)
    assert meter.allowance(2, tiers, probe=1.0, wants=(0.0, 0.0, 11_000.0)) == pytest.approx(29_000 / 2)
