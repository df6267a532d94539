"""A robot on a thin uplink (issue 25): the real bridge reaches the embedded broker through a 128 kbit/s shaped link
(one FIFO shared by all its connections, like a modem) while ROS floods it with far more than the link carries:
poses at 10 Hz, a 2 kB state blob at 10 Hz and 20 kB camera frames at 10 Hz (≈ 1.8 Mbit/s in all).

With ``bridge.uplink: scheduled`` (the default) the viewer sees fresh poses (latest wins: a superseded pose is
never sent), heartbeats on time and service replies within a second, while the camera gets what is left. The
control, the same scene with ``uplink: fifo`` (poses pile up seconds old, which the same checks would catch), runs
side by side with it in ``bench/weak_link.py`` (docs/performance.md, "Weak links"): 15 s of the suite's time.
"""

from __future__ import annotations

import contextlib
import re
import secrets
import sys
import threading
import time

import orjson
import pytest

from roslink_mqtt.bridge.core.spool import Spool
from roslink_mqtt.client import RobotClient
from roslink_mqtt.client.directory import DEFAULT_STALE_AFTER
from roslink_mqtt.localproc import free_port, wait_for_port
from roslink_mqtt.protocol.link import LinkReport
from tests.support.broker_setup import write_fleet
from tests.support.embedded_broker import EmbeddedBrokerProcess
from tests.support.measure import record_measurement
from tests.support.mqtt_client import TestClient
from tests.support.procs import bridge_env, run
from tests.support.ros import RosProbe
from tests.support.waits import never, paced, stays, wait_until

pytestmark = pytest.mark.timeout(120)

UPLINK_KBIT = 128
RULES = """    rules: &rules
      - {direction: ros_to_mqtt, ros_topic: /wl/odom, ros_type: nav_msgs/msg/Odometry,
         mqtt_topic: state/pose, preset: global_motion}
      - {direction: ros_to_mqtt, ros_topic: /wl/blob, ros_type: std_msgs/msg/String, mqtt_topic: state/blob}
      - {direction: ros_to_mqtt, ros_topic: /wl/camera, ros_type: sensor_msgs/msg/CompressedImage,
         mqtt_topic: state/camera, encoding: raw}
"""
MEASURE = 4.0  # s of flood measured, after the first pose arrived
LARGE_FRAME = 300_000  # bytes: 19 s of the thin uplink in one message
HEARTBEAT_GAP_LINE = DEFAULT_STALE_AFTER - 1.0  # s: a viewer still sees the robot online, with a second to spare


def _first_pose(poses: list, log) -> None:
    """Until the viewer has a pose (30 s); the tail of the bridge's ``log`` if none comes."""
    try:
        wait_until("a first pose at the viewer", lambda: poses, timeout=30)
    except AssertionError:
        raise AssertionError(f"no pose arrived: {log.read_text()[-2000:]}") from None


def _scene(tmp_path, mode: str, *link_args: str, measure: float = MEASURE, settle: float = 0.0,
           large_every: int = 0, keepalive: int = 2, until_measured: float = 0.0) -> dict:
    """Flood the robot for ``measure`` s; what bob and a service caller saw. ``link_args``: more options of the
    shaped link (``--hidden-queue``); ``settle``: s of the flood before measuring, after the first pose;
    ``large_every``: every that many camera frames is a LARGE_FRAME (a map's worth in one message);
    ``keepalive``: the bridge's (the demo's 2 s by default); ``until_measured``: after the measurement, the flood
    goes on for up to this many s until a link report says the uplink's meter has measured the link (on a loaded
    machine the flood itself may be slow to fill the link: a clean-clone run with a CPU hog saw a 4 s scene end
    before it had)."""
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import CompressedImage
    from std_msgs.msg import String
    from std_srvs.srv import Trigger

    fleet = write_fleet(tmp_path, edit=lambda text: text.replace("    rules: &rules\n", RULES, 1).replace(
        "      keepalive: 2\n", f"      keepalive: {keepalive}\n      uplink: {mode}\n", 1))
    seen: dict = {"poses": [], "blobs": [], "camera": 0, "heartbeats": [], "replies": [], "link": None,
                  "links": []}
    with EmbeddedBrokerProcess(tmp_path, fleet) as broker:
        link_port = free_port()
        uplink = [] if "--phases" in link_args else ["--up-kbit", str(UPLINK_KBIT)]  # phases: the uplink's rates
        with run(["-m", "roslink_mqtt.shaped_link", "--listen", f"127.0.0.1:{link_port}", "--to",
                  f"127.0.0.1:{broker.port}", "--delay-ms", "20", "--jitter-ms", "0", *uplink,
                  "--down-kbit", "1024", *link_args], tmp_path / "link.log"), \
                run(["-m", "roslink_mqtt.bridge.main", "--config", str(fleet), "--robot", "turtle1", "--url",
                     f"mqtt://127.0.0.1:{link_port}"], tmp_path / "bridge.log", bridge_env("turtle1")), \
                TestClient(broker.port, "bob", "bob-demo") as bob:
            wait_for_port(link_port, 10)
            seen["link_up"] = time.time()  # its phases (--phases) count from here
            probe = RosProbe()
            probe.node.create_service(Trigger, "/status", lambda _req, resp: setattr(resp, "success", True) or resp)
            recording, ended = threading.Event(), threading.Event()

            def on_message(_c, _u, m) -> None:
                now = time.time()
                leaf = m.topic.rsplit("/", 1)[-1]
                if leaf == "pose":
                    body = orjson.loads(m.payload)["payload"]
                    seen["poses"].append((now, body["x"], now - body["time_boot_ms"] / 1000))
                if leaf == "link" and m.payload and not ended.is_set():  # a report after the flood shows an idle
                    seen["link"] = LinkReport.from_json(m.payload)  # link (a loaded clean-clone run: measured False)
                    if seen["poses"]:  # every report from the flood's first pose on (one every 2 s)
                        seen["links"].append(seen["link"])
                if not recording.is_set() or m.retain:
                    return
                if leaf == "blob":
                    seen["blobs"].append(now - float(orjson.loads(m.payload)["data"][:20]))
                elif leaf == "camera":
                    seen["camera"] += 1
                elif leaf == "heartbeat":
                    seen["heartbeats"].append(time.monotonic())

            try:
                assert bob.connect() == 0
                bob.client.on_message = on_message
                bob.subscribe("roslink/turtle1/state/#", qos=0)
                bob.subscribe("roslink/turtle1/heartbeat", qos=0)
                odom = probe.publisher(Odometry, "/wl/odom")
                blob = probe.publisher(String, "/wl/blob")
                camera = probe.publisher(CompressedImage, "/wl/camera")
                frame = CompressedImage(format="jpeg", data=bytes(20_000))
                large = CompressedImage(format="jpeg", data=bytes(LARGE_FRAME))
                stop = threading.Event()

                def flood() -> None:
                    n = 0
                    while not stop.wait(0.1):  # 10 Hz poses, blob and camera
                        n += 1
                        msg = Odometry()
                        now = time.time()
                        msg.header.stamp.sec, msg.header.stamp.nanosec = int(now), int((now % 1) * 1e9)
                        msg.pose.pose.position.x = float(n)
                        odom.publish(msg)
                        blob.publish(String(data=f"{time.time():<20.6f}" + "x" * 2000))
                        camera.publish(large if large_every and n % large_every == 0 else frame)

                flooder = threading.Thread(target=flood, daemon=True)
                flooder.start()
                _first_pose(seen["poses"], tmp_path / "bridge.log")
                stays("the flood", flooder.is_alive, seconds=settle)
                recording.set()
                began = len(seen["poses"])
                with RobotClient("bob", "bob-demo", url=f"mqtt://127.0.0.1:{broker.port}") as caller:
                    for _ in paced(1.0, within=measure):  # a call a second
                        t0 = time.monotonic()
                        try:
                            caller.call("turtle1", "status", timeout=5.0)
                            seen["replies"].append(time.monotonic() - t0)
                        except Exception as err:  # noqa: BLE001 - a lost reply is what the check counts
                            seen["replies"].append(float("inf"))
                            print(f"call failed: {err}", file=sys.stderr)
                recording.clear()
                with contextlib.suppress(AssertionError):  # not measured yet: the test's own check says so
                    wait_until("a link report that has measured the uplink",
                               lambda: seen["link"] is not None and _knows_capacity(seen["link"]),
                               timeout=until_measured, period=0.2)
                ended.set()
                seen["poses"] = seen["poses"][began:]
                stop.set()
                flooder.join(2)
            finally:
                probe.close()
    return seen


