"""The uplink sender behind a hop that hides the queue (roslink_mqtt/bridge/core/uplink_sender.py): what a paced lane
still holds in paho has not left the robot, and while the path steers the lane writes at its allowance. ROS-free;
the links are stand-ins with real, never connected paho clients (the sender reads their queues)."""

from __future__ import annotations

import time

import pytest

from roslink_mqtt.bridge.core.uplink import PROBE
from roslink_mqtt.bridge.core.uplink_sender import Uplink
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


def a_modem_with_a_camera() -> Uplink:
    """A sender with a state lane and a camera's lane (lanes[2]) on a link whose queue backs up into the robot: the
    path answered once at the TCP connection's own round trip, so the socket steers."""
    main, state, camera = Link("main"), Link("state"), Link("camera")
    sender = Uplink(main, state, state_links={"state/camera": camera})  # type: ignore[arg-type, dict-item]
    sender.path.tcp_rtt = 0.039
    sender.path.probe_sent(time.monotonic() - 0.04, 0)
    sender.path.probe_answered(time.monotonic())
    return sender


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
    assert lane.pacer.rate == pytest.approx(sender.meter.allowance(lane.index, sender._tiers, probe=1.0,
                                                                   rate=sender.path.rate))
    sender.path.tcp_rtt = 0.039  # the TCP round trip is the path's: a modem, no hop; the socket steers alone
    with sender.lock:
        sender._refill(lane, time.monotonic())
    assert lane.pacer.rate is None


def test_paced_lanes_together_never_write_faster_than_the_path_carries() -> None:
    """While the path steers, the paced lanes' writes add up to the path's rate, not PROBE × it: a lane with a
    backlog that lasts (a 4 MB map) written 25 % over the path's rate kept a hidden queue growing for as long as
    the map took (the path cut to 0.85 × what it delivered, and 1.25 × that is still over it), until the camera
    got nothing and poses were seconds old (bench/weak_link.py's camera + map rows)."""
    main, state, camera, grid = Link("main"), Link("state"), Link("camera"), Link("map")
    sender = Uplink(main, state, {"camera": camera, "map": grid})  # type: ignore[arg-type] - stand-ins
    sender.path.tcp_rtt = 0.0001
    now = time.monotonic()
    sender.path.probe_sent(now - 0.04, 0)
    sender.path.probe_answered(now)
    assert sender.path.steering(now)
    with sender.lock:
        for lane in sender.lanes:
            sender._refill(lane, now)
        rate = sender.rate(now)
        # every lane busy: the state lane may take all the path leaves the main lane, the bulk lanes share it
        state_pace = sender.lanes[1].pacer.rate
        bulk_paces = [lane.pacer.rate for lane in sender.lanes[2:]]
    assert rate == sender.path.rate  # (the socket's meter starts at 1 Mbit/s, the path at 256 kbit/s)
    assert state_pace is not None and state_pace <= rate * 1.0001
    assert all(pace is not None for pace in bulk_paces)
    assert max(p or 0.0 for p in bulk_paces) <= rate * 1.0001


def test_behind_a_hop_the_sockets_meter_may_still_probe_up_to_the_paths_rate() -> None:
    """Where the socket's estimate is below the path's, the lanes offer PROBE × it (how the socket's meter finds a
    faster link; at exactly its estimate it would never see more delivered), but never more than the path's."""
    sender, state = behind_a_hop()
    lane = sender.lanes[1]
    sender.meter.rate = 10_000.0
    sender.path.rate = 100_000.0
    with sender.lock:
        sender._refill(lane, time.monotonic())
    assert lane.pacer.rate == pytest.approx(PROBE * 10_000.0)
    sender.meter.rate = 90_000.0
    with sender.lock:
        sender._refill(lane, time.monotonic())
    assert lane.pacer.rate == pytest.approx(100_000.0)


