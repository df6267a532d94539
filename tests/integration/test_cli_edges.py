"""The command line's rough edges (issue 13 item 10), through real processes against a real stack.

echo says why nothing came and exits with a status that tells timeout, unknown state and an offline robot
apart; a closed stdout ends every command quietly; ``roslink-mqtt-sim --help`` starts nothing; teleop keys
step the velocity (w then a drives an arc) and the e-stopped screen shows no speed; a clean Ctrl-C of the
bridge and a finished ``pub`` do not log warnings, while a killed commanding client still stops the robot
with one.
"""

from __future__ import annotations

import os
import pty
import re
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import orjson
import pytest

from roslink_mqtt.cli import echo_cmd
from roslink_mqtt.cli.main import EXIT_BROKEN_PIPE
from roslink_mqtt.cli.teleop_cmd import ARM, ESTOP, QUIT, Drive
from tests.support.embedded_broker import EmbeddedBrokerProcess
from tests.support.mqtt_client import TestClient
from tests.support.procs import ROOT, bridge_args, bridge_env, run
from tests.support.robot_stack import turtle1_online
from tests.support.waits import never, paced, wait_until

pytestmark = pytest.mark.timeout(180)


@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    """(broker port, bridge log) of a live turtle1."""
    work = tmp_path_factory.mktemp("cli-edges")
    with turtle1_online(work) as port:
        yield port, work / "bridge.log"


def cli(port: int, user: str, *args: str, timeout: float = 30, **kw) -> subprocess.CompletedProcess:
    env = {**os.environ, "ROSLINK_PASSWORD": f"{user}-demo"}
    return subprocess.run([sys.executable, "-m", "roslink_mqtt.cli.main", *args, "--url", f"mqtt://127.0.0.1:{port}",
                           "-u", user], capture_output=True, text=True, env=env, cwd=ROOT, timeout=timeout,
                          stdin=subprocess.DEVNULL, **kw)


# -- echo --------------------------------------------------------------------------------------------------------

def test_echo_heartbeat(stack) -> None:
    out = cli(stack[0], "bob", "echo", "turtle1", "heartbeat", "-n", "1", "--timeout", "10")
    assert out.returncode == 0, out.stderr
    beat = orjson.loads(out.stdout)
    assert beat["name"] == "turtle1" and beat["system_status"] == 4


def test_echo_every_state_with_a_wildcard(stack) -> None:
    out = cli(stack[0], "bob", "echo", "turtle1", "#", "-n", "5", "--timeout", "10")
    assert out.returncode == 0, out.stderr
    lines = [orjson.loads(line) for line in out.stdout.splitlines()]
    assert len(lines) == 5 and "Traceback" not in out.stderr
    assert {"global_motion", "robot_status"} & {line["state"] for line in lines}
    assert all(isinstance(line["message"], dict) for line in lines)


def test_echo_timeout_says_so(stack) -> None:
    out = cli(stack[0], "bob", "echo", "turtle1", "global_motion", "-n", "10000", "--timeout", "1.5")
    assert out.returncode == echo_cmd.EXIT_TIMEOUT == 1, out.stderr
    assert re.search(r"timeout: \d+ of 10000 messages on turtle1 state/global_motion within 1.5 s", out.stderr)


def test_echo_unknown_state_names_what_the_robot_publishes(stack) -> None:
    out = cli(stack[0], "bob", "echo", "turtle1", "global_motoin", "-n", "1", "--timeout", "1.5")
    assert out.returncode == echo_cmd.EXIT_USAGE == 2, out.stderr  # the description says it never comes
    assert "publishes no state/global_motoin; did you mean global_motion?" in out.stderr
    assert "global_motion" in out.stderr.split("It publishes:")[1]
    assert out.stdout == ""
    listed = cli(stack[0], "bob", "echo", "turtle1", "ack", "-n", "1", "--timeout", "1.5")  # listed, nothing yet
    assert listed.returncode == echo_cmd.EXIT_NOTHING == 3, listed.stderr
    assert "acks come only when something happens" in listed.stderr