DISK_EVENT_RULES = """    rules: &rules
      - {direction: ros_to_mqtt, ros_topic: /wl/odom, ros_type: nav_msgs/msg/Odometry,
         mqtt_topic: state/pose, preset: global_motion}
      - {direction: ros_to_mqtt, ros_topic: /wl/events, ros_type: std_msgs/msg/String,
         mqtt_topic: state/events, mqtt_qos: 1, buffer: disk}
"""


def _disk_events_fleet(tmp_path, *, keepalive: int, mode: str):
    """The demo fleet with turtle1's poses and a ``buffer: disk`` event rule (spooled under ``tmp_path``)."""
    settings = f"      keepalive: {keepalive}\n      uplink: {mode}\n      buffer_dir: {tmp_path / 'spool'}\n"
    return write_fleet(tmp_path, edit=lambda text: text.replace("    rules: &rules\n", DISK_EVENT_RULES, 1).replace(
        "      keepalive: 2\n", settings, 1))


def _spooled(spool_dir) -> int:
    """How many records turtle1's disk buffer holds (a record still being written is not counted)."""
    return sum(Spool.whole_records(segment.read_bytes()) for segment in spool_dir.glob("turtle1-*.spool"))


def _knows_capacity(link: LinkReport) -> bool:
    """The report's rate is the link's capacity: the robot's socket found the link full (``measured``), or the path
    steers (``hidden``: a queue the sockets did not show was found, so the rate is the path's estimate; this test's
    link has no hop). Where the path steers from the start it keeps the socket from ever filling, so ``measured``
    alone may stay false for a whole run (a clean-clone CI run: path rate 104 kbit/s for this 128 kbit/s link,
    steering, ``measured`` false). The rate band below checks the estimate itself."""
    return link.measured or link.hidden


def _quantile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


def test_a_thin_uplink_keeps_poses_fresh_heartbeats_on_time_and_bulk_last(tmp_path) -> None:
    seen = _scene(tmp_path, "scheduled", until_measured=20.0)
    poses = seen["poses"]
    ages = [age for _, _, age in poses]
    indices = [x for _, x, _ in poses]
    assert indices == sorted(indices), "poses out of order"
    assert len(set(indices)) == len(indices), "a pose arrived twice"
    assert len(poses) >= 5 * MEASURE, f"only {len(poses)} poses in {MEASURE} s"  # ≥ 5 Hz of the 10 Hz offered
    assert _quantile(ages, 0.9) < 1.5, f"poses arrive stale: p90 age {_quantile(ages, 0.9):.2f} s"
    beats = seen["heartbeats"]
    gaps = [b - a for a, b in zip(beats, beats[1:], strict=False)]
    # The line is what a viewer needs: a gap under DEFAULT_STALE_AFTER never shows the robot offline. The typical
    # gap (≤ 1.1 s at this rate) is bench/weak_link.py's to measure; CI once saw one heartbeat 1.85 s late (2.85 s).
    record_measurement("thin uplink: largest heartbeat gap", max(gaps, default=float("inf")), HEARTBEAT_GAP_LINE)
    assert len(beats) >= MEASURE - 3 and max(gaps) < HEARTBEAT_GAP_LINE, f"heartbeat gaps {gaps}"
    assert seen["replies"] and max(seen["replies"]) < 3.0, f"service replies waited: {seen['replies']}"
    assert seen["blobs"] and max(seen["blobs"]) < 4.0, f"stale state blobs: {seen['blobs']}"
    assert len(seen["blobs"]) < 0.6 * 10 * MEASURE  # most were superseded (latest wins), yet each is fresh
    assert seen["camera"] < 10 * MEASURE / 2, "the camera was not held back"  # bulk gets what is left
    link = seen["link"]  # the retained state/link report says why the streams are slow
    assert link is not None and link.mode == "scheduled" and _knows_capacity(link), link
    # the estimate the reports show finds the link's rate, and stays near it (each report is a snapshot of an estimate
    # that starts high: loaded clean-clone runs saw 400 then 109 kbit/s, and a single report of 203 or 205 kbit/s, for
    # a 128 kbit/s link; a meter that does not find the link stays at several times it)
    rates = [r.rate_kbit_s for r in seen["links"]]
    assert any(0.5 * UPLINK_KBIT < r < 2 * UPLINK_KBIT for r in rates) and rates[-1] < 2 * UPLINK_KBIT, rates
    blob = link.streams["blob"]
    assert blob.priority == "state" and blob.latest_only and blob.superseded > 0 and blob.sent_hz < blob.offered_hz
    assert link.streams["camera"].priority == "bulk" and link.streams["pose"].priority == "motion"


