"""Start order does not matter: the bridge waits for a broker that is not there yet, and for ROS topics.

While it waits it says so (issue 30 item 6): an unreachable broker, with the attempt and the next retry; a refused
login as what it is, retried slowly, or the bridge exits with status 5 when robots.yaml says so.
"""

from __future__ import annotations

import re
import time

import pytest

from roslink_mqtt.bridge.core.claim import EXIT_LOGIN_REFUSED
from roslink_mqtt.protocol import MessageId, SystemStatus, decode
from tests.support.broker_setup import write_fleet
from tests.support.embedded_broker import EmbeddedBrokerProcess
from tests.support.fleet_brokers import fleet_password_file
from tests.support.mosquitto import run_mosquitto
from tests.support.mqtt_client import TestClient
from tests.support.net import free_port
from tests.support.procs import bridge_args, bridge_env, run
from tests.support.waits import never, wait_until

pytestmark = pytest.mark.timeout(90)


def test_bridge_first_then_robot_then_broker(tmp_path) -> None:
    port = free_port()  # nothing listens here yet
    with run(bridge_args("turtle1", port), tmp_path / "bridge.log", bridge_env("turtle1")) as bridge:
        # the bridge keeps retrying a broker that does not exist
        never("the bridge giving up without a broker", lambda: bridge.popen.poll() is not None and bridge.output(),
              seconds=2.0)
        assert bridge.popen.poll() is None, f"bridge gave up without a broker:\n{bridge.output()}"
        with run(["-m", "roslink_mqtt.sim"], tmp_path / "sim.log") as sim:
            wait_until("the simulated robot ready", lambda: "simulated robot ready" in sim.output(), timeout=20)
            conf = f"allow_anonymous false\npassword_file {fleet_password_file(tmp_path)}\n"
            with run_mosquitto(tmp_path, conf, port=port), \
                    TestClient(port, "alice", "alice-demo", operator=True) as alice:
                assert alice.connect() == 0
                alice.subscribe("roslink/turtle1/#")
                heartbeat = alice.wait_for(lambda m: m.topic == "roslink/turtle1/heartbeat", timeout=20)
                assert decode(heartbeat.payload, MessageId.HEARTBEAT).payload["system_status"] == SystemStatus.ACTIVE
                motion = alice.wait_for(lambda m: m.topic == "roslink/turtle1/state/global_motion", timeout=20)
                assert decode(motion.payload, MessageId.GLOBAL_MOTION).system_id == 1
        assert bridge.popen.poll() is None, "the bridge must survive its robot going away"


def test_bridge_started_before_its_broker_says_it_is_retrying(tmp_path) -> None:
    port = free_port()  # nothing listens here
    with run(bridge_args("turtle1", port), tmp_path / "bridge.log", bridge_env("turtle1")) as bridge:
        said = wait_until("the third attempt logged", lambda: re.findall(
            rf"WARNING .*broker mqtt://127\.0\.0\.1:{port} unreachable, retrying \(attempt (\d+), next in ([\d.]+) s\)",
            bridge.output()) if "attempt 3," in bridge.output() else None, timeout=20)
        assert bridge.popen.poll() is None, bridge.output()
    print("\n" + "\n".join(line for line in bridge.output().splitlines() if "unreachable" in line))
    attempts, delays = [int(a) for a, _ in said], [float(d) for _, d in said]
    assert attempts[:3] == [1, 2, 3] and delays == sorted(delays) and delays[0] < delays[-1], said  # a backoff


def test_refused_login_is_said_and_backed_off_or_ends_the_bridge(tmp_path) -> None:
    """Two bridges with a wrong password: one keeps retrying, slowly; one exits 5 (bridge.exit_on_refused_login)."""
    exiting = write_fleet(tmp_path, name="exiting.yaml", read_only_service=False, edit=lambda t: t.replace(
        "    bridge: &bridge\n", "    bridge: &bridge\n      exit_on_refused_login: true\n", 1))
    wrong = {**bridge_env("turtle1"), "ROSLINK_PASSWORD": "not-the-robots-password"}
    with EmbeddedBrokerProcess(tmp_path) as broker, \
            run(bridge_args("turtle1", broker.port), tmp_path / "retrying.log", wrong) as retrying, \
            run(bridge_args("turtle1", broker.port, config=exiting), tmp_path / "exiting.log", wrong) as leaving:
        refused = f"ERROR roslink_mqtt.bridge.core.link: broker mqtt://127.0.0.1:{broker.port} refused turtle1's " \
                  "login: wrong username or password"
        wait_until("the retrying bridge's refusal", lambda: refused in retrying.output(), timeout=20)
        first = time.monotonic()
        assert "retrying in 5 s" in retrying.output(), retrying.output()
        wait_until("the other bridge's exit", lambda: leaving.popen.poll() is not None, timeout=20)
        assert leaving.popen.returncode == EXIT_LOGIN_REFUSED, leaving.output()
        assert refused in leaving.output() and "exiting with status 5" in leaving.output(), leaving.output()
        # paho's own backoff (0.1 s doubling to 2 s) tried 4 times in 2 s; the refused login waits 5 s
        never("the retrying bridge trying again or exiting within 2 s of the refusal",
              lambda: retrying.output().count(refused) > 1 or retrying.popen.poll() is not None,
              seconds=max(0.0, first + 2.0 - time.monotonic()))
        assert retrying.popen.poll() is None, retrying.output()
        assert retrying.output().count(refused) == 1, retrying.output()
        # (a login the broker's busy password checks turn away at once, "try again", is retried at once, rightly:
        # a clean-clone run saw one; only a refused password is backed off)
        viewers = re.findall(r"refused client_id='(roslink-bridge-turtle1-viewers-\w+)' .*: wrong password",
                             broker.output())
    print("\n" + "\n".join(line for line in retrying.output().splitlines() if "refused" in line))
    assert viewers and all(viewers.count(v) == 1 for v in viewers), viewers  # each viewer link: one refused password