def test_echo_offline_or_unseen_robot(stack) -> None:
    out = cli(stack[0], "carol", "echo", "turtle2", "global_motion", "-n", "1", "--timeout", "1.5")
    assert out.returncode == echo_cmd.EXIT_OFFLINE == 4, out.stderr
    assert "robot turtle2 never seen in" in out.stderr or "robot turtle2 is offline" in out.stderr, out.stderr
    refused = cli(stack[0], "carol", "echo", "turtle1", "global_motion", "-n", "1", "--timeout", "1.5")
    assert refused.returncode == echo_cmd.EXIT_OFFLINE, refused.stderr  # not hers to see
    assert "user 'carol' has no grant on turtle1: the broker refused" in refused.stderr, refused.stderr


def test_a_robot_name_typo_is_answered_within_seconds_with_the_name_meant(stack) -> None:
    """Issue 43, 3: `pub turtel1` waited 5.6 s for "never seen" with no hint; echo worded it differently."""
    started = time.monotonic()
    pub = cli(stack[0], "alice", "pub", "turtel1", "twist", '{"lx": 0.1}')
    took = time.monotonic() - started
    assert pub.returncode == 1 and "no robot turtel1" in pub.stderr + pub.stdout, pub  # on this broker: no grant
    assert "did you mean turtle1?" in pub.stderr + pub.stdout, pub
    assert took < 5.0, took  # about a second of waiting, plus Python's start (a generous bound: a busy machine)
    echo = cli(stack[0], "bob", "echo", "turtel1", "global_motion", "-n", "1", "--timeout", "3")
    assert echo.returncode == echo_cmd.EXIT_OFFLINE and "did you mean turtle1?" in echo.stderr, echo.stderr
    denied = cli(stack[0], "carol", "pub", "turtle1", "twist", '{"lx": 0.1}')
    assert denied.returncode == 1 and "user 'carol' has no grant on turtle1" in denied.stderr + denied.stdout, denied


def test_echo_bad_name_is_a_usage_error(stack) -> None:
    out = cli(stack[0], "bob", "echo", "turtle1", "global#", "-n", "1", "--timeout", "1")
    assert out.returncode == echo_cmd.EXIT_USAGE == 2
    assert "must be whole levels" in out.stderr and "Traceback" not in out.stderr


# -- a closed stdout ---------------------------------------------------------------------------------------------

def _closed_stdout(args: list[str], port: int | None = None, user: str = "bob") -> tuple[int, str]:
    """Run the CLI with a stdout whose reader is already gone (what `| head` becomes once head exits)."""
    env = {**os.environ, "ROSLINK_PASSWORD": f"{user}-demo"}
    conn = ["--url", f"mqtt://127.0.0.1:{port}", "-u", user] if port else []
    read, write = os.pipe()
    os.close(read)
    try:
        proc = subprocess.run([sys.executable, "-m", "roslink_mqtt.cli.main", *args, *conn], stdout=write,
                              stderr=subprocess.PIPE, text=True, env=env, cwd=ROOT, timeout=30,
                              stdin=subprocess.DEVNULL)
    finally:
        os.close(write)
    return proc.returncode, proc.stderr


def test_fleet_into_a_closed_pipe() -> None:
    code, err = _closed_stdout(["fleet", "--config", str(ROOT / "config" / "robots.yaml")])
    assert "Traceback" not in err and "Exception ignored" not in err, err
    assert code == EXIT_BROKEN_PIPE


def test_help_into_a_closed_pipe() -> None:
    code, err = _closed_stdout(["--help"])
    assert "Traceback" not in err and "Exception ignored" not in err, err
    assert code in (0, EXIT_BROKEN_PIPE)