def test_behind_a_hop_that_hides_the_queue_the_path_steers_and_poses_stay_fresh(tmp_path) -> None:
    """The same flood through a hop that acknowledges every byte at once (a carrier's split-TCP proxy, a VPN, a load
    balancer that terminates TCP: ``shaped_link --hidden-queue``), so the robot's socket never shows the queue.
    The socket alone let it grow: poses 5-9 s old and getting older (issue 42). The path's probes find it: after
    the first seconds, in which the path's rate is learnt (``settle``), the poses stay fresh, heartbeats on time,
    and ``state/link`` says the path steers, at about the link's rate. Every 20th camera frame is 300 kB: written
    in one go it would put 19 s of the link ahead of every connection's keep-alive (a 4 MB map did so behind a
    1 Mbit/s hop, and the robot went offline); the camera's lane writes it at its allowance instead."""
    seen = _scene(tmp_path, "scheduled", "--hidden-queue", measure=2 * MEASURE, settle=3.0, large_every=20)
    poses = seen["poses"]
    ages = [age for _, _, age in poses]
    assert len(poses) >= 5 * 2 * MEASURE, f"only {len(poses)} poses in {2 * MEASURE} s"
    record_measurement("hidden-queue uplink: pose age p90", _quantile(ages, 0.9), 1.5)
    assert _quantile(ages, 0.9) < 1.5, f"poses arrive stale behind the hidden queue: {sorted(ages)[-5:]}"
    assert max(ages) < 3.0, f"the hidden queue grew: poses up to {max(ages):.1f} s old"
    beats = seen["heartbeats"]
    gaps = [b - a for a, b in zip(beats, beats[1:], strict=False)]
    record_measurement("hidden-queue uplink: largest heartbeat gap", max(gaps, default=float("inf")),
                       HEARTBEAT_GAP_LINE)
    assert len(beats) >= 2 * MEASURE - 3 and max(gaps) < HEARTBEAT_GAP_LINE, f"heartbeat gaps {gaps}"
    assert seen["replies"] and max(seen["replies"]) < 3.0, f"service replies waited: {seen['replies']}"
    link = seen["link"]
    assert link is not None and link.path is not None, link
    assert link.path.steering and link.path.cuts > 0, link.path  # the queue was found beyond the socket
    paths = [r.path.rate_kbit_s for r in seen["links"] if r.path is not None]  # found, and kept near it
    assert any(0.3 * UPLINK_KBIT < r < 1.5 * UPLINK_KBIT for r in paths) and paths[-1] < 2 * UPLINK_KBIT, paths
    assert seen["camera"] < 10 * 2 * MEASURE / 2, "the camera was not held back"
    # the 300 kB frames leave at the camera lane's allowance, seconds each: paho's keep-alive dropped that lane
    # mid-frame nearly every time (its PINGREQ queued behind the frame), until a lane whose bytes leave counted as
    # alive. (The broker may still drop a connection that only listens, whose PINGREQ met more than a second of
    # queue: with the demo's 2 s keep-alive, once in about twenty runs on a busy machine, while the path's rate is
    # learnt: the demo's keep-alive is short on purpose; it is not what this check is about.)
    lost = [line for line in (tmp_path / "bridge.log").read_text().splitlines() if "Keep alive timeout" in line]
    assert not lost, f"the bridge dropped a connection of its own: {lost}"


def test_behind_a_hiding_hop_a_fall_to_an_eighth_is_followed(tmp_path) -> None:
    """The hidden-queue hop's capacity falls from 1 Mbit/s to 128 kbit/s in an instant (a vehicle moving to a worse
    cell): what was on its way at the old rate takes eight times as long, and the path's rate must follow within
    seconds, or the queue it keeps filling grows without bound. Poses from four seconds after the fall are fresh.

    What the path held at the fall (up to about 0.3 s of the old rate) takes up to ~3.4 s to cross after it: poses
    in it arrive that old, and the demo's 2 s keep-alive (3 s at the broker) can lose every connection meanwhile
    (two clean-clone runs in about twenty did: the reconnection then restarts the path's estimate). That is a limit
    of any sender that cannot see the fall coming (docs/performance.md); this test gives the bridge the default
    5 s keep-alive and looks at what follows the drain."""
    fall = 8.0
    seen = _scene(tmp_path, "scheduled", "--hidden-queue", "--phases", f"{fall:g}:1024,600:{UPLINK_KBIT}",
                  "--phases-once", measure=fall + 8.0, keepalive=5)
    fell_at = seen["link_up"] + fall
    after = [age for at, _, age in seen["poses"] if at > fell_at + 4.0]
    assert seen["poses"][0][0] < fell_at, "the flood began after the fall: nothing measured before it"
    assert len(after) >= 5 * 3, f"only {len(after)} poses from 4 s after the fall"
    record_measurement("hidden-queue uplink, 1 Mbit/s → 128 kbit/s: pose age p90 from 4 s after the fall",
                       _quantile(after, 0.9), 1.5)
    assert _quantile(after, 0.9) < 1.5, f"stale after the fall: {sorted(after)[-5:]}"
    link = seen["link"]
    assert link is not None and link.path is not None and link.path.rate_kbit_s < 2 * UPLINK_KBIT, link


