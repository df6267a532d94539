"""The bridge follows the fleet file on SIGHUP, as the broker does: grants given and taken apply at once.

Real processes: the embedded broker, the simulated robot and the bridge, all reading one fleet file
that the test edits.
"""

from __future__ import annotations

import signal
import threading
import time
from pathlib import Path

import pytest

from tests.support.broker_setup import write_fleet
from tests.support.embedded_broker import EmbeddedBrokerProcess
from tests.support.measure import record_measurement
from tests.support.mqtt_client import TestClient
from tests.support.procs import bridge_args, bridge_env, run
from tests.support.ros import RosProbe
from tests.support.waits import never, paced, wait_until

pytestmark = pytest.mark.timeout(120)

CAROL_GRANTS = "      - {key: demo-key-turtle2, role: operator}\n  admin:"
ALICE_GRANT = "    grants:\n      - {key: demo-key-turtle1, role: operator}\n  bob:"


def _wait_for_log(proc, text: str, count: int, timeout: float = 10.0) -> None:
    try:
        wait_until(f"{text!r} in the log", lambda: proc.output().count(text) >= count, timeout=timeout)
    except AssertionError as err:
        raise AssertionError(f"no {text!r} in the log:\n{proc.output()[-3000:]}") from err


def _stream(client: TestClient, user: str, lx: float, stop: threading.Event) -> threading.Thread:
    def loop() -> None:
        for _ in paced(0.05, within=120, stop=stop.is_set):  # 120 s: the test's own timeout
            client.publish(f"roslink/turtle1/from/{user}/cmd/twist", {"lx": lx}, qos=0)
    thread = threading.Thread(target=loop, daemon=True)
    thread.start()
    return thread


def test_sighup_gives_and_takes_operator_grants(tmp_path: Path) -> None:
    from geometry_msgs.msg import Twist

    fleet = write_fleet(tmp_path, read_only_service=False)
    text = fleet.read_text()
    assert text.count(CAROL_GRANTS) == 1 and text.count(ALICE_GRANT) == 1, "demo robots.yaml changed"
    probe = RosProbe()
    cmd_vel = probe.watch(Twist, "/cmd_vel")
    try:
        with EmbeddedBrokerProcess(tmp_path, fleet) as broker, \
                run(["-m", "roslink_mqtt.sim"], tmp_path / "sim.log"), \
                run(bridge_args("turtle1", broker.port, config=fleet), tmp_path / "bridge.log",
                    bridge_env("turtle1")) as bridge, \
                TestClient(broker.port, "admin", "admin-demo") as admin, \
                TestClient(broker.port, "carol", "carol-demo", operator=True) as carol, \
                TestClient(broker.port, "alice", "alice-demo", operator=True) as alice:
            for client in (admin, carol, alice):
                assert client.connect() == 0
            admin.subscribe("roslink/turtle1/heartbeat")
            admin.wait_for(lambda m: m.json()["payload"]["system_status"] == 4, timeout=20)
            admin.subscribe("roslink/turtle1/state/ack")
            alice.subscribe("roslink/turtle1/to/alice/error")

            # 1. carol gets turtle1: broker and bridge reload, and her twist drives the robot
            fleet.write_text(text.replace(CAROL_GRANTS, "      - {key: demo-key-turtle1, role: operator}\n"
                                          + CAROL_GRANTS))
            broker.signal(signal.SIGHUP)
            _wait_for_log(broker, "reloaded", 1)
            bridge.signal(signal.SIGHUP)
            _wait_for_log(bridge, "reloaded", 1)
            stop_carol = threading.Event()
            t0 = time.monotonic()
            streamer = _stream(carol, "carol", 0.21, stop_carol)
            try:
                cmd_vel.wait_for(lambda m: m.linear.x == pytest.approx(0.21), after=t0, timeout=10)
            finally:
                stop_carol.set()
                streamer.join()
            assert "carol:operator" in bridge.output()
            carol.publish("roslink/turtle1/from/carol/control/release", b"")  # alice drives next

            # 2. alice loses turtle1 while she drives: only the bridge reloads (the broker still lets her
            #    publish), so the stop below is the bridge's doing, not the broker's or the dead-man's
            stop_alice = threading.Event()
            t1 = time.monotonic()
            streamer = _stream(alice, "alice", 0.33, stop_alice)
            try:
                cmd_vel.wait_for(lambda m: m.linear.x == pytest.approx(0.33), after=t1, timeout=10)
                fleet.write_text(fleet.read_text().replace(ALICE_GRANT, "    grants: []\n  bob:"))
                hup_at = time.monotonic()
                bridge.signal(signal.SIGHUP)
                stopped_at, _ = cmd_vel.wait_for(lambda m: m.linear.x == 0 and m.angular.z == 0, after=hup_at,
                                                 timeout=5)
                err = alice.wait_for(lambda m: "not an operator" in m.json().get("error", ""), timeout=5).json()
                never("alice's twists reaching the robot after the revocation",  # her stream goes on meanwhile
                      lambda: [m for _, m in cmd_vel.since(stopped_at + 0.1) if m.linear.x != 0], seconds=0.5)
            finally:
                stop_alice.set()
                streamer.join()
            record_measurement("bridge SIGHUP revokes the driving operator → stop", stopped_at - hup_at, 1.0)
            assert stopped_at - hup_at < 1.0  # the dead-man alone could not stop a live stream
            assert err["topic"] == "roslink/turtle1/from/alice/cmd/twist"
            late = [m for at, m in cmd_vel.since(stopped_at + 0.1) if m.linear.x != 0]
            assert not late, f"{len(late)} non-zero twists reached the robot after the revocation"
            ack = admin.wait_for(lambda m: m.topic.endswith("/state/ack")  # heartbeats arrive here too
                                 and "operator grant removed" in m.json()["payload"]["text"], timeout=5)
            assert "operator alice went away" in ack.json()["payload"]["text"]

            # 3. a broken file keeps the running grants
            fleet.write_text("robots: [\n")
            bridge.signal(signal.SIGHUP)
            _wait_for_log(bridge, "reload failed, keeping the current grants", 1)
            assert bridge.popen.poll() is None
    finally:
        probe.close()
