"""Zenoh as a peer row for bench/weak_link.py: the same simulated robot's odometry and scan, sent with Zenoh's
priorities across the same link to a Zenoh router on the far side, and timed there.

    .venv/bin/python bench/zenoh_peer.py --robot --connect tcp/127.0.0.1:PORT    (the robot's side; until SIGINT)

What stands for a user's Zenoh deployment. The Zenoh way to put a ROS 2 robot on the Internet is
``zenoh-bridge-ros2dds`` on the robot and a Zenoh router in the cloud; the bridge is a Rust binary that is not on
PyPI, so the robot's side here is a small rclpy process doing what that bridge does with the settings a user would
pick for a thin uplink (its ``pub_priorities`` and ``pub_max_frequencies``): each ROS message is taken as its
serialized CDR bytes (no conversion), odometry is thinned to 10 Hz (our rows' global_motion rate), and both
streams are put with eclipse-zenoh (PyPI, the same Rust core as the bridge) —

* odometry at priority ``INTERACTIVE_HIGH``, ``express`` (sent at once, not batched);
* the scan at ``DATA_LOW``;
* both with ``CongestionControl.DROP``: a message that finds Zenoh's transmission queue full is dropped rather than
  waited for, the setting that keeps data fresh on a link that cannot carry it all.

The far side is a Zenoh router (eclipse-zenoh's session in ``router`` mode, in the bench's process) listening on
loopback; the robot's session is a client that dials it through the shaped link, so the robot's uplink is the
link's up direction, as for the MQTT bridge. A message's age is its arrival at the router's subscriber minus the
``header.stamp`` read from the CDR bytes (one wall clock: everything runs on this machine). Multicast scouting is
off on both sides: nothing leaves the machine.
"""

from __future__ import annotations

import argparse
import json
import signal
import struct
import sys
import threading
import time
from typing import Any

ODOM_TOPIC, SCAN_TOPIC = "/odom", "/scan"
KEY_ODOM, KEY_SCAN = "turtle1/odom", "turtle1/scan"
ODOM_RATE = 10.0  # Hz: what reaches the far side, like our rows' global_motion


def locator(port: int) -> str:
    """The Zenoh endpoint of a TCP port on loopback (a Zenoh locator, not a URL)."""
    return f"tcp/127.0.0.1:{port}"


def config(mode: str, *, listen: str | None = None, connect: str | None = None) -> Any:
    """A Zenoh configuration on loopback endpoints only, with multicast scouting off."""
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode))
    conf.insert_json5("scouting/multicast/enabled", "false")
    if listen:
        conf.insert_json5("listen/endpoints", json.dumps([listen]))
    if connect:
        conf.insert_json5("connect/endpoints", json.dumps([connect]))
    return conf


def cdr_stamp(data: bytes) -> float | None:
    """``header.stamp`` (s) of a serialized message whose first field is a ``std_msgs/Header``, or None.

    CDR: a 4-byte encapsulation header (its second byte 1 for little-endian), then the stamp's int32 seconds and
    uint32 nanoseconds."""
    if len(data) < 12:
        return None
    order = "<" if data[1] & 1 else ">"
    sec, nanosec = struct.unpack_from(order + "iI", data, 4)
    return sec + nanosec * 1e-9


class Throttle:
    """At most ``rate`` messages a second, the first of each interval (a small slack for a source at twice it)."""

    def __init__(self, rate: float) -> None:
        self.interval, self.last = 1.0 / rate, -1e9

    def admit(self, now: float) -> bool:
        if now - self.last < self.interval * 0.9:
            return False
        self.last = now
        return True


# -- the far side: a Zenoh router with the viewer's subscriptions ----------------------------------------------
class ZenohViewer:
    """A Zenoh router listening on ``tcp/127.0.0.1:port`` whose subscribers record (arrival on time.monotonic(),
    age) per stream: ``timed["odom"]``, ``timed["scan"]``."""

    def __init__(self, port: int) -> None:
        import zenoh

        self.timed: dict[str, list[tuple[float, float]]] = {"odom": [], "scan": []}
        self._lock = threading.Lock()
        self.first = threading.Event()
        self.session = zenoh.open(config("router", listen=locator(port)))
        self._subs = [self.session.declare_subscriber(KEY_ODOM, lambda s: self._record("odom", s)),
                      self.session.declare_subscriber(KEY_SCAN, lambda s: self._record("scan", s))]

    def _record(self, stream: str, sample: Any) -> None:
        arrived, monotonic = time.time(), time.monotonic()
        stamp = cdr_stamp(bytes(sample.payload.to_bytes()))
        if stamp is None:
            return
        with self._lock:
            self.timed[stream].append((monotonic, arrived - stamp))
        if stream == "odom":
            self.first.set()

    def between(self, stream: str, start: float, end: float) -> list[tuple[float, float]]:
        with self._lock:
            return [(t, age) for t, age in self.timed[stream] if start <= t < end]

    def clear(self) -> None:
        with self._lock:
            for stream in self.timed.values():
                stream.clear()
        self.first.clear()

    def close(self) -> None:
        for sub in self._subs:
            sub.undeclare()
        self.session.close()


# -- the robot's side (a child process, on the sim's ROS graph) ------------------------------------------------
def robot(connect: str) -> int:
    """Forward the sim's odometry (thinned to ODOM_RATE) and scan to the router at ``connect``, until SIGINT/SIGTERM."""
    import rclpy
    import zenoh
    from nav_msgs.msg import Odometry
    from rclpy.qos import qos_profile_sensor_data
    from rclpy.signals import SignalHandlerOptions
    from sensor_msgs.msg import LaserScan

    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    session = zenoh.open(config("client", connect=connect))
    odom = session.declare_publisher(KEY_ODOM, priority=zenoh.Priority.INTERACTIVE_HIGH, express=True,
                                     congestion_control=zenoh.CongestionControl.DROP)
    scan = session.declare_publisher(KEY_SCAN, priority=zenoh.Priority.DATA_LOW,
                                     congestion_control=zenoh.CongestionControl.DROP)
    throttle = Throttle(ODOM_RATE)
    node = rclpy.create_node("zenoh_peer_robot")

    def on_odom(raw: bytes) -> None:
        if throttle.admit(time.monotonic()):
            odom.put(raw)

    node.create_subscription(Odometry, ODOM_TOPIC, on_odom, 10, raw=True)
    # the sim publishes its scan best-effort (sensor data): a reliable subscription would never match it
    node.create_subscription(LaserScan, SCAN_TOPIC, scan.put, qos_profile_sensor_data, raw=True)
    print("zenoh peer: forwarding /odom and /scan", flush=True)
    try:
        while not stop.is_set():
            rclpy.spin_once(node, timeout_sec=0.1)
    finally:
        node.destroy_node()
        session.close()
        rclpy.try_shutdown()
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--robot", action="store_true", help="run the robot's side")
    p.add_argument("--connect", required=True, help="the router's endpoint, e.g. tcp/127.0.0.1:7447")
    args = p.parse_args(argv)
    if not args.robot:
        p.error("only --robot runs from the command line (the far side is ZenohViewer, in bench/weak_link.py)")
    return robot(args.connect)


if __name__ == "__main__":
    sys.exit(main())