def test_a_dead_spot_shorter_than_the_keepalive_loses_no_connection_and_no_disk_event(tmp_path) -> None:
    """Behind a hiding hop, the link goes dead both ways for 3 s (a tunnel, a yard behind a hall: nothing crosses,
    yet the connections stay open) while an idle robot with the default 5 s keep-alive publishes poses and
    ``buffer: disk`` events. The bridge keeps every connection (no last will at the viewer, no keep-alive drop in
    its log), stops nothing (nobody drives: the broker's silence stops a robot only while it moves), every event
    published before, during and after the dead spot arrives, in order, and poses are fresh again within seconds
    of the link's return (issue 42)."""
    from nav_msgs.msg import Odometry
    from std_msgs.msg import String

    dead_at, dead, after = 9.0, 3.0, 7.0  # s from the link's start
    fleet = _disk_events_fleet(tmp_path, keepalive=5, mode="scheduled")
    poses: list[tuple[float, float]] = []  # (arrival, age)
    events: list[int] = []
    offline = threading.Event()

    def on_message(_c, _u, m) -> None:
        now = time.time()
        leaf = m.topic.rsplit("/", 1)[-1]
        if leaf == "pose":
            poses.append((now, now - orjson.loads(m.payload)["payload"]["time_boot_ms"] / 1000))
        elif leaf == "events":
            events.append(int(orjson.loads(m.payload)["data"][:8]))
        elif leaf == "heartbeat" and m.payload and orjson.loads(m.payload)["payload"]["system_status"] == 8:
            offline.set()  # the bridge's last will: the broker saw a connection of the robot go

    probe = RosProbe()
    stop = threading.Event()
    published: list[int] = []
    try:
        odom = probe.publisher(Odometry, "/wl/odom")
        event_pub = probe.publisher(String, "/wl/events")

        def publish() -> None:
            n = 0
            while not stop.wait(0.1):  # poses at 10 Hz, an event every 0.2 s
                msg = Odometry()
                now = time.time()
                msg.header.stamp.sec, msg.header.stamp.nanosec = int(now), int((now % 1) * 1e9)
                odom.publish(msg)
                n += 1
                if n % 2 == 0 and poses:  # from the first pose on: the bridge is online
                    event_pub.publish(String(data=f"{len(published):<8}" + "e" * 200))
                    published.append(len(published))

        with EmbeddedBrokerProcess(tmp_path, fleet) as broker, TestClient(broker.port, "bob", "bob-demo") as bob:
            assert bob.connect() == 0
            bob.client.on_message = on_message
            bob.subscribe("roslink/turtle1/state/#", qos=1)
            bob.subscribe("roslink/turtle1/heartbeat", qos=1)
            link_port = free_port()
            with run(["-m", "roslink_mqtt.shaped_link", "--listen", f"127.0.0.1:{link_port}", "--to",
                      f"127.0.0.1:{broker.port}", "--delay-ms", "20", "--jitter-ms", "0", "--hidden-queue",
                      "--phases", f"{dead_at:g}:256,{dead:g}:0,600:256", "--down-phases",
                      f"{dead_at:g}:1024,{dead:g}:0,600:1024", "--phases-once"], tmp_path / "link.log"), \
                    run(["-m", "roslink_mqtt.bridge.main", "--config", str(fleet), "--robot", "turtle1", "--url",
                         f"mqtt://127.0.0.1:{link_port}"], tmp_path / "bridge.log", bridge_env("turtle1")):
                wait_for_port(link_port, 10)
                link_up = time.time()  # its phases count from here
                threading.Thread(target=publish, daemon=True).start()
                log = tmp_path / "bridge.log"
                _first_pose(poses, log)
                assert time.time() < link_up + dead_at - 2.0, "the robot came online too late for the dead spot"
                # through the dead spot and ``after`` s beyond it, no connection of the bridge may go
                never("the bridge's last will at the viewer", offline.is_set,
                      seconds=max(0.0, link_up + dead_at + dead + after - time.time()))
                stop.set()
                wanted = list(published)
                with contextlib.suppress(AssertionError):  # the checks below say which are missing
                    wait_until("every published event at the viewer", lambda: set(wanted) <= set(events),
                               timeout=15, period=0.1)
                log_text = log.read_text()
                went = offline.is_set()  # (before the bridge's own offline heartbeat as it shuts down)
    finally:
        stop.set()
        probe.close()
    back = link_up + dead_at + dead
    assert len(wanted) > 5 * (dead + after), f"only {len(wanted)} events were published"
    assert set(wanted) <= set(events), f"events lost: {sorted(set(wanted) - set(events))[:10]}"
    first = list(dict.fromkeys(events))  # QoS 1: a resend may repeat one; first arrivals in order
    assert first == sorted(first), f"events out of order: {first}"
    assert not went, "a connection of the bridge went (its last will was published)"
    assert "Keep alive timeout" not in log_text and "failsafe stop" not in log_text, log_text[-3000:]
    stale = [at for at, age in poses if at > back and age >= 0.8]
    fresh_at = max(stale, default=back) - back
    record_measurement("hidden-queue uplink, 3 s dead spot: poses fresh again after the return", fresh_at, 5.0)
    assert fresh_at < 5.0, f"poses stale until {fresh_at:.1f} s after the link returned"
    assert [at for at, _ in poses if at > back + fresh_at], "no pose after the link returned"


