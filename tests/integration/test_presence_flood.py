"""Issue 12 (5): heavy presence payloads from a viewer must not delay an operator's commands or stops.

Real processes: a broker, simulated robot, bridge. bob (a viewer) floods his own presence topic with
~3.9 MB JSON bodies that are expensive to parse, while alice drives at 10 Hz and then sends a zero twist.
Against Mosquitto (no per-topic size limit) the bridge itself must ignore the bodies unread; the embedded
broker may drop them before they reach the bridge, and the same bounds must hold either way.
Each twist carries its sequence number in ``az`` (milli-rad/s), so what reaches ``/cmd_vel`` tells which
command it was and how long it took. Figures go to the run's closing summary.
"""

from __future__ import annotations

import contextlib
import sys
import time
from contextlib import ExitStack

import orjson
import pytest

from tests.support.embedded_broker import EmbeddedBrokerProcess
from tests.support.fleet_brokers import fleet_password_file
from tests.support.marked_twists import MarkedTwists, nonzero
from tests.support.measure import record_measurement
from tests.support.mosquitto import MosquittoProcess
from tests.support.mqtt_client import TestClient
from tests.support.procs import bridge_args, bridge_env, run
from tests.support.ros import RosProbe
from tests.support.waits import never, paced

pytestmark = pytest.mark.timeout(90)

COMMAND_TIMEOUT = 1.0  # the demo fleet's bridge.command_timeout
FLOOD_BYTES = 3_900_000  # under the embedded broker's 4 MiB max_payload
FLOOD_COUNT, FLOOD_RATE = 40, 10.0  # messages, per second: faster than the old bridge could parse them
DELAY_BOUND = 1.5  # s: generous; the bridge itself drops motion that waited longer than command_timeout
TWIST = "roslink/turtle1/from/alice/cmd/twist"


def _flood_body() -> bytes:
    """Valid JSON that costs the most to parse per byte (many small objects); not a heartbeat."""
    body = orjson.dumps([{"a": 1}] * (FLOOD_BYTES // 8))
    assert len(body) <= FLOOD_BYTES + 8
    return body


@pytest.mark.parametrize("broker_kind", ["mosquitto", "embedded"])
def test_presence_flood_neither_delays_commands_nor_lets_stale_motion_follow_a_stop(tmp_path, broker_kind) -> None:
    from geometry_msgs.msg import Twist

    probe = RosProbe()
    with ExitStack() as exits:
        exits.callback(probe.close)
        cmd_vel = probe.watch(Twist, "/cmd_vel", 1000)  # deep: a burst of stale twists must not be lost here
        if broker_kind == "embedded":
            broker = EmbeddedBrokerProcess(tmp_path)
        else:
            logins = fleet_password_file(tmp_path)
            broker = MosquittoProcess(tmp_path, f"allow_anonymous false\npassword_file {logins}\n")
        exits.callback(broker.stop)
        broker.start()
        exits.enter_context(run(["-m", "roslink_mqtt.sim"], tmp_path / "sim.log"))
        bridge = exits.enter_context(run(bridge_args("turtle1", broker.port), tmp_path / "bridge.log",
                                         bridge_env("turtle1")))
        alice = exits.enter_context(TestClient(broker.port, "alice", "alice-demo", operator=True))
        assert alice.connect() == 0
        alice.subscribe("roslink/turtle1/heartbeat")
        alice.subscribe("roslink/turtle1/state/ack")
        alice.wait_for(lambda m: m.topic.endswith("/heartbeat") and m.json()["payload"]["system_status"] == 4,
                       timeout=30)
        bob = exits.enter_context(TestClient(broker.port, "bob", "bob-demo", client_id="bob-flood"))
        assert bob.connect() == 0

        twists = MarkedTwists(alice, TWIST, lx=0.2, period=0.1).start()
        exits.callback(twists.stop)
        cmd_vel.wait_for(nonzero, timeout=20)  # the robot moves before the flood starts

        body = _flood_body()
        flood_start = time.monotonic()
        for _ in paced(1 / FLOOD_RATE, count=FLOOD_COUNT):
            bob.client.publish("roslink/operators/bob/bob-flood", body, qos=0)
        stop_seq = twists.stop() + 1
        zero_sent = time.monotonic()
        alice.client.publish(TWIST, orjson.dumps({"message_id": 100, "sequence_number": stop_seq, "payload": {}}),
                             qos=0)
        # past the dead-man: stale motion would have shown by now (judged below, with the report and the measurement)
        with contextlib.suppress(AssertionError):
            never("non-zero motion later than the dead-man after the zero twist",
                  lambda: [round(at - zero_sent, 3) for at, m in cmd_vel.since(zero_sent)
                           if nonzero(m) and at - zero_sent > COMMAND_TIMEOUT], seconds=COMMAND_TIMEOUT + 1.0)
        assert bridge.popen.poll() is None, bridge.output()[-3000:]

        seen = cmd_vel.since(flood_start)
        delays = twists.delays(seen, flood_start, zero_sent)
        worst = delays.worst
        after_stop = [at - zero_sent for at, m in seen if at > zero_sent and nonzero(m)]
        last_motion = max(after_stop, default=0.0)
        stops = [m.json()["payload"]["text"] for m in alice.drain(0.2) if m.topic.endswith("/state/ack")]
        report = (f"[{broker_kind}] {len(delays.delivered)}/{delays.sent} twists delivered during the flood, "
                  f"worst delay {worst:.3f} s; "
                  f"last non-zero twist {last_motion:.3f} s after the zero twist was sent; "
                  f"failsafe acks: {stops}")
        print(report, file=sys.stderr)
        record_measurement(f"[{broker_kind}] presence flood: worst twist delay", worst, DELAY_BOUND)
        record_measurement(f"[{broker_kind}] presence flood: motion after zero twist", last_motion, COMMAND_TIMEOUT)

        assert worst <= DELAY_BOUND, report
        assert len(delays.delivered) >= 0.8 * delays.sent, report  # commands keep flowing, not merely dropped
        assert last_motion <= COMMAND_TIMEOUT, report
        assert not [text for text in stops if "lost the broker" in text], report  # the link stayed up
        if broker_kind == "mosquitto":  # it forwards the bodies: the bridge must have seen and ignored them
            assert "ignored an oversized presence payload (3900001 bytes" in bridge.output(), bridge.output()[-3000:]
            assert bridge.output().count("ignored an oversized presence") == 1  # once per client
