"""A fleet of simulated robots for the dashboard's fleet tests and ``bench/dashboard_soak.py``: MQTT only, no ROS.

Each robot sends what a bridge sends a dashboard: a retained heartbeat at 1 Hz, ``state/global_motion`` at 10 Hz
(driving a circle around its own origin), ``state/robot_status`` (battery) and ``state/link`` (its uplink report)
at 1 Hz, a GPS fix at 1 Hz for the first three, and the retained access reports of the fleet's users. Each robot
has its own MQTT connection and login, as a bridge has (one thread publishes for all of them).

Knobs for the tests: a robot's battery, its link quality, and ``silence(name)``: its heartbeats stop (the page
must call it stale), ``failsafe(name)``: a failsafe notice on its ``state/ack``.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from roslink_mqtt.protocol import Envelope, encode
from roslink_mqtt.protocol.messages import SPECS
from roslink_mqtt.topics import TopicTree, Verb
from tests.support.mqtt_client import TestClient

PASSWORD = "sim-fleet-demo"  # every login of the simulated fleet (the tests are not about logins)
PREFIX = "roslink"
TREE = TopicTree(PREFIX)
MESSAGE_IDS = {s.name: s.as_data()["id"] for s in SPECS}
GPS_ORIGIN = (48.1372, 11.5755)  # the first three robots report GPS fixes around here
GPS_ROBOTS = 3


def robot_name(i: int) -> str:
    return f"sim{i + 1:02d}"


def write_sim_fleet(path: Path, robots: int, port: int, ws_port: int) -> Path:
    """``robots`` robots; users ``ops`` (operator of all), ``watch`` (viewer of all) and ``admin``."""
    from roslink_mqtt.config import load_fleet
    from roslink_mqtt.config.passwords import hash_password

    hashed = hash_password(PASSWORD, iterations=1000)
    names = [robot_name(i) for i in range(robots)]
    data: dict[str, Any] = {
        "prefix": PREFIX,
        "broker": {"host": "127.0.0.1", "port": port, "ws_port": ws_port},
        "robots": {n: {"system_id": i + 1, "key": f"key-{n}", "type": "ground", "password": hashed}
                   for i, n in enumerate(names)},
        "users": {
            "ops": {"password": hashed, "grants": [{"key": f"key-{n}", "role": "operator"} for n in names]},
            "watch": {"password": hashed, "grants": [{"key": f"key-{n}", "role": "viewer"} for n in names]},
            "admin": {"password": hashed, "admin": True},
        },
    }
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    load_fleet(path)  # fail here, not in the broker
    return path


@dataclass
class SimRobot:
    name: str
    system_id: int
    battery: float = 80.0
    link_quality: float = 1.0  # the share of its offered messages its uplink carries
    silent: bool = False
    seq: int = 0
    phase: float = field(default=0.0)


class SimulatedFleet:
    """``robots`` simulated robots on the broker at ``port``, publishing from a thread until :meth:`stop`."""

    def __init__(self, port: int, robots: int = 10, *, session: int | None = None) -> None:
        self.robots = {robot_name(i): SimRobot(robot_name(i), i + 1, battery=90.0 - 7 * i, phase=i * 0.6)
                       for i in range(robots)}
        self.port = port
        self.session = session or int(time.time())
        self.clients = {name: TestClient(port, name, PASSWORD, client_id=f"{name}-sim-{time.monotonic_ns()}")
                        for name in self.robots}
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.sent = 0
        self.motion = True  # False: only the 1 Hz messages (heartbeat, battery, link, GPS), no positions

    # -- what one robot sends -------------------------------------------------------------------------------
    def _message(self, robot: SimRobot, name: str, payload: dict[str, Any]) -> bytes:
        robot.seq = (robot.seq + 1) % 2**32
        return encode(Envelope(MESSAGE_IDS[name], payload, robot.system_id, robot.seq))

    def _publish(self, topic: str, payload: bytes | dict[str, Any], retain: bool = False, qos: int = 0) -> None:
        self.clients[TREE.parse(topic).robot].publish(topic, payload, qos=qos, retain=retain)
        self.sent += 1

    def heartbeat(self, robot: SimRobot, status: int = 4) -> None:
        self._publish(TREE.heartbeat(robot.name), self._message(robot, "heartbeat", {
            "type": 1, "name": robot.name, "system_status": status, "owner_id": "", "mode": 2,
            "session": self.session}), retain=True)

    def access(self, robot: SimRobot) -> None:
        for user, role in (("ops", "operator"), ("watch", "viewer")):
            self._publish(TREE.user_topic(robot.name, user, Verb.ACCESS),
                          {"role": role, "services": [], "actions": [], "estop": True, "snapshot": False},
                          retain=True, qos=1)

    def _pose(self, robot: SimRobot, t: float) -> dict[str, Any]:
        radius = 1.0 + 0.5 * (robot.system_id - 1)  # each its own circle, at 0.5 m/s
        w = 0.5 / radius
        a = robot.phase + w * t
        return {"time_boot_ms": int(t * 1000) % 2**32, "x": radius * math.cos(a), "y": radius * math.sin(a),
                "z": 0.0, "vx": 0.5, "vy": 0.0, "vz": 0.0, "wx": 0.0, "wy": 0.0, "wz": w, "roll": 0.0, "pitch": 0.0,
                "yaw": a + math.pi / 2}

    def _slow(self, robot: SimRobot, t: float) -> None:
        """The 1 Hz messages: heartbeat, battery, link, GPS."""
        if not robot.silent:
            self.heartbeat(robot)
        self._publish(TREE.state(robot.name, "robot_status"), self._message(robot, "robot_status", {
            "voltage_battery": 11.0 + robot.battery / 50, "current_battery": 1.2,
            "battery_remaining": round(robot.battery)}), retain=True)
        offered = 10.0
        self._publish(TREE.state(robot.name, "link"), {
            "mode": "scheduled", "rate_kbit_s": 256.0 * robot.link_quality, "measured": robot.link_quality < 1,
            "budget_bytes": 8000, "rtt_ms": 40.0, "period": 1.0,
            "streams": {"global_motion": {"priority": 1, "latest_only": True, "offered_hz": offered,
                                          "sent_hz": offered * robot.link_quality, "superseded": 0, "dropped": 0,
                                          "kbit_s": 10.0}}}, retain=True)
        if robot.system_id <= GPS_ROBOTS:
            p = self._pose(robot, t)
            lat = GPS_ORIGIN[0] + (robot.system_id - 1) * 0.002 + p["y"] / 111_000
            lon = GPS_ORIGIN[1] + (robot.system_id - 1) * 0.002 + p["x"] / 74_000
            self._publish(TREE.state(robot.name, "gps_raw_info"), self._message(robot, "gps_raw_info", {
                "fix_type": 3, "lat": lat, "lon": lon, "alt": 520.0, "satellites_visible": 9}))

    def _run(self, seconds: float) -> None:
        t0 = time.monotonic()
        tick = 0
        while not self._stop.is_set() and time.monotonic() - t0 < seconds:  # bounded: at most `seconds`
            t = time.monotonic() - t0
            for robot in self.robots.values():
                if tick % 10 == 0:
                    self._slow(robot, t)
                if self.motion and not robot.silent:
                    self._publish(TREE.state(robot.name, "global_motion"),
                                  self._message(robot, "global_motion", self._pose(robot, t)))
            tick += 1
            self._stop.wait(max(0.0, t0 + tick * 0.1 - time.monotonic()))

    # -- control ----------------------------------------------------------------------------------------------
    def start(self, seconds: float = 900.0) -> SimulatedFleet:
        for name, client in self.clients.items():
            assert client.connect() == 0, f"{name}'s login was refused"
        for robot in self.robots.values():
            self.access(robot)
            self.heartbeat(robot)
        self._thread = threading.Thread(target=self._run, args=(seconds,), name="sim-fleet", daemon=True)
        self._thread.start()
        return self

    def silence(self, name: str) -> None:
        """The robot's heartbeats and positions stop (its link is down): the page must call it stale."""
        self.robots[name].silent = True

    def resume(self, name: str) -> None:
        self.robots[name].silent = False

    def failsafe(self, name: str, text: str) -> None:
        robot = self.robots[name]
        self._publish(TREE.state(robot.name, "ack"), self._message(robot, "ack", {
            "command": 0, "result": 3, "text": text, "command_sequence": 0}), qos=1)

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5)
        for robot in self.robots.values():  # leave nothing retained for the next test
            self._publish(TREE.heartbeat(robot.name), b"", retain=True, qos=1)
            for level in ("robot_status", "link"):
                self._publish(TREE.state(robot.name, level), b"", retain=True, qos=1)
            for user in ("ops", "watch"):
                self._publish(TREE.user_topic(robot.name, user, Verb.ACCESS), b"", retain=True, qos=1)
        time.sleep(0.3)
        for client in self.clients.values():
            client.close()

    def __enter__(self) -> SimulatedFleet:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