@pytest.mark.parametrize("conflate", [True, False], ids=["conflated", "fifo-control"])
def test_a_viewer_on_a_thin_downlink_sees_fresh_poses_while_a_camera_streams(tmp_path, conflate: bool) -> None:
    """A phone on a 256 kbit/s downlink subscribes to a robot's camera (1.6 Mbit/s) and pose: the embedded broker
    holds one latest-wins slot per state topic for it once its connection is backed up, so its poses stay fresh.
    ``conflate_backlog=0`` (first in, first out, like Mosquitto's queue) is the control: poses go stale."""
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import CompressedImage

    fleet = write_fleet(tmp_path, edit=lambda text: text.replace("    rules: &rules\n", RULES, 1))
    extra = () if conflate else ("--limit", "conflate_backlog=0")
    ages: list[float] = []
    arrivals: list[float] = []  # s from the flood's start, every pose: shown when a line is missed
    began = time.monotonic()
    with EmbeddedBrokerProcess(tmp_path, fleet, *extra) as broker:
        link_port = free_port()
        with run(["-m", "roslink_mqtt.shaped_link", "--listen", f"127.0.0.1:{link_port}", "--to",
                  f"127.0.0.1:{broker.port}", "--delay-ms", "20", "--jitter-ms", "0", "--down-kbit", "256"],
                 tmp_path / "link.log"), \
                run(["-m", "roslink_mqtt.bridge.main", "--config", str(fleet), "--robot", "turtle1", "--url",
                     f"mqtt://127.0.0.1:{broker.port}"], tmp_path / "bridge.log", bridge_env("turtle1")), \
                TestClient(link_port, "bob", "bob-demo") as phone:
            wait_for_port(link_port)
            probe = RosProbe()
            recording = threading.Event()

            def on_message(_c, _u, m) -> None:
                if recording.is_set() and m.topic.endswith("/state/pose"):
                    ages.append(time.time() - orjson.loads(m.payload)["payload"]["time_boot_ms"] / 1000)
                if m.topic.endswith("/state/pose"):
                    arrivals.append(round(time.monotonic() - began, 2))

            try:
                assert phone.connect(timeout=10) == 0
                phone.client.on_message = on_message
                phone.subscribe("roslink/turtle1/state/#", qos=0)
                odom = probe.publisher(Odometry, "/wl/odom")
                camera = probe.publisher(CompressedImage, "/wl/camera")
                frame = CompressedImage(format="jpeg", data=bytes(20_000))
                # the FIFO control needs little time to show the backlog: 1.6 Mbit/s into 256 kbit/s
                measure = MEASURE if conflate else MEASURE / 4
                end = time.monotonic() + 3 + measure
                began = time.monotonic()
                for _ in paced(0.1, within=3 + measure):  # 10 Hz poses and camera frames
                    if time.monotonic() > end - measure:
                        recording.set()
                    msg = Odometry()
                    now = time.time()
                    msg.header.stamp.sec, msg.header.stamp.nanosec = int(now), int((now % 1) * 1e9)
                    odom.publish(msg)
                    camera.publish(frame)
                # FIFO: the poses sent while recording are still queued behind frames; they arrive (stale) later
                with contextlib.suppress(AssertionError):  # the check below says why none came
                    wait_until("a recorded pose at the phone", lambda: ages, timeout=15, period=0.1)
            finally:
                probe.close()
        broker_log = broker.output()
    broker_lines = [line for line in broker_log.splitlines() if "slow consumer" in line or "bob" in line]
    why = (f"poses arrived at {arrivals[:40]} s (the flood {3 + MEASURE:g} s from 0, recorded from 3); broker: "
           f"{broker_lines[-8:]}; link: {(tmp_path / 'link.log').read_text(errors='replace')[-600:]!r}")
    assert ages, f"no pose reached the phone; {why}"
    if conflate:
        assert _quantile(ages, 0.9) < 1.5, f"poses to a slow viewer are stale: p90 {_quantile(ages, 0.9):.2f} s; {why}"
        assert len(ages) >= 2 * MEASURE, f"only {len(ages)} poses in {MEASURE} s; {why}"
        assert "state topics are conflated" in broker_log
    else:
        assert _quantile(ages, 0.9) > 1.5, f"FIFO to a slow viewer kept poses fresh? p90 {_quantile(ages, 0.9):.2f}"


def test_buffered_events_survive_a_broker_outage_and_a_bridge_restart(tmp_path) -> None:
    """A ``buffer: disk`` rule: what ROS publishes while the broker is down (across a restart of the bridge,
    too) reaches the viewer after the broker returns, every message, the buffered ones oldest first.

    The bridge reaches the broker through a door (a plain TCP proxy) that the test opens again only once the viewer
    is subscribed: a bridge that reconnected first sent its disk buffer's oldest records to no subscriber (a clean
    run lost events 1 and 2 that way: the spool held and sent all thirty)."""
    from std_msgs.msg import String

    rules = RULES.replace("    rules: &rules\n", "    rules: &rules\n      - {direction: ros_to_mqtt, ros_topic: "
                          "/wl/events, ros_type: std_msgs/msg/String, mqtt_topic: state/events, mqtt_qos: 1, "
                          "buffer: disk}\n")
    spool_dir = tmp_path / "spool"
    fleet = write_fleet(tmp_path, edit=lambda text: text.replace("    rules: &rules\n", rules, 1).replace(
        "      keepalive: 2\n", f"      keepalive: 2\n      buffer_dir: {spool_dir}\n", 1))
    bridge_cmd = ["-m", "roslink_mqtt.bridge.main", "--config", str(fleet), "--robot", "turtle1"]
    door_port = free_port()
    door = ["-m", "roslink_mqtt.shaped_link", "--listen", f"127.0.0.1:{door_port}", "--to", "", "--delay-ms", "0",
            "--jitter-ms", "0"]
    received: list[int] = []
    probe = RosProbe()
    try:
        events = probe.publisher(String, "/wl/events")
        n = 0

        def publish(count: int) -> None:
            nonlocal n
            for _ in paced(0.05, count=count):
                events.publish(String(data=str(n)))
                n += 1

        def matched() -> None:
            wait_until("the bridge's subscription to /wl/events", lambda: events.get_subscription_count() >= 1,
                       timeout=20)

        with EmbeddedBrokerProcess(tmp_path, fleet) as broker:
            url = ["--url", f"mqtt://127.0.0.1:{door_port}"]
            door[door.index("--to") + 1] = f"127.0.0.1:{broker.port}"
            with run(door, tmp_path / "door1.log"), \
                    run(bridge_cmd + url, tmp_path / "bridge1.log", bridge_env("turtle1")) as bridge:
                wait_for_port(door_port, 10)
                with TestClient(broker.port, "bob", "bob-demo") as bob:
                    assert bob.connect() == 0
                    bob.subscribe("roslink/turtle1/state/events", qos=1)
                    matched()
                    deadline = time.monotonic() + 20
                    while not bob.drain(0.3) and time.monotonic() < deadline:  # until the bridge is online
                        publish(1)
                first_offline = n
                broker.stop()
                publish(20)  # the broker is down: kept on disk
                bridge.stop()
            with run(bridge_cmd + url, tmp_path / "bridge2.log", bridge_env("turtle1")):
                matched()
                publish(10)  # the new bridge, still without a broker, keeps these too
                last_offline = n - 1
                broker.start()
                with TestClient(broker.port, "bob", "bob-demo") as bob:
                    bob.client.on_message = lambda _c, _u, m: received.append(int(orjson.loads(m.payload)["data"]))
                    assert bob.connect(timeout=10) == 0
                    bob.subscribe("roslink/turtle1/state/events", qos=1)
                    with run(door, tmp_path / "door2.log"):  # only now may the bridge reach the broker
                        for _ in paced(0.15, within=20, stop=lambda: set(range(first_offline, last_offline + 1))
                                       <= set(received)):
                            publish(1)  # live events go on meanwhile
    finally:
        probe.close()
    buffered = [i for i in received if first_offline <= i <= last_offline]
    missing = sorted(set(range(first_offline, last_offline + 1)) - set(buffered))
    assert not missing, f"lost while the broker was down: {missing} (got {received})"
    assert buffered == sorted(buffered), f"buffered events out of order: {buffered}"
    assert list(spool_dir.glob("turtle1-*.spool")), "the disk buffer was not where bridge.buffer_dir says"


