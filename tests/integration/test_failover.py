"""Failover across several brokers, with real processes: the bridge, an SDK operator and the CLI get two URLs.

Two Mosquitto brokers with the fleet's logins stand in for two nodes of a cluster
(tests/integration/test_rabbitmq_cluster.py does the same against a real RabbitMQ cluster). Killing the broker
everyone is on must stop the robot (the failsafe), and within 5 s the bridge and the operator are on the other
broker and the robot moves again.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
from contextlib import ExitStack

import pytest

from roslink_mqtt.client import RobotClient
from tests.support.failover import drive, kill_and_measure, moving
from tests.support.fleet_brokers import fleet_password_file
from tests.support.mosquitto import MosquittoProcess
from tests.support.procs import CONFIG, ROOT, bridge_env, run
from tests.support.ros import RosProbe

pytestmark = pytest.mark.timeout(120)


def test_bridge_and_sdk_fail_over_to_the_next_broker(tmp_path) -> None:
    from geometry_msgs.msg import Twist

    probe = RosProbe()
    cmd_vel = probe.watch(Twist, "/cmd_vel")
    stop = threading.Event()
    with ExitStack() as exits:
        exits.callback(probe.close)
        passwd = fleet_password_file(tmp_path)
        brokers = []
        for name in ("a", "b"):
            work = tmp_path / name
            work.mkdir()
            broker = MosquittoProcess(work, f"allow_anonymous false\npassword_file {passwd}\n")
            exits.callback(broker.stop)
            broker.start()
            brokers.append(broker)
        urls = ",".join(f"mqtt://127.0.0.1:{b.port}" for b in brokers)
        exits.enter_context(run(["-m", "roslink_mqtt.sim"], tmp_path / "sim.log"))
        exits.enter_context(run(["-m", "roslink_mqtt.bridge.main", "--config", str(CONFIG), "--robot", "turtle1",
                                 "--url", urls], tmp_path / "bridge.log", bridge_env("turtle1")))
        alice = exits.enter_context(RobotClient("alice", "alice-demo", url=urls, robots=["turtle1"]))
        assert alice.wait_for_robot("turtle1", timeout=30), "the robot never came online"
        exits.callback(stop.set)
        drive(alice, "turtle1", stop)
        cmd_vel.wait_for(moving, timeout=20)
        assert alice.connection.url.port == brokers[0].port  # everyone starts on the first node of the list
        kill_and_measure(cmd_vel, brokers[0].kill, "Mosquitto pair")
        assert alice.connection.url.port == brokers[1].port
        log = (tmp_path / "bridge.log").read_text()
        assert f"lost the broker mqtt://127.0.0.1:{brokers[0].port}" in log
        assert f"reconnecting to mqtt://127.0.0.1:{brokers[1].port}" in log
        # the CLI, given the same list with the first broker dead, connects to the next one
        listed = subprocess.run([sys.executable, "-m", "roslink_mqtt.cli.main", "robots", "--url", urls, "-u", "alice"],
                                capture_output=True, text=True, cwd=ROOT, timeout=60, stdin=subprocess.DEVNULL,
                                env={**os.environ, "ROSLINK_PASSWORD": "alice-demo"})
        assert listed.returncode == 0, listed.stderr
        assert "turtle1" in listed.stdout


