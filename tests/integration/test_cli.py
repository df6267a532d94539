"""The `roslink-mqtt` command line against a real stack (embedded broker, sim robot, bridge)."""

from __future__ import annotations

import math
import os
import subprocess
import sys

import orjson
import pytest

from tests.support.procs import ROOT
from tests.support.robot_stack import turtle1_online
from tests.support.waits import wait_until

pytestmark = pytest.mark.timeout(120)


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    return tmp_path_factory.mktemp("cli")


@pytest.fixture(scope="module")
def port(work):
    with turtle1_online(work) as broker_port:  # its bridge runs from turtle1's robot file (fleet split)
        yield broker_port


def cli(port: int, user: str, *args: str, timeout: float = 30) -> subprocess.CompletedProcess:
    env = {**os.environ, "ROSLINK_PASSWORD": f"{user}-demo"}
    return subprocess.run([sys.executable, "-m", "roslink_mqtt.cli.main", *args, "--url", f"mqtt://127.0.0.1:{port}",
                           "-u", user], capture_output=True, text=True, env=env, cwd=ROOT, timeout=timeout,
                          stdin=subprocess.DEVNULL)


def test_the_bridge_runs_from_its_robot_file_which_holds_no_password_hash(port, work) -> None:
    """``fleet split``'s robot file: no login's hash, no other robot's key, no users; the stack's bridge runs from
    it, takes turtle1's grants from the (embedded) broker, and they hold (an operator's call runs, a viewer's is
    refused)."""
    from roslink_mqtt.config import load_fleet

    robot_file = work / "robot-files" / "turtle1.yaml"
    text = robot_file.read_text()
    assert "$7$" not in text and "password:" not in text, text
    assert "demo-key-turtle2" not in text and "carol" not in text and "turtle2" not in text, text
    assert robot_file.stat().st_mode & 0o777 == 0o600
    fleet = load_fleet(robot_file)
    assert fleet.robot_file == "turtle1" and list(fleet.robots) == ["turtle1"]
    assert fleet.users == {} and fleet.grants_pending and "alice" not in text and "users:" not in text
    assert "grants from broker: 3 users may see turtle1 (admin:operator, alice:operator, bob:viewer)" in \
        (work / "bridge.log").read_text()
    _reset(port)
    refused = cli(port, "bob", "call", "turtle1", "reset")
    assert refused.returncode != 0, refused.stdout


def test_robots_lists_granted_robots_only(port) -> None:
    out = cli(port, "alice", "robots")
    assert out.returncode == 0, out.stderr
    assert "turtle1" in out.stdout and "active" in out.stdout and "turtle2" not in out.stdout
    nothing = cli(port, "carol", "robots", "--wait", "0.5")  # turtle2 has no bridge running
    assert "turtle1" not in nothing.stdout


def test_echo_prints_state_as_json(port) -> None:
    out = cli(port, "bob", "echo", "turtle1", "global_motion", "-n", "2", "--timeout", "10")
    assert out.returncode == 0, out.stderr
    lines = out.stdout.strip().splitlines()
    assert len(lines) == 2 and {"x", "y", "yaw"} <= set(orjson.loads(lines[0]))


def _motion(port: int) -> dict:
    out = cli(port, "bob", "echo", "turtle1", "global_motion", "-n", "1", "--timeout", "10")
    assert out.returncode == 0, out.stderr
    return orjson.loads(out.stdout)


def _pose(port: int) -> tuple[float, float, float]:
    motion = _motion(port)
    return motion["x"], motion["y"], motion["yaw"]


def _centred_pose(port: int) -> tuple[float, float, float]:
    """turtle1's pose once it shows at the room centre (a reset reaches the state stream a moment later)."""
    poses: list[tuple[float, float, float]] = []

    def centred() -> bool:
        poses.append(_pose(port))
        return abs(poses[-1][0]) < 0.05 and abs(poses[-1][1]) < 0.05

    try:
        wait_until("turtle1 at the room centre", centred, timeout=15)
    except AssertionError as e:
        raise AssertionError(f"{e}: {poses[-1]}") from None
    return poses[-1]


def _reset(port: int) -> None:
    def found():  # a bridge just started finds the sim's reset server a moment later (longer on a busy machine)
        reset = cli(port, "alice", "call", "turtle1", "reset")
        return reset if "has no server" not in reset.stdout + reset.stderr else None

    reset = wait_until("the bridge to find the sim's reset server", found, timeout=20, period=0.5)
    assert reset.returncode == 0 and '"success": true' in reset.stdout, reset.stdout + reset.stderr


def test_pub_stream_moves_robot_and_call_resets_it(port) -> None:
    # turtle1 is shared by this module's tests: start from the room centre and measure the displacement.
    _reset(port)
    x0, y0, yaw0 = _centred_pose(port)
    assert abs(x0) < 0.05 and abs(y0) < 0.05, (x0, y0)
    out = cli(port, "alice", "pub", "turtle1", "twist", '{"lx": 0.5}', "--rate", "10", "--duration", "1.5")
    assert out.returncode == 0 and "sent 15 × twist" in out.stdout, out.stdout + out.stderr
    # the dead-man (command_timeout 1.0 s) stops it: its motion then says so
    stopped = wait_until("turtle1 stopped by the dead-man",
                         lambda: (m := _motion(port))["vx"] == 0 and m["wz"] == 0 and m, timeout=15)
    x1, y1, yaw1 = stopped["x"], stopped["y"], stopped["yaw"]
    ahead = (x1 - x0) * math.cos(yaw0) + (y1 - y0) * math.sin(yaw0)
    aside = -(x1 - x0) * math.sin(yaw0) + (y1 - y0) * math.cos(yaw0)
    # 0.5 m/s for 1.5 s = 0.75 m straight ahead, plus at most the dead-man's 1.0 s of coasting.
    assert 0.6 < ahead < 1.3 and abs(aside) < 0.05 and abs(yaw1 - yaw0) < 0.05, (x0, y0, yaw0, x1, y1, yaw1)
    _reset(port)
    x2, y2, _ = _centred_pose(port)
    assert abs(x2) < 0.05 and abs(y2) < 0.05, (x2, y2)  # back at the centre


def test_clear_errors(port) -> None:
    bad = cli(port, "alice", "pub", "turtle1", "twist", '{"lx": "fast"}')
    assert bad.returncode == 1 and 'expected number, got "fast"' in bad.stdout
    viewer = cli(port, "bob", "call", "turtle1", "reset", "--timeout", "2")
    assert viewer.returncode == 1  # the broker drops a viewer's call to a non-read-only service
    wrong = subprocess.run([sys.executable, "-m", "roslink_mqtt.cli.main", "robots", "--url",
                            f"mqtt://127.0.0.1:{port}", "-u", "alice"], capture_output=True, text=True,
                           env={**os.environ, "ROSLINK_PASSWORD": "nope"}, cwd=ROOT, timeout=30,
                           stdin=subprocess.DEVNULL)
    assert wrong.returncode != 0 and "cannot connect" in wrong.stderr
