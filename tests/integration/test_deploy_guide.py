"""docs/deploy.md as written, each step on its machine: three network namespaces made here ("cloud", "robot",
"laptop"), the robot and the laptop each joined to the cloud by a veth pair (10.77.1.0/24, 10.77.2.0/24, this
machine only), ``broker.example.net`` resolving to the cloud in each (``ip netns exec`` mounts
/etc/netns/<name>/hosts over /etc/hosts), a HOME of its own per machine, the repository's venv on PATH.

The guide's ```` ```sh ns <host> ```` blocks run in order with ``bash -e``; ``serve=1`` blocks are servers (the
broker, the bridge) kept running until the end once they say they are up. The robot's own drivers are the
simulator here, started in the robot's namespace. Between the machines the test copies what the guide's ``scp``
lines copy. At the end nothing of the broker listens in clear text: only 8883, TLS.
"""

from __future__ import annotations

import json
import math
import os
import re
import shutil
import signal
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.support.procs import ROOT
from tests.support.waits import wait_until

pytestmark = pytest.mark.timeout(240)

DOC = ROOT / "docs" / "deploy.md"
FENCE = re.compile(r"^```sh ns ([a-z]+)([^\n]*)\n(.*?)^```[ \t]*$", re.M | re.S)
NAME = "broker.example.net"
LINKS = {"robot": "10.77.1", "laptop": "10.77.2"}  # each host's link to the cloud: .1 the cloud, .2 the host
READY = {"cloud": "listening on mqtts://", "robot": "connected to mqtts://"}  # a server block is up
COPIES = {  # the guide's scp lines: (from host, to host, files under ~/roslink), each copied once it exists
    "robot": ("cloud", ["robot-files/turtle1.yaml", "turtle1.password", "ca.pem"]),
    "laptop": ("cloud", ["alice.password", "ca.pem", "bob.password"]),
}


@dataclass(frozen=True)
class Step:
    host: str
    serve: bool
    code: str
    line: int


def steps() -> list[Step]:
    text = DOC.read_text()
    return [Step(m.group(1), "serve=1" in m.group(2), m.group(3), text.count("\n", 0, m.start()) + 1)
            for m in FENCE.finditer(text)]


def _ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True, capture_output=True, timeout=10)


@dataclass
class Machines:
    names: dict[str, str]  # host → namespace
    homes: dict[str, Path]
    servers: list[subprocess.Popen]

    def env(self, host: str) -> dict[str, str]:
        return {**os.environ, "HOME": str(self.homes[host]), "PATH": f"{Path(sys.executable).parent}:"
                f"{os.environ.get('PATH', '')}", "PYTHONUNBUFFERED": "1"}

    def command(self, host: str, script: str) -> list[str]:
        return ["ip", "netns", "exec", self.names[host], "bash", "-e", "-c", script]


@pytest.fixture
def machines(tmp_path: Path) -> Iterator[Machines]:
    if os.geteuid() != 0 or shutil.which("ip") is None:
        pytest.skip("network namespaces need root and iproute2 (CI has both)")
    tag = f"{os.getpid() % 100000}"
    names = {host: f"rl{host[0]}{tag}" for host in ("cloud", "robot", "laptop")}
    homes = {host: tmp_path / host for host in names}
    made: list[str] = []
    try:
        for host, ns in names.items():
            _ip("netns", "add", ns)
            made.append(ns)
            _ip("-n", ns, "link", "set", "lo", "up")
            homes[host].mkdir()
        for host, net in LINKS.items():
            here, there = f"v{host[0]}{tag}h", f"v{host[0]}{tag}c"
            _ip("link", "add", here, "netns", names[host], "type", "veth", "peer", "name", there, "netns",
                names["cloud"])
            _ip("-n", names[host], "addr", "add", f"{net}.2/24", "dev", here)
            _ip("-n", names["cloud"], "addr", "add", f"{net}.1/24", "dev", there)
            _ip("-n", names[host], "link", "set", here, "up")
            _ip("-n", names["cloud"], "link", "set", there, "up")
        for host, ns in names.items():  # the server's name, as each machine resolves it
            etc = Path("/etc/netns") / ns
            etc.mkdir(parents=True, exist_ok=True)
            where = "127.0.0.1" if host == "cloud" else f"{LINKS[host]}.1"
            (etc / "hosts").write_text(f"127.0.0.1 localhost\n{where} {NAME}\n")
        yield Machines(names, homes, [])
    finally:
        for ns in made:
            subprocess.run(["ip", "netns", "pids", ns], capture_output=True, timeout=10)
            pids = subprocess.run(["ip", "netns", "pids", ns], capture_output=True, text=True, timeout=10).stdout
            for pid in pids.split():
                try:
                    os.kill(int(pid), signal.SIGKILL)
                except (ProcessLookupError, ValueError):
                    pass
            subprocess.run(["ip", "netns", "del", ns], capture_output=True, timeout=10)
            shutil.rmtree(Path("/etc/netns") / ns, ignore_errors=True)