def test_echo_into_head(stack) -> None:
    env = {**os.environ, "ROSLINK_PASSWORD": "bob-demo"}
    proc = subprocess.Popen([sys.executable, "-m", "roslink_mqtt.cli.main", "echo", "turtle1", "global_motion",
                             "--url", f"mqtt://127.0.0.1:{stack[0]}", "-u", "bob"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, env=env, cwd=ROOT, stdin=subprocess.DEVNULL)
    try:
        first = proc.stdout.readline()
        assert b'"x"' in first
        proc.stdout.close()  # head -n 1 exits
        code = proc.wait(timeout=15)
        err = proc.stderr.read().decode()
    finally:
        if proc.poll() is None:
            proc.kill()
    assert "Traceback" not in err and "Exception ignored" not in err, err
    assert code == EXIT_BROKEN_PIPE


# -- the simulated robot -----------------------------------------------------------------------------------------

def test_sim_help_starts_no_robot() -> None:
    out = subprocess.run([sys.executable, "-m", "roslink_mqtt.sim", "--help"], capture_output=True, text=True,
                         cwd=ROOT, timeout=20)
    assert out.returncode == 0 and "usage: roslink-mqtt-sim" in out.stdout
    assert "--ros-args" in out.stdout and "LOCALHOST" in out.stdout
    probe = subprocess.run([sys.executable, "-c", "import sys\nfrom roslink_mqtt.sim.node import main\n"
                            "try:\n    main(['roslink-mqtt-sim', '--help'])\nexcept SystemExit:\n    pass\n"
                            "print('rclpy loaded' if 'rclpy' in sys.modules else 'no rclpy')"],
                           capture_output=True, text=True, cwd=ROOT, timeout=20)
    assert probe.stdout.strip().endswith("no rclpy"), probe.stdout + probe.stderr
    typo = subprocess.run([sys.executable, "-m", "roslink_mqtt.sim", "--hepl"], capture_output=True, text=True,
                          cwd=ROOT, timeout=20)
    assert typo.returncode == 2 and "unrecognized arguments: --hepl" in typo.stderr


def test_sim_always_applies_the_local_dds_settings() -> None:
    """Even from a shell with no DDS settings the sim's environment is loopback-only (its domain id kept)."""
    bare = {k: v for k, v in os.environ.items()
            if k not in ("ROS_AUTOMATIC_DISCOVERY_RANGE", "FASTRTPS_DEFAULT_PROFILES_FILE", "RMW_IMPLEMENTATION")}
    bare["ROS_DOMAIN_ID"] = "17"
    out = subprocess.run([sys.executable, "-c", "import os\nfrom roslink_mqtt.sim.node import local_dds_env\n"
                          "local_dds_env()\nfor k in ('ROS_AUTOMATIC_DISCOVERY_RANGE', 'ROS_DOMAIN_ID', "
                          "'RMW_IMPLEMENTATION', 'FASTRTPS_DEFAULT_PROFILES_FILE'):\n    print(k, os.environ.get(k))"],
                         capture_output=True, text=True, cwd=ROOT, timeout=20, env=bare)
    got = dict(line.split(" ", 1) for line in out.stdout.splitlines())
    assert got["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST" and got["ROS_DOMAIN_ID"] == "17", out.stderr
    assert got["RMW_IMPLEMENTATION"] == "rmw_fastrtps_cpp" and got["FASTRTPS_DEFAULT_PROFILES_FILE"].endswith(
        "fastdds_localhost.xml")


def test_sim_binds_loopback_without_a_profile_in_its_environment(tmp_path) -> None:
    """The real process: started without the Fast DDS profile, its DDS ports are still on 127.0.0.1 only.

    (The discovery range stays LOCALHOST in this test's environment, so even a sim without the fix
    would not have announced itself beyond this machine.)
    """
    env = {k: v for k, v in os.environ.items() if k not in ("FASTRTPS_DEFAULT_PROFILES_FILE", "RMW_IMPLEMENTATION")}
    domain = int(env["ROS_DOMAIN_ID"])
    with run(["-m", "roslink_mqtt.sim"], tmp_path / "sim.log", env) as sim:

        def ready() -> bool:
            out = sim.output()
            assert "simulated robot ready" in out or sim.popen.poll() is None, out  # it exited
            return "simulated robot ready" in out

        wait_until("the sim to say it is ready", ready, timeout=20, period=0.1)
        sockets = subprocess.run(["ss", "-uanp"], capture_output=True, text=True, timeout=10).stdout
        log = sim.output()
    base = 7400 + 250 * domain  # RTPS well-known ports of this domain (multicast and unicast discovery, user)
    bound = [line.split()[3] for line in sockets.splitlines() if f"pid={sim.pid}," in line]
    in_domain = [addr for addr in bound if base <= int(addr.rsplit(":", 1)[1]) < base + 250]
    assert in_domain, sockets
    assert all(addr.startswith("127.0.0.1:") for addr in in_domain), in_domain
    assert "ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST" in log


# -- teleop ------------------------------------------------------------------------------------------------------

def test_teleop_keys_step_and_combine() -> None:
    drive = Drive(linear_step=0.1, angular_step=0.3, max_linear=0.25, max_angular=1.5)
    drive.key("w")
    drive.key("a")
    assert (drive.lx, drive.az) == (0.1, 0.3)  # forward + turn: an arc
    drive.key("w")
    drive.key("w")
    assert drive.lx == 0.25  # steps add up to the cap
    drive.key("d")
    drive.key("d")
    assert drive.az == -0.3
    drive.key(" ")
    assert (drive.lx, drive.az) == (0.0, 0.0)
    assert drive.key("e") == ESTOP and drive.estopped and not drive.streaming
    drive.key("w")
    assert drive.lx == 0.0 and "m/s" not in drive.status() and "EMERGENCY STOP" in drive.status()
    assert drive.key("r") == ARM and drive.streaming and "lx=+0.00" in drive.status()
    assert drive.key("q") == QUIT


def test_teleop_drives_an_arc_in_a_terminal(stack) -> None:
    """The real command in a pseudo-terminal: w, w, a makes the robot move forward and turn at once."""
    port = stack[0]
    env = {**os.environ, "ROSLINK_PASSWORD": "alice-demo"}
    pid, fd = pty.fork()
    if pid == 0:  # child: the terminal is ours
        os.chdir(ROOT)
        os.execve(sys.executable, [sys.executable, "-m", "roslink_mqtt.cli.main", "teleop", "turtle1", "--url",
                                   f"mqtt://127.0.0.1:{port}", "-u", "alice"], env)
    screen = b""

    def read_until(pattern: bytes, timeout: float) -> None:
        nonlocal screen
        deadline = time.monotonic() + timeout
        while pattern not in screen:
            assert time.monotonic() < deadline, screen.decode(errors="replace")
            if select.select([fd], [], [], 0.2)[0]:
                try:
                    screen += os.read(fd, 4096)
                except OSError:
                    break

    try:
        read_until(b"teleop turtle1:", 20)
        with TestClient(port, "bob", "bob-demo") as bob:
            assert bob.connect() == 0
            keys = b"wwa"
            for i in paced(0.2, count=len(keys)):
                os.write(fd, keys[i:i + 1])
            read_until(b"lx=+0.20 m/s az=+0.30 rad/s", 5)
            bob.subscribe("roslink/turtle1/state/global_motion", qos=0)
            motion = bob.wait_for(lambda m: m.json()["payload"]["vx"] > 0.15, timeout=5).json()["payload"]
            assert motion["vx"] == pytest.approx(0.2, abs=0.02) and motion["wz"] == pytest.approx(0.3, abs=0.02)
        os.write(fd, b"e")
        read_until(b"EMERGENCY STOP", 5)
        after = screen.rsplit(b"EMERGENCY STOP", 1)[1]
        assert b"m/s" not in after
        os.write(fd, b"r")
        read_until(b"lx=+0.00", 5)
        os.write(fd, b"q")
        _, status = os.waitpid(pid, 0)
        pid = 0
        assert os.WIFEXITED(status) and os.WEXITSTATUS(status) == 0
    finally:
        if pid:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
        os.close(fd)


# -- what the bridge logs ----------------------------------------------------------------------------------------

def _bridge_lines(log: Path, since: int) -> list[str]:
    return log.read_text(errors="replace")[since:].splitlines()


def _wait_line(log: Path, since: int, needle: str, timeout: float = 5) -> list[str]:
    def found() -> list[str]:
        lines = _bridge_lines(log, since)
        return lines if any(needle in line for line in lines) else []

    try:
        return wait_until(f"{needle!r} in the bridge log", found, timeout=timeout, period=0.1)
    except AssertionError:
        raise AssertionError(f"no {needle!r} in the bridge log:\n" + "\n".join(_bridge_lines(log, since))) from None


def test_finished_pub_is_no_warning_but_the_robot_stops(stack) -> None:
    port, log = stack
    since = len(log.read_text(errors="replace"))
    out = cli(port, "alice", "pub", "turtle1", "twist", '{"lx": 0.2}', "--rate", "10", "--duration", "1")
    assert out.returncode == 0, out.stdout + out.stderr
    lines = _wait_line(log, since, "operator alice went away (signed off)")
    stop = next(line for line in lines if "operator alice went away (signed off)" in line)
    assert " INFO " in stop and "stop of turtle1" in stop
    assert not [line for line in lines if " WARNING " in line], lines
    for command in ("arm", "emergency_stop", "arm"):  # commands that start no motion stop nothing
        assert cli(port, "alice", "pub", "turtle1", command).returncode == 0
    never("a failsafe warning in the bridge log", lambda: [
        line for line in _bridge_lines(log, since) if " WARNING " in line and "failsafe" in line], seconds=0.5)


def test_a_stream_ended_by_a_zero_twist_is_no_failsafe(stack) -> None:
    """A released drive pad sends one zero twist: the operator stopped the robot; the dead-man used to fire a second
    later and log (and acknowledge) a failsafe stop that never happened. Nor is signing off then a stop."""
    from roslink_mqtt.client import RobotClient

    port, log = stack
    since = len(log.read_text(errors="replace"))

    def stops() -> list[str]:
        return [line for line in _bridge_lines(log, since) if "dead-man" in line or "stop of turtle1" in line]

    with RobotClient("alice", "alice-demo", url=f"mqtt://127.0.0.1:{port}") as alice:
        alice.wait_for_robot("turtle1", timeout=10)
        for _ in paced(0.1, count=5):
            alice.twist("turtle1", lx=0.2)
        alice.twist("turtle1")  # the pad released
        never("a stop in the bridge log", stops, seconds=2.0)  # twice the command_timeout, the operator still present
    never("a stop in the bridge log after alice signed off", stops, seconds=0.5)


def test_killed_commanding_client_still_stops_the_robot_with_a_warning(stack) -> None:
    port, log = stack
    since = len(log.read_text(errors="replace"))
    env = {**os.environ, "ROSLINK_PASSWORD": "alice-demo"}
    pub = subprocess.Popen([sys.executable, "-m", "roslink_mqtt.cli.main", "pub", "turtle1", "twist", '{"lx": 0.2}',
                            "--rate", "10", "--duration", "20", "--url", f"mqtt://127.0.0.1:{port}", "-u", "alice"],
                           cwd=ROOT, env=env, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL)
    try:
        with TestClient(port, "bob", "bob-demo") as bob:  # until the robot moves: a busy machine starts pub late
            assert bob.connect() == 0
            bob.subscribe("roslink/turtle1/state/global_motion", qos=0)
            bob.wait_for(lambda m: m.json()["payload"]["vx"] > 0.15, timeout=20)
    finally:
        pub.kill()
        pub.wait()
    lines = _wait_line(log, since, "failsafe stop of turtle1", timeout=5)
    stop = next(line for line in lines if "failsafe stop of turtle1" in line)
    assert " WARNING " in stop and "last-will" in stop


def test_clean_ctrl_c_of_the_bridge_is_not_a_lost_broker(tmp_path) -> None:
    with EmbeddedBrokerProcess(tmp_path) as broker, run(["-m", "roslink_mqtt.sim"], tmp_path / "sim.log"):
        with run(bridge_args("turtle1", broker.port), tmp_path / "bridge.log", bridge_env("turtle1")) as bridge, \
                TestClient(broker.port, "alice", "alice-demo", operator=True) as alice:
            assert alice.connect() == 0
            alice.subscribe("roslink/turtle1/heartbeat")
            alice.wait_for(lambda m: m.json()["payload"]["system_status"] == 4, timeout=20)
            for _ in paced(0.1, count=5):  # the robot is moving when the bridge is stopped
                alice.publish("roslink/turtle1/from/alice/cmd/twist", {"lx": 0.1}, qos=0)
            bridge.signal(signal.SIGINT)
            assert bridge.popen.wait(15) == 0
        text = bridge.output()
    assert "disconnected from" in text and "(shutting down)" in text, text
    assert "stop of turtle1: the bridge is shutting down" in text
    assert " WARNING " not in text, text


# -- pub: clamping is said, the ROS shape is taken (issue 30 item 8) ---------------------------------------------

def test_pub_says_the_robot_clamped_the_twist(stack) -> None:
    """lx 50 against turtle1's 0.5 m/s limit: the robot drives at 0.5 and says so, to the sender, once per stream."""
    port, _log = stack
    once = cli(port, "alice", "pub", "turtle1", "twist", '{"lx": 50}')
    assert once.returncode == 0, once.stdout + once.stderr
    assert "sent 1 × twist" in once.stdout
    assert "clamped" in once.stdout and "0.5 m/s" in once.stdout, once.stdout
    stream = cli(port, "alice", "pub", "turtle1", "twist", '{"lx": 50}', "--rate", "10", "--duration", "1")
    assert stream.returncode == 0, stream.stdout + stream.stderr
    assert stream.stdout.count("clamped") == 1, stream.stdout  # the first twist of the stream, not all ten
    within = cli(port, "alice", "pub", "turtle1", "twist", '{"lx": 0.3}')
    assert within.returncode == 0 and "clamped" not in within.stdout, within.stdout


def test_pub_takes_the_ros_twist_shape(stack) -> None:
    """The rclpy-shaped SDK accepts {"linear": {"x": …}}; so does pub (the same converter)."""
    port, _log = stack
    out = cli(port, "alice", "pub", "turtle1", "twist", '{"linear": {"x": 0.2}, "angular": {"z": 0.1}}')
    assert out.returncode == 0 and "sent 1 × twist" in out.stdout, out.stdout + out.stderr
    fast = cli(port, "alice", "pub", "turtle1", "twist", '{"linear": {"x": 9}}')
    assert fast.returncode == 0 and "clamped" in fast.stdout, fast.stdout + fast.stderr


# -- a ROS name typo in a rule is said, by the bridge and by echo (issue 30 item 9) ------------------------------

def test_a_ros_name_typo_is_warned_about_and_echo_says_what_is_true(tmp_path) -> None:
    """`ros_topic: odm` used to pass silently: the bridge logged nothing and echo said "no rule publishes it"."""
    demo = (ROOT / "config" / "robots.yaml").read_text()
    assert "ros_topic: odom," in demo and "ros_service: reset\n" in demo
    fleet = tmp_path / "typo.yaml"
    fleet.write_text(demo.replace("ros_topic: odom,", "ros_topic: odm,").replace("ros_service: reset\n",
                                                                                  "ros_service: resett\n"))
    with turtle1_online(tmp_path, fleet=fleet) as port:
        log = tmp_path / "bridge.log"
        lines = _wait_line(log, 0, "the rule for call/reset", timeout=15)
        assert any("the rule for state/global_motion reads ROS topic /odm, which has no publisher "
                   "(did you mean /odom?)" in line and " WARNING " in line for line in lines), lines
        assert any("calls ROS service /resett, which has no server (did you mean /reset?)" in line
                   for line in lines), lines
        assert not any("state/robot_status reads" in line for line in lines), lines  # its topic is published
        out = cli(port, "bob", "echo", "turtle1", "global_motion", "-n", "1", "--timeout", "1")
        assert out.returncode == echo_cmd.EXIT_NOTHING, out.stdout + out.stderr
        assert ("the rule for global_motion reads ROS topic /odm, which has no publisher (did you mean /odom?)"
                in out.stderr), out.stderr
        assert "no rule" not in out.stderr
        info = cli(port, "bob", "info", "turtle1")
        assert info.returncode == 0 and "/odm, which has no publisher" in info.stdout, info.stdout + info.stderr