def test_an_emergency_stop_overtakes_a_flooded_downlink(tmp_path) -> None:
    """The robot's downlink is 64 kbit/s and alice floods it with log lines (160 kB/s): an ordinary command she
    sends waits behind them, her emergency stop does not (the bridge reads stops on a connection of their own)."""
    from rclpy.qos import DurabilityPolicy, QoSProfile
    from std_msgs.msg import Bool, String

    fleet = write_fleet(tmp_path)
    with EmbeddedBrokerProcess(tmp_path, fleet) as broker:
        link_port = free_port()
        with run(["-m", "roslink_mqtt.shaped_link", "--listen", f"127.0.0.1:{link_port}", "--to",
                  f"127.0.0.1:{broker.port}", "--delay-ms", "20", "--jitter-ms", "0", "--up-kbit", "1000",
                  "--down-kbit", "64"], tmp_path / "link.log"), \
                run(["-m", "roslink_mqtt.bridge.main", "--config", str(fleet), "--robot", "turtle1", "--url",
                     f"mqtt://127.0.0.1:{link_port}"], tmp_path / "bridge.log", bridge_env("turtle1")), \
                TestClient(broker.port, "alice", "alice-demo", operator=True) as alice:
            probe = RosProbe()
            try:
                stops = probe.watch(Bool, "/emergency_stop", QoSProfile(depth=10,
                                                                       durability=DurabilityPolicy.TRANSIENT_LOCAL))
                modes = probe.watch(String, "/mode")
                assert alice.connect() == 0
                alice.subscribe("roslink/turtle1/heartbeat")
                alice.wait_for(lambda m: m.topic.endswith("/heartbeat") and not m.retain, timeout=30)
                stops.wait_matched(20)
                modes.wait_matched(20)
                # the path works when the link is idle; sent again while the bridge's /mode publisher has not yet
                # matched the probe (DDS matches each side on its own: a first message can miss a new subscriber)
                for _attempt in range(10):
                    alice.publish("roslink/turtle1/from/alice/cmd/set_mode", {"mode": "GUIDED"}, qos=1)
                    try:
                        modes.wait_for(lambda m: m.data == "GUIDED", timeout=1.0)
                        break
                    except TimeoutError:
                        continue
                else:
                    raise AssertionError("set_mode never reached /mode over the idle link")
                flooding = threading.Event()
                flooding.set()

                def flood() -> None:
                    line = orjson.dumps({"level": 20, "msg": "x" * 8000})
                    for _ in paced(0.05, within=60, stop=lambda: not flooding.is_set()):  # (within: a bound)
                        alice.client.publish("roslink/turtle1/from/alice/log/flood", line, qos=0)

                flooder = threading.Thread(target=flood, daemon=True)
                flooder.start()
                stays("alice's flood", flooder.is_alive, seconds=1.5)  # a queue builds up in front of the robot
                sent = time.monotonic()
                alice.publish("roslink/turtle1/from/alice/cmd/set_mode", {"mode": "AUTO"}, qos=1)
                alice.publish("roslink/turtle1/from/alice/cmd/emergency_stop", {}, qos=1)
                stopped_at, _ = stops.wait_for(lambda m: m.data, timeout=10, after=sent)
                try:
                    mode_at, _ = modes.wait_for(lambda m: m.data == "AUTO", timeout=3, after=sent)
                except TimeoutError:
                    mode_at = float("inf")
                flooding.clear()
                flooder.join(2)
            finally:
                probe.close()
    stop_delay, mode_delay = stopped_at - sent, mode_at - sent
    assert stop_delay < 1.5, f"the emergency stop took {stop_delay:.2f} s through the flooded downlink"
    assert mode_delay > stop_delay + 1.0, (f"the ordinary command was not held up ({mode_delay:.2f} s vs the stop's "
                                           f"{stop_delay:.2f} s): the flood did not congest the downlink")