def test_a_paced_lane_holds_in_its_socket_its_own_share_of_the_budget_not_the_whole_links() -> None:
    """Where the queue backs up into the robot, a lane's socket drains at the lane's share: a camera behind the
    link's whole budget of its own frames waited seconds after a fall. Its own allowance's worth, at least one
    segment, at most the link's budget."""
    from roslink_mqtt.bridge.core.uplink import MIN_BUDGET

    sender = a_modem_with_a_camera()
    meter, lane = sender.meter, sender.lanes[2]
    meter.rate, meter.measured, meter.min_rtt = 32_000.0, True, 0.04
    meter.lane_rates, meter.lane_demand = [3_000.0, 30_000.0, 2_000.0], [3_000.0, 30_000.0, 2_000.0]
    with sender.lock:
        assert sender._lane_budget(lane, sender.budget()) == sender.budget()  # not a video lane: the link's budget
    lane.wants, lane.wanted_at = 12_000.0, time.monotonic()  # the camera's encoder aims at 96 kbit/s
    with sender.lock:
        budget = sender.budget()
        allowance, steering = sender._allowance(lane, time.monotonic())
        assert not steering
        mine = sender._lane_budget(lane, budget)
    assert mine == pytest.approx(max(MIN_BUDGET, allowance * (meter.min_rtt + meter.target_delay)), abs=1)
    assert mine <= 0.6 * budget  # the scan is owed half of what main leaves: the camera's socket holds its share
    meter.lane_demand = [3_000.0, 0.0, 0.0]  # alone on the link: the link's budget, no more
    with sender.lock:
        assert sender._lane_budget(lane, budget) == budget


def test_while_the_path_steers_a_stream_may_probe_up_only_without_a_queue_or_a_recent_cuts_capacity() -> None:
    """Behind a hop the path's rate never grows past 1.5 × what was delivered, so a camera whose encoder sends less
    than it aims at would never find the link: its probes at the base round trip say it may go up; a capacity found
    at a recent cut says it may not; nor may it where the robot's own sockets fill (a modem's queue: the probes
    of an idle lane come back at the base round trip while the busy lanes' sockets hold the queue)."""
    sender, _state = behind_a_hop()
    lane = sender.lanes[1]
    sender.meter.full = False  # behind the hop the sockets never fill
    assert sender.share_of(lane)[1]  # answered at the base round trip: no queue anywhere
    sender.meter.full = True
    assert not sender.share_of(lane)[1]
    sender.meter.full = False
    sender.path.capacity, sender.path._capacity_at = sender.path.rate, time.monotonic()
    assert not sender.share_of(lane)[1]


def test_a_streams_share_of_a_full_link_is_of_what_it_delivers_not_of_the_probe() -> None:
    """The lanes may offer PROBE × the socket meter's rate (how a faster link is found), but a camera aiming at
    its part of that on a full link built a standing queue in its socket (256 kbit/s modem: frames 430 ms old at
    the viewer); on a full link its share is of the rate; with room, of the probe (and it may probe itself)."""
    sender = a_modem_with_a_camera()
    meter, cam = sender.meter, sender.lanes[2]
    meter.rate, meter.measured = 32_000.0, True
    meter.lane_rates, meter.lane_demand = [3_000.0, 15_000.0, 14_000.0], [3_000.0, 30_000.0, 14_000.0]
    meter.full = True
    share, headroom = sender.share_of(cam, 14_000.0)
    assert not headroom
    assert share == pytest.approx((32_000.0 - 3_000.0) / 2)  # the scan wants more than half: half each
    with sender.lock:
        paced, steering = sender._allowance(cam, time.monotonic())
    assert not steering
    assert paced == pytest.approx((PROBE * 32_000.0 - 3_000.0) / 2)  # what the lane may write: still probes
    meter.full = False
    share, headroom = sender.share_of(cam, 14_000.0)
    assert headroom
    assert share == pytest.approx((PROBE * 32_000.0 - 3_000.0) / 2)


def test_what_a_stream_wants_counts_only_while_it_keeps_saying_it() -> None:
    """A camera nobody watches any more says nothing: it must not keep half its tier from the scan."""
    main, state, camera = Link("main"), Link("state"), Link("camera")
    sender = Uplink(main, state, state_links={"state/camera": camera})  # type: ignore[arg-type, dict-item]
    sender.meter.lane_rates, sender.meter.lane_demand = [3_000.0, 30_000.0, 0.0], [3_000.0, 60_000.0, 0.0]
    scan, cam = sender.lanes[1], sender.lanes[2]
    alone = sender.share_of(scan)[0]
    sender.share_of(cam, 10_000.0)  # the camera's encoder aims at 80 kbit/s (under half of what main leaves)
    assert sender.share_of(scan)[0] == pytest.approx(alone - 10_000.0)
    cam.wanted_at -= 2.0  # it stopped saying so (nobody watches)
    assert sender.share_of(scan)[0] == pytest.approx(alone)
