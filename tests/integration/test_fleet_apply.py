"""``roslink-mqtt fleet apply``: a fleet change reaches the broker and the robots live, with nothing restarted.

Real processes: a broker started from a copy of the demo fleet (the embedded one, or Mosquitto with its
dynamic-security plugin from ``acl export --format mosquitto-dynsec``), the simulated turtle1 and its bridge, which
runs from its robot file (``fleet split``: no users) and so knows who may drive only from the grants the broker
side publishes. The test edits the fleet file with the CLI (``fleet user add``, ``fleet grant``, ``fleet revoke``)
and applies it with ``fleet apply``, as an administrator would.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from roslink_mqtt.config.split import split_fleet
from roslink_mqtt.localproc import Mosquitto
from tests.support.broker_setup import write_fleet
from tests.support.embedded_broker import EmbeddedBrokerProcess
from tests.support.fleet_apply import Apply
from tests.support.measure import record_measurement
from tests.support.mqtt_client import TestClient
from tests.support.procs import ROOT, bridge_args, bridge_env, run
from tests.support.ros import RosProbe
from tests.support.waits import never, paced, wait_until

pytestmark = pytest.mark.timeout(180)

TWIST = "roslink/turtle1/from/{user}/cmd/twist"


def cli(*args: str, env_password: str = "admin-demo") -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "roslink_mqtt.cli.main", *args], capture_output=True, text=True,
                          cwd=ROOT, timeout=60, env={**os.environ, "ROSLINK_PASSWORD": env_password},
                          stdin=subprocess.DEVNULL)


def _stream(client: TestClient, user: str, lx: float, stop: threading.Event) -> threading.Thread:
    def loop() -> None:  # 20 Hz until stopped
        for _ in paced(0.05, within=180, stop=stop.is_set):
            client.publish(TWIST.format(user=user), {"lx": lx}, qos=0)
    thread = threading.Thread(target=loop, daemon=True)
    thread.start()
    return thread


def _wait_for_log(proc, text: str, timeout: float = 10.0) -> None:
    try:
        wait_until(f"{text!r} in the log", lambda: text in proc.output(), timeout=timeout)
    except AssertionError as e:
        raise AssertionError(f"{e}; the log:\n{proc.output()[-3000:]}") from None


@contextmanager
def _broker(kind: str, work: Path, fleet: Path) -> Iterator[tuple[int, Callable[[], str]]]:
    """(port, its log) of a broker enforcing ``fleet``: the embedded one, or Mosquitto with dynamic security."""
    if kind == "embedded":
        with EmbeddedBrokerProcess(work, fleet) as broker:
            yield broker.port, broker.output
    else:
        with Mosquitto.exported_dynsec(work, fleet) as mosquitto:
            yield mosquitto.port, mosquitto.output


@pytest.mark.parametrize("kind", ["embedded", "mosquitto"])
def test_fleet_apply_adds_a_driver_and_cuts_a_revoked_one_off(kind: str, tmp_path: Path) -> None:
    from geometry_msgs.msg import Twist

    fleet = write_fleet(tmp_path, read_only_service=False)
    robot_file = split_fleet(fleet, tmp_path / "robot-files", ["turtle1"])[0]
    dave_password = tmp_path / "dave.password"
    passwords = tmp_path / "passwords.yaml"  # Mosquitto's plugin takes a new login's password in clear text
    passwords.write_text("{}\n")
    options = ("--broker-kind", kind) + (("--passwords", str(passwords)) if kind == "mosquitto" else ())
    probe = RosProbe()
    cmd_vel = probe.watch(Twist, "/cmd_vel")
    try:
        with _broker(kind, tmp_path, fleet) as (port, broker_log), \
                run(["-m", "roslink_mqtt.sim"], tmp_path / "sim.log"), \
                run(bridge_args("turtle1", port, config=robot_file), tmp_path / "bridge.log",
                    bridge_env("turtle1")) as bridge, \
                TestClient(port, "admin", "admin-demo") as admin, \
                TestClient(port, "alice", "alice-demo", operator=True) as alice:
            for client in (admin, alice):
                assert client.connect() == 0
            admin.subscribe("roslink/turtle1/heartbeat")
            admin.wait_for(lambda m: m.json()["payload"]["system_status"] == 4, timeout=20)
            admin.subscribe("roslink/turtle1/state/ack")
            alice.subscribe("roslink/turtle1/to/alice/error")

            # 0. no grants on the broker (Mosquitto has never had any; the embedded broker's are cleared): the
            #    bridge obeys nobody, and says why; fleet apply publishes them (nothing else differs)
            if kind == "embedded":
                _wait_for_log(bridge, "grants from broker: 3 users may see turtle1")
                admin.publish("roslink/turtle1/grants", b"", retain=True)
                _wait_for_log(bridge, "grants of turtle1 were withdrawn")
            # the bridge subscribes to everyone's inputs once it has no grants (to refuse them with the reason),
            # after its log line and on a connection of its own: a twist may reach the broker first, unheard (a
            # clean-clone run beside a CPU hog), so alice sends until she hears why
            deadline = time.monotonic() + 20
            while True:
                alice.publish(TWIST.format(user="alice"), {"lx": 0.1})
                try:
                    refusal = alice.wait_for(lambda m: "has no grants from the broker yet" in m.json().get("error", ""),
                                             timeout=2)
                    break
                except TimeoutError:
                    assert time.monotonic() < deadline, "no refusal for a twist sent without grants"
            assert refusal.json()["topic"] == TWIST.format(user="alice")
            restored = Apply(fleet, port, *options)
            assert "nothing to change" in restored.output and "bridge   turtle1: grants published" in restored.output
            _wait_for_log(bridge, "grants from admin: 3 users may see turtle1")

            # 1. a new user, granted turtle1: can log in and drive once apply has run (--dry-run first: no change)
            dry = cli("fleet", "apply", "--config", str(fleet), "--url", f"mqtt://127.0.0.1:{port}", "-u", "admin",
                      *options, "--dry-run")
            assert dry.returncode == 0 and "nothing to change" in dry.stdout, dry.stdout + dry.stderr
            added = cli("fleet", "user", "add", "--config", str(fleet), "dave", "--password-file",
                        str(dave_password), "--iterations", "1000")
            assert added.returncode == 0, added.stderr
            granted = cli("fleet", "grant", "--config", str(fleet), "dave", "turtle1")
            assert granted.returncode == 0, granted.stderr
            password = dave_password.read_text().strip()
            passwords.write_text(f"dave: {password}\n")
            with TestClient(port, "dave", password, operator=True) as early:
                assert early.connect() != 0  # not yet: the broker has not been told
            dry = cli("fleet", "apply", "--config", str(fleet), "--url", f"mqtt://127.0.0.1:{port}", "-u", "admin",
                      *options, "--dry-run")
            assert "add      dave: user" in dry.stdout, dry.stdout
            assert "bridge   turtle1: grants would be published" in dry.stdout, dry.stdout
            assert "applied" not in dry.stdout
            with TestClient(port, "dave", password, operator=True) as early:
                assert early.connect() != 0  # a dry run changes nothing
            applied = Apply(fleet, port, *options)
            # the embedded broker republishes the grants itself on reload; for Mosquitto fleet apply publishes them
            told = "grants   turtle1" if kind == "embedded" else "bridge   turtle1: grants published"
            assert "add      dave: user" in applied.output and told in applied.output, applied.output
            assert applied.planned is not None
            with TestClient(port, "dave", password, operator=True) as dave:
                assert dave.connect() == 0
                stop = threading.Event()
                streamer = _stream(dave, "dave", 0.27, stop)
                try:
                    drove_at, _ = cmd_vel.wait_for(lambda m: m.linear.x == pytest.approx(0.27), after=applied.done,
                                                   timeout=10)
                finally:
                    stop.set()
                    streamer.join()
                dave.publish("roslink/turtle1/from/dave/control/release", b"")
            record_measurement(f"fleet apply ({kind}): a new user drives, after the plan was printed",
                               drove_at - applied.planned, 3.0)
            record_measurement(f"fleet apply ({kind}): a new user drives, from the command's start (Python "
                               "included)", drove_at - applied.started, 3.0)
            # the product's share (after the plan was printed) at the target; the whole including the CLI's Python
            # start-up only at a generous deadline: on a busy machine imports alone take seconds (issue 47)
            assert drove_at - applied.planned < 3.0
            assert drove_at - applied.started < 10.0

            # 2. alice loses turtle1 while she drives: the broker drops her connection and her publishes, the bridge
            #    stops the robot at once (not the dead-man's timeout later); her programs say why (issue 43)
            from roslink_mqtt.client import NotGranted, RobotClient
            alice_sdk = RobotClient("alice", "alice-demo", url=f"mqtt://127.0.0.1:{port}", robots=["turtle1"])
            alice_sdk.connect()
            alice_sdk.wait_for_robot("turtle1", timeout=10)
            stop = threading.Event()
            t0 = time.monotonic()
            streamer = _stream(alice, "alice", 0.33, stop)
            try:
                cmd_vel.wait_for(lambda m: m.linear.x == pytest.approx(0.33), after=t0, timeout=10)
                revoked = cli("fleet", "revoke", "--config", str(fleet), "alice", "turtle1")
                assert revoked.returncode == 0, revoked.stderr
                applied = Apply(fleet, port, *options)
                assert applied.planned is not None
                stopped_at, _ = cmd_vel.wait_for(lambda m: m.linear.x == 0 and m.angular.z == 0,
                                                 after=applied.planned, timeout=5)
                # her stream goes on (her client reconnects): none of it may reach the robot
                never("a non-zero twist reaching the robot after the revocation",
                      lambda: [m for _, m in cmd_vel.since(stopped_at + 0.1) if m.linear.x != 0], seconds=1.0)
            finally:
                stop.set()
                streamer.join()
            record_measurement(f"fleet apply ({kind}): a revoked driver's robot stops, after the plan was printed",
                               stopped_at - applied.planned, 1.0)
            assert stopped_at - applied.planned < 1.0
            late = [m for _, m in cmd_vel.since(stopped_at + 0.1) if m.linear.x != 0]
            assert not late, f"{len(late)} non-zero twists reached the robot after the revocation"
            ack = admin.wait_for(lambda m: m.topic.endswith("/state/ack")
                                 and "operator grant removed" in m.json()["payload"]["text"], timeout=5)
            assert "alice" in ack.json()["payload"]["text"]
            assert "broker lost" not in bridge.output()  # no grant change disconnected the robot
            if kind == "embedded":
                assert "fewer grants ['alice']" in broker_log() and "connection(s) dropped" in broker_log()
            # what alice's programs are told. The embedded broker refuses her turtle1 filter when her SDK client
            # reconnects: the client reports it at once, and a `pub` afterwards says the same instead of "never
            # seen". Mosquitto grants the filter and delivers nothing: the client says the retained heartbeat
            # that any reader gets at once did not come
            if kind == "embedded":
                removed = "your grant to turtle1 was removed by the fleet"
                try:
                    wait_until("alice's client to report her removed grant",
                               lambda: any(removed in e.error for e in list(alice_sdk.recent_errors)), timeout=15)
                except AssertionError as e:
                    raise AssertionError(f"{e}: {list(alice_sdk.recent_errors)}") from None
                with pytest.raises(NotGranted, match=removed):
                    alice_sdk.wait_for_robot("turtle1", timeout=5)
            else:
                with pytest.raises(TimeoutError, match="was your grant to turtle1 removed by the fleet"):
                    alice_sdk.wait_for_robot("turtle1", timeout=3)
            alice_sdk.close()
            pub = cli("pub", "turtle1", "twist", '{"lx": 0.1}', "--url", f"mqtt://127.0.0.1:{port}", "-u", "alice",
                      env_password="alice-demo")
            told = "user 'alice' has no grant on turtle1" if kind == "embedded" else "granted to alice?"
            assert pub.returncode == 1 and told in pub.stderr, pub
    finally:
        probe.close()


def test_a_robot_added_with_fleet_robot_add_runs_from_its_bundle(tmp_path: Path) -> None:
    """``fleet robot add``: after ``fleet apply`` the new robot's login works, and its bridge runs as the bundle's
    systemd drop-in says (its ExecStart, with the bundle's environment file), from the robot file alone."""
    fleet = write_fleet(tmp_path, read_only_service=False)
    bundle = tmp_path / "bundle"
    with EmbeddedBrokerProcess(tmp_path, fleet) as broker:
        added = cli("fleet", "robot", "add", "--config", str(fleet), "turtle3", "--like", "turtle1", "--bundle",
                    str(bundle), "--broker-url", f"mqtt://127.0.0.1:{broker.port}")
        assert added.returncode == 0, added.stderr
        env = dict(line.split("=", 1) for line in (bundle / "turtle3.env").read_text().splitlines()
                   if line.startswith("ROSLINK_"))  # the ROS graph's settings stay the test's (its own domain)
        password = (bundle / "turtle3.password").read_text().strip()
        with TestClient(broker.port, "turtle3", password) as early:
            assert early.connect() != 0  # not before apply
        applied = Apply(fleet, broker.port)
        assert "add      turtle3: robot" in applied.output and "grants   turtle3" in applied.output
        drop_in = (bundle / "roslink-mqtt-bridge.service.d" / "turtle3.conf").read_text()
        exec_start = [x for x in drop_in.splitlines() if x.startswith("ExecStart=/")][0].split("=", 1)[1]
        argv = exec_start.replace("${ROSLINK_ROBOT}", env["ROSLINK_ROBOT"]).replace(
            "$ROSLINK_BRIDGE_ARGS", env["ROSLINK_BRIDGE_ARGS"]).replace("/etc/roslink-mqtt/", f"{bundle}/").split()
        assert argv[0].endswith("/.venv/bin/roslink-mqtt-bridge")
        environment = {k: v for k, v in os.environ.items() if k != "ROSLINK_PASSWORD"}  # the bundle's file only
        with run(["-m", "roslink_mqtt.bridge.main", *argv[1:]], tmp_path / "bridge3.log", environment) as bridge, \
                TestClient(broker.port, "admin", "admin-demo") as admin:
            assert admin.connect() == 0
            admin.subscribe("roslink/turtle3/heartbeat")
            admin.wait_for(lambda m: m.json()["payload"]["system_status"] == 4, timeout=30)
            _wait_for_log(bridge, "grants from broker: 1 users may see turtle3 (admin:operator)")


def test_a_robot_password_rotates_without_dropping_the_robot(tmp_path: Path) -> None:
    """``fleet robot rotate``: both passwords work until ``--finish``; the bridge takes the new one on SIGHUP from
    its password file and keeps its connections throughout; after the broker restarts it logs in with the new one."""
    fleet = write_fleet(tmp_path, read_only_service=False)
    robot_file = split_fleet(fleet, tmp_path / "robot-files", ["turtle1"])[0]
    password_file = tmp_path / "turtle1.password"
    password_file.write_text("turtle1-demo\n")
    new_password = tmp_path / "new.password"
    environment = {k: v for k, v in os.environ.items() if k != "ROSLINK_PASSWORD"}

    def logs_in(port: int, password: str) -> bool:
        with TestClient(port, "turtle1", password) as probe:
            return probe.connect() == 0

    with EmbeddedBrokerProcess(tmp_path, fleet) as broker, \
            run(bridge_args("turtle1", broker.port, "--password-file", str(password_file), config=robot_file),
                tmp_path / "bridge.log", environment) as bridge, \
            TestClient(broker.port, "admin", "admin-demo") as admin:
        assert admin.connect() == 0
        admin.subscribe("roslink/turtle1/heartbeat")
        admin.wait_for(lambda m: m.json()["payload"]["system_status"] == 4, timeout=30)
        rotated = cli("fleet", "robot", "rotate", "--config", str(fleet), "turtle1", "--password-file",
                      str(new_password))
        assert rotated.returncode == 0, rotated.stderr
        applied = Apply(fleet, broker.port)
        assert "password turtle1" in applied.output
        new = new_password.read_text().strip()
        assert logs_in(broker.port, "turtle1-demo") and logs_in(broker.port, new)  # both, meanwhile
        password_file.write_text(new + "\n")  # the robot gets its new password, and its bridge is reloaded
        bridge.signal(signal.SIGHUP)
        _wait_for_log(bridge, "the robot's password changed")
        finished = cli("fleet", "robot", "rotate", "--config", str(fleet), "turtle1", "--finish")
        assert finished.returncode == 0, finished.stderr
        Apply(fleet, broker.port)
        assert not logs_in(broker.port, "turtle1-demo") and logs_in(broker.port, new)
        assert "broker lost" not in bridge.output()  # nothing dropped the robot meanwhile
        assert "0 connection(s) dropped" in broker.output()
        broker.stop()  # the next connection of the bridge: with the new password
        broker.start()
        admin.wait_for(lambda m: m.json()["payload"]["system_status"] == 4 and not m.retain, timeout=30)
        assert "refused" not in bridge.output()


def test_only_administrators_reach_the_fleet_control_topic(tmp_path: Path) -> None:
    """bob (a viewer) as an attacker: 500 reload requests on ``$CONTROL/roslink/v1`` reload nothing, cost one log
    line, and he cannot read the answers; an administrator's request meanwhile is answered."""
    from roslink_mqtt.protocol.fleet_control import ControlRequest, ControlResponse

    fleet = write_fleet(tmp_path, read_only_service=False)
    request = ControlRequest(({"command": "reload"},), "attack").to_json()
    with EmbeddedBrokerProcess(tmp_path, fleet) as broker, \
            TestClient(broker.port, "bob", "bob-demo") as bob, TestClient(broker.port, "admin", "admin-demo") as admin:
        assert bob.connect() == 0 and admin.connect() == 0
        bob.subscribe("$CONTROL/roslink/v1/response")  # refused (SUBACK 0x80); and nothing may reach him there
        for _ in range(500):
            bob.publish("$CONTROL/roslink/v1", request, qos=0)
        bob.publish("$CONTROL/roslink/v1", request, qos=1)  # acknowledged: everything before it was handled
        admin.subscribe("$CONTROL/roslink/v1/response")
        admin.publish("$CONTROL/roslink/v1", ControlRequest(({"command": "getFleet"},), "mine").to_json())
        answer = ControlResponse.from_json(admin.wait_for(lambda m: m.topic.endswith("/response")).payload)
        assert answer.id == "mine" and "bob" in answer.responses[0]["data"]["logins"]
        assert not [m for m in bob.drain(0.5) if m.topic.startswith("$CONTROL")], "bob read the control answers"
        log = broker.output()
        assert "asks to reload" not in log and "reloaded" not in log
        assert log.count("only the fleet's administrators may use it") == 1