@pytest.mark.parametrize("mode", ["scheduled", "fifo"])
def test_a_disk_backlog_drains_behind_live_poses_on_a_thin_uplink(tmp_path, mode: str) -> None:
    """The robot's link (64 kbit/s) goes down for a while; a ``buffer: disk`` rule keeps 50 kB of events meanwhile.
    When the link returns the backlog takes seconds of link time, and it drains *behind* live data: the viewer's
    poses are fresh and keep their rate while the backlog is still crossing, and every buffered event still arrives,
    oldest first. In both uplink modes: with ``fifo`` poses and the backlog share one connection, and only the
    drain's pacing keeps the backlog from sitting in front of them (handed at once, poses arrive 4 s old)."""
    from nav_msgs.msg import Odometry
    from std_msgs.msg import String

    uplink_kbit, event_bytes, offline_events = 64, 1000, 50  # 50 kB ≈ 6 s of the uplink
    fleet = _disk_events_fleet(tmp_path, keepalive=2, mode=mode)
    poses: list[tuple[float, float]] = []  # (arrival, age)
    events: list[tuple[float, int]] = []  # (arrival, index)
    offline = threading.Event()

    def on_message(_c, _u, m) -> None:
        now = time.time()
        leaf = m.topic.rsplit("/", 1)[-1]
        if leaf == "pose":
            poses.append((now, now - orjson.loads(m.payload)["payload"]["time_boot_ms"] / 1000))
        elif leaf == "events":
            events.append((now, int(orjson.loads(m.payload)["data"][:8])))
        elif leaf == "heartbeat" and m.payload and orjson.loads(m.payload)["payload"]["system_status"] == 8:
            offline.set()  # the bridge's last will: the broker saw the robot's connection go

    link_port = free_port()
    link_cmd = ["-m", "roslink_mqtt.shaped_link", "--listen", f"127.0.0.1:{link_port}", "--to", "", "--delay-ms",
                "20", "--jitter-ms", "0", "--up-kbit", str(uplink_kbit), "--down-kbit", "512"]
    probe = RosProbe()
    stop = threading.Event()
    try:
        odom = probe.publisher(Odometry, "/wl/odom")
        event_pub = probe.publisher(String, "/wl/events")

        def live_poses() -> None:
            while not stop.wait(0.1):
                msg = Odometry()
                now = time.time()
                msg.header.stamp.sec, msg.header.stamp.nanosec = int(now), int((now % 1) * 1e9)
                odom.publish(msg)

        with EmbeddedBrokerProcess(tmp_path, fleet) as broker, TestClient(broker.port, "bob", "bob-demo") as bob:
            link_cmd[link_cmd.index("--to") + 1] = f"127.0.0.1:{broker.port}"
            assert bob.connect() == 0
            bob.client.on_message = on_message
            bob.subscribe("roslink/turtle1/state/#", qos=1)
            bob.subscribe("roslink/turtle1/heartbeat", qos=1)
            with run(["-m", "roslink_mqtt.bridge.main", "--config", str(fleet), "--robot", "turtle1", "--url",
                      f"mqtt://127.0.0.1:{link_port}"], tmp_path / "bridge.log", bridge_env("turtle1")):
                threading.Thread(target=live_poses, daemon=True).start()
                with run(link_cmd, tmp_path / "link1.log"):
                    _first_pose(poses, tmp_path / "bridge.log")
                assert offline.wait(15), "the broker never published the bridge's will when its link went"
                for n in paced(0.01, count=offline_events):  # the link is down: kept on disk
                    event_pub.publish(String(data=f"{n:<8}" + "e" * (event_bytes - 8)))
                wait_until("every event in the bridge's disk buffer", lambda: _spooled(tmp_path / "spool")
                           >= offline_events)
                with run(link_cmd, tmp_path / "link2.log"):
                    back = time.time()
                    with contextlib.suppress(AssertionError):  # the checks below say which are missing
                        wait_until("every buffered event at the viewer",
                                   lambda: len({n for _, n in events}) >= offline_events, timeout=60, period=0.2)
    finally:
        stop.set()
        probe.close()
    received = [n for _, n in events]
    assert sorted(set(received)) == list(range(offline_events)), f"lost while the link was down: {received}"
    assert received == sorted(received), f"buffered events out of order: {received}"
    drained = max(t for t, _ in events)
    first_pose = min(t for t, _ in poses if t > back)
    assert drained - first_pose > 3.0, (f"the backlog took {drained - first_pose:.1f} s after the first live pose: "
                                        "too short to show which goes first")
    during = [age for t, age in poses if first_pose <= t <= drained]
    assert len(during) >= 4 * (drained - first_pose), (  # the demo's 10 Hz global_motion: at least 4 Hz of it
        f"{len(during)} poses in the {drained - first_pose:.1f} s the backlog took: it held live data back")
    # the failure this guards against leaves poses ~4 s old (the backlog in front of them); a loaded CI machine has
    # shown 1.7-2.1 s with the drain paced as it should be: the line sits between the two
    assert _quantile(during, 0.9) < 3.0, f"poses arrived stale while the backlog drained: {sorted(during)[-5:]}"
    assert first_pose - back < 10.0, f"the first live pose took {first_pose - back:.1f} s after the link returned"
    if mode == "scheduled":
        # the description (several kB) once went out on the command connection at each connect: at 64 kbit/s its
        # keep-alive ran out behind it, it reconnected, sent it again (3 drops in 3 runs; a run in CI: 4, poses 3.8 Hz)
        dropped = [line for line in (tmp_path / "bridge.log").read_text().splitlines() if "Keep alive" in line]
        assert not dropped, f"a connection lost its keep-alive while the backlog drained: {dropped}"


SNAPSHOT_KBIT = 256