def _start_server(machines: Machines, step: Step, log: Path) -> subprocess.Popen:
    with open(log, "wb") as out:
        proc = subprocess.Popen(machines.command(step.host, step.code), env=machines.env(step.host), stdout=out,
                                stderr=subprocess.STDOUT, start_new_session=True)
    machines.servers.append(proc)
    ready = READY[step.host]
    try:
        wait_until(f"docs/deploy.md:{step.line} ({step.host}) up or ended",
                   lambda: ready in log.read_text(errors="replace") or proc.poll() is not None, timeout=45, period=0.2)
    except AssertionError:
        raise AssertionError(f"docs/deploy.md:{step.line} ({step.host}) not up in 45 s:\n{log.read_text()[-3000:]}") \
            from None
    assert ready in log.read_text(errors="replace"), \
        f"docs/deploy.md:{step.line} ({step.host}) exited:\n{log.read_text()[-3000:]}"
    return proc


def _copy(machines: Machines, host: str) -> None:
    source, files = COPIES[host]
    for name in files:
        origin = machines.homes[source] / "roslink" / name
        target = machines.homes[host] / "roslink" / Path(name).name
        if origin.exists() and not target.exists():
            target.parent.mkdir(exist_ok=True)
            shutil.copy2(origin, target)


def test_the_deploy_guide_runs_on_three_machines(machines: Machines, tmp_path: Path) -> None:
    guide = steps()
    assert [s.host for s in guide] == ["cloud", "cloud", "cloud", "robot", "laptop", "cloud", "laptop"], guide
    sim = None
    try:
        for n, step in enumerate(guide):
            if step.host in COPIES:
                _copy(machines, step.host)
            if step.host == "robot" and sim is None:  # the robot's drivers: odom out, cmd_vel in
                with open(tmp_path / "sim.log", "wb") as out:
                    sim = subprocess.Popen(machines.command("robot", f"exec {sys.executable} -m roslink_mqtt.sim"),
                                           env=machines.env("robot"), cwd=ROOT, stdout=out,
                                           stderr=subprocess.STDOUT, start_new_session=True)
                machines.servers.append(sim)
            if step.serve:
                _start_server(machines, step, tmp_path / f"server-{n}-{step.host}.log")
                continue
            done = subprocess.run(machines.command(step.host, step.code), env=machines.env(step.host),
                                  capture_output=True, text=True, timeout=120)
            out = done.stdout + done.stderr
            assert done.returncode == 0, f"docs/deploy.md:{step.line} ({step.host}) exit {done.returncode}:\n{out}"
            assert "Traceback" not in out, f"docs/deploy.md:{step.line} ({step.host}):\n{out}"
            if step.host == "laptop":
                assert re.search(r"^turtle1 +active", done.stdout, re.M), out  # online, through TLS
        # the laptop's twist drove the robot: its pose moved from the origin
        echo = subprocess.run(machines.command("laptop", guide[-1].code.split("roslink-mqtt robots")[0] +
                                               "roslink-mqtt echo turtle1 global_motion --count 1 --timeout 10"),
                              env=machines.env("laptop"), capture_output=True, text=True, timeout=60)
        pose = json.loads(echo.stdout.strip().splitlines()[-1])
        assert math.hypot(pose["x"], pose["y"]) > 0.1, pose
        # TLS only: from the laptop, the server answers on 8883 and on nothing in clear text
        probe = ("import socket, sys\n"
                 "def open_(p):\n"
                 "    with socket.socket() as s:\n"
                 "        s.settimeout(3)\n"
                 f"        return s.connect_ex(('{LINKS['laptop']}.1', p)) == 0\n"
                 "sys.exit(0 if open_(8883) and not open_(1883) and not open_(8083) else 1)\n")
        ports = subprocess.run(["ip", "netns", "exec", machines.names["laptop"], sys.executable, "-c", probe],
                               capture_output=True, timeout=30)
        assert ports.returncode == 0, "the server listens in clear text (1883 or 8083), or not on 8883"
    finally:
        for proc in reversed(machines.servers):
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGINT)
        for proc in machines.servers:
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(5)
