"""The `roslink-mqtt` command line against a real stack (embedded broker, sim robot, bridge)."""

from __future__ import annotations

import os
import subprocess
import sys
import time

import orjson
import pytest

from .support.procs import ROOT
from .support.robot_stack import turtle1_online

pytestmark = pytest.mark.timeout(120)


@pytest.fixture(scope="module")
def port(tmp_path_factory):
    work = tmp_path_factory.mktemp("cli")
    with turtle1_online(work) as broker_port:
        yield broker_port


def cli(port: int, user: str, *args: str, timeout: float = 30) -> subprocess.CompletedProcess:
    env = {**os.environ, "ROSLINK_PASSWORD": f"{user}-demo"}
    return subprocess.run([sys.executable, "-m", "roslink_mqtt.cli.main", *args, "--url", f"mqtt://127.0.0.1:{port}",
                           "-u", user], capture_output=True, text=True, env=env, cwd=ROOT, timeout=timeout,
                          stdin=subprocess.DEVNULL)


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


def test_pub_stream_moves_robot_and_call_resets_it(port) -> None:
    out = cli(port, "alice", "pub", "turtle1", "twist", '{"lx": 0.5}', "--rate", "10", "--duration", "1.5")
    assert out.returncode == 0 and "sent 15 × twist" in out.stdout, out.stdout + out.stderr
    time.sleep(0.3)
    motion = orjson.loads(cli(port, "bob", "echo", "turtle1", "global_motion", "-n", "1").stdout)
    assert abs(motion["x"]) > 0.2 or abs(motion["y"]) > 0.2
    reset = cli(port, "alice", "call", "turtle1", "reset")
    assert reset.returncode == 0 and '"success": true' in reset.stdout, reset.stdout + reset.stderr


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