def _thin_link_snapshot(tmp_path, *, break_at: float | None = None) -> tuple:
    """The bridge keeps 4 s of a 3 kB log line at 20 Hz and the poses (10 Hz) and reaches the broker over a
    256 kbit/s uplink; alice asks for them all while bob watches the poses. ``break_at``: s after the first chunk
    came, the link goes for a second (its process killed and started again), so every connection of the bridge
    drops. (Counted from the request, a busy machine's bridge once took longer than that to write the file, and
    the link was back before the first chunk left.)
    Returns (the snapshot, seconds it took, the poses' ages while it crossed, the file's message count, and the
    seconds from the request to the outage: None without one)."""
    from mcap.reader import make_reader
    from nav_msgs.msg import Odometry
    from std_msgs.msg import String

    snapshot = ("    snapshot:\n      topics: [/wl/odom, {ros_topic: /wl/log, ros_type: std_msgs/msg/String}]\n"
                "      seconds: 4\n")
    fleet = write_fleet(tmp_path, edit=lambda text: re.sub(r"    snapshot:\n(      .*\n|        .*\n)+", snapshot,
                                                           text.replace("    rules: &rules\n", RULES, 1), count=1))
    ages: list[float] = []
    reports: list[str] = []  # the bridge's state/link while the snapshot crossed: shown when a line is missed
    env = {**bridge_env("turtle1"), "STATE_DIRECTORY": str(tmp_path / "state")}  # the failsafe's own snapshots
    with EmbeddedBrokerProcess(tmp_path, fleet) as broker:
        link_port = free_port()
        with run(["-m", "roslink_mqtt.shaped_link", "--listen", f"127.0.0.1:{link_port}", "--to",
                  f"127.0.0.1:{broker.port}", "--delay-ms", "20", "--jitter-ms", "0", "--up-kbit",
                  str(SNAPSHOT_KBIT), "--down-kbit", "1024"], tmp_path / "link.log") as link, \
                run(["-m", "roslink_mqtt.bridge.main", "--config", str(fleet), "--robot", "turtle1", "--url",
                     f"mqtt://127.0.0.1:{link_port}"], tmp_path / "bridge.log", env), \
                TestClient(broker.port, "bob", "bob-demo") as bob:
            probe = RosProbe()
            fetching, first_chunk = threading.Event(), threading.Event()
            killed: list[float] = []

            def on_message(_c, _u, m) -> None:
                if fetching.is_set() and m.topic.endswith("/state/pose"):
                    ages.append(time.time() - orjson.loads(m.payload)["payload"]["time_boot_ms"] / 1000)
                elif fetching.is_set() and m.topic.endswith("/state/link"):
                    reports.append(_link_summary(LinkReport.from_json(m.payload)))

            def break_link() -> None:
                if first_chunk.wait(60) and not stop.wait(break_at):
                    killed.append(time.monotonic())
                    link.kill()
                    time.sleep(1.0)  # the outage itself: its length is the scenario, there is nothing to wait for
                    link.spawn()

            stop = threading.Event()
            try:
                assert bob.connect() == 0
                bob.client.on_message = on_message
                bob.subscribe("roslink/turtle1/state/pose", qos=0)
                bob.subscribe("roslink/turtle1/state/link", qos=0)
                odom, lines = probe.publisher(Odometry, "/wl/odom"), probe.publisher(String, "/wl/log")

                def flood() -> None:
                    n = 0
                    while not stop.wait(0.05):  # the log at 20 Hz (only in the ring buffer), poses at 10 Hz
                        n += 1
                        lines.publish(String(data=secrets.token_urlsafe(2250)))  # 3 kB zstd cannot shrink much
                        if n % 2:
                            continue
                        msg = Odometry()
                        now = time.time()
                        msg.header.stamp.sec, msg.header.stamp.nanosec = int(now), int((now % 1) * 1e9)
                        odom.publish(msg)

                flooder = threading.Thread(target=flood, daemon=True)
                flooder.start()
                with RobotClient("alice", "alice-demo", url=f"mqtt://127.0.0.1:{broker.port}") as alice:
                    alice.wait_for_robot("turtle1", timeout=30)
                    stays("the flood", flooder.is_alive, seconds=4.5)  # the ring buffer fills
                    fetching.set()
                    if break_at is not None:
                        threading.Thread(target=break_link, daemon=True).start()
                    started = time.monotonic()
                    snap = alice.snapshot("turtle1", 4, path=tmp_path / "thin.mcap", timeout=120, stall=3.0,
                                          on_progress=lambda _chunks, _of: first_chunk.set())
                    took = time.monotonic() - started
                    fetching.clear()
            finally:
                stop.set()
                probe.close()
    with (tmp_path / "thin.mcap").open("rb") as f:
        stats = make_reader(f).get_summary().statistics
    return (snap, took, ages, stats.message_count, (killed[0] - started if killed else None),
            "; ".join(reports[-6:]) or "no state/link report")


def _link_summary(report: LinkReport) -> str:
    """One state/link report in a line: what a failed line about the uplink's speed is explained by."""
    path = report.path
    streams = ", ".join(f"{name} {s.sent_hz}/{s.offered_hz} Hz {s.kbit_s} kbit/s"
                        for name, s in report.streams.items() if s.offered_hz or s.sent_hz)
    seen = (f"path base {path.base_ms} rtt {path.rtt_ms} queue {path.queue_ms} ms rate {path.rate_kbit_s} kbit/s "
            f"cuts {path.cuts} steering {path.steering}") if path is not None else "no path"
    return (f"[rate {report.rate_kbit_s} kbit/s measured {report.measured} budget {report.budget_bytes} B; {seen}; "
            f"{streams}]")


def test_a_snapshot_crosses_a_thin_uplink_intact_while_poses_stay_fresh(tmp_path) -> None:
    """≈ 200 kB, eight seconds of the whole link: the file arrives whole (its SHA-256 checked), and the poses stay
    fresh meanwhile: the chunks go at bulk priority, one at a time, on a connection of their own. (Handing every chunk
    to the command connection at once — the naive way — fails this test: tried by hand.)"""
    snap, took, ages, messages, _, link = _thin_link_snapshot(tmp_path)
    assert messages == snap.messages >= 100, snap.messages  # 4 s of 20 + 10 Hz, less the window's cut
    assert len(snap.data) > 150_000, f"{len(snap.data)} bytes"  # seconds of the link: long enough to show the poses
    # held up (or not)
    kbit = len(snap.data) * 8 / 1000 / took
    record_measurement(f"snapshot over {SNAPSHOT_KBIT} kbit/s ({len(snap.data) // 1000} kB, {kbit:.0f} kbit/s)", took,
                       60.0)
    assert ages and _quantile(ages, 0.9) < 1.5, (f"poses went stale during the snapshot: p90 "
                                                 f"{_quantile(ages, 0.9):.2f}; uplink: {link}")
    # 10 Hz offered; ~9.9 Hz arrive as a rule. Known defect (issue 42): in 2 of ~16 clean-clone runs the uplink's
    # estimate fell to 18–132 kbit/s on this 256 kbit/s link while its probes' round trip stayed at ~640 ms
    # (base 41 ms), and the poses came at 4.1 and 4.5 Hz while the snapshot took 22–24 s. The line catches a
    # collapse; the rate is in the run's summary so that the trap shows when it happens.
    record_measurement("snapshot over 256 kbit/s: period of the poses meanwhile (10 Hz offered)",
                       took / max(1, len(ages)), 1 / 3.0)
    assert len(ages) >= 3 * took, f"only {len(ages)} poses in {took:.1f} s; uplink: {link}"


def test_a_snapshot_broken_by_a_link_outage_arrives_whole(tmp_path) -> None:
    """The link goes for a second in the middle of the transfer: every connection of the bridge drops and comes
    back, and the file still arrives whole, its SHA-256 checked. A chunk lost with the connection is asked again by
    the SDK from its first missing chunk (a resume); a chunk paho had in flight it sends again itself (QoS 1), so an
    outage may cost no chunk at all (a clean-clone run beside a CPU hog: no resume, the file whole; the test asked
    for a resume then and failed)."""
    snap, took, _ages, messages, broken, _link = _thin_link_snapshot(tmp_path, break_at=1.0)
    assert broken is not None and broken < took, f"the outage ({broken} s) came after the transfer ({took:.1f} s)"
    log = (tmp_path / "bridge.log").read_text(errors="replace")
    assert "lost the broker" in log, "the bridge's connections never dropped: the transfer was not broken"
    assert messages == snap.messages >= 100, snap.messages
    record_measurement(f"snapshot over {SNAPSHOT_KBIT} kbit/s with a 1 s outage ({snap.resumes} resumes)", took, 120.0)

