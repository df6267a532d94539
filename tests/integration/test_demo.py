"""`make demo` runs end to end and shows the real thing (broker, robot, bridge, clients)."""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest

from tests.support.procs import ROOT
from tests.support.waits import wait_until

# The demo's default ports (1883, 8083) are the docs' too: under `pytest -n`, these and tests/integration/
# test_docs_run.py run on one worker, one after the other (tests/conftest.py: SAME_WORKER). The demo runs in this
# run's ROS domain: one it picked itself could be another worker's (free for a moment between two tests), and its
# robot would take their commands.
pytestmark = pytest.mark.timeout(120)
OUR_DOMAIN = ("--ros-domain-id", os.environ["ROS_DOMAIN_ID"])


def nobody_listens(port: int) -> bool:
    """No process accepts connections on ``port`` (binding it is no test: the broker's closed connections may
    leave it in TIME_WAIT for a minute)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.settimeout(2)
        return s.connect_ex(("127.0.0.1", port)) != 0


SCENE = ("bob sees roslink/turtle1/heartbeat: turtle1 ACTIVE",
         "bob sees roslink/turtle1/state/global_motion",
         "bob sees roslink/turtle1/state/range_finder_data",
         "payload.lx: expected number, got \"fast\"",
         "/to/alice/reply/reset", '"result":true',
         'goal_status: {"id":"demo-goal","status":"accepted"}', "feedback: ",
         'result: {"id":"demo-goal","status":"succeeded","result":{"sequence":[0,1,1,2,3,5,8]}}',
         '/to/alice/param_reply/sim_robot: {"id":"demo-speed","result":true,"values":{"max_speed":'
         '{"successful":true,"reason":""}}}', "the robot drives at vx=0.20 m/s",
         "dead-man")


def test_demo_plays_the_scene_serves_the_dashboard_and_stops_cleanly(tmp_path) -> None:
    """``make dashboard`` (``make demo`` plays the same scene, then ends): the whole scene with real processes, then
    the web dashboard until Ctrl-C; nothing is left running after it. One scene for both (the suite's time)."""
    proc = subprocess.Popen([sys.executable, "-m", "roslink_mqtt.demo", "--logs", str(tmp_path), "--dashboard",
                             "--dashboard-port", "0", *OUR_DOMAIN], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    lines: list[str] = []
    try:
        deadline = time.monotonic() + 100
        while time.monotonic() < deadline:
            line = proc.stdout.readline()
            if not line:
                break
            lines.append(line)
            if "Ctrl-C stops everything" in line:
                break
        text = "".join(lines)
        for expected in SCENE:
            assert expected in text, f"missing {expected!r} in:\n{text}"
        moved = [line for line in text.splitlines() if "the robot moved" in line]
        assert moved and float(moved[0].split("moved ")[1].split(" m")[0]) > 0.1, text
        url = re.search(r"open (http://127\.0\.0\.1:\d+/)", text)
        broker_port = int(re.search(r"broker on 127\.0\.0\.1:(\d+)", text).group(1))
        assert url, text
        with urllib.request.urlopen(url.group(1), timeout=5) as page:
            assert page.status == 200 and b"<html" in page.read().lower()
        with urllib.request.urlopen(url.group(1) + "vendor/mqtt.min.js", timeout=5) as bundle:
            assert bundle.status == 200
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            _kill_tree(proc.pid)
            proc.communicate()
    assert proc.returncode == 0, "".join(lines) + out
    assert "Done: stopping" in out
    assert nobody_listens(broker_port), "the broker outlived the demo"
    with pytest.raises(OSError):
        urllib.request.urlopen(url.group(1), timeout=2)


# -- the demo's processes never outlive it ------------------------------------------------------------------------

def _descendants(pid: int) -> dict[int, str]:
    """Every living process below ``pid`` (the demo's children sit in process groups of their own), with its
    command line."""
    parents: dict[int, int] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if fields[0] != "Z":
            parents[int(stat.parent.name)] = int(fields[1])
    below, todo = set(), [pid]
    while todo:
        parent = todo.pop()
        for child, ppid in parents.items():
            if ppid == parent and child not in below:
                below.add(child)
                todo.append(child)
    cmdlines = {}
    for child in below:
        try:
            cmdlines[child] = Path(f"/proc/{child}/cmdline").read_bytes().replace(b"\0", b" ").decode()
        except OSError:
            pass
    return cmdlines


def _child_running(pid: int, module: str, timeout: float = 10.0) -> int:
    """The process below ``pid`` that runs ``module`` (read from /proc until it shows: a busy machine may show it
    a moment late)."""
    started: dict[int, str] = {}

    def found() -> list[int]:
        started.clear()
        started.update(_descendants(pid))
        return [child for child, cmd in started.items() if module in cmd]

    try:
        return wait_until(f"{module} below pid {pid}", found, timeout=timeout, period=0.1)[0]
    except AssertionError as err:
        raise AssertionError(f"no {module} below pid {pid}: {started}") from err


def _kill_tree(pid: int) -> None:
    """A test that failed midway: SIGKILL the demo and everything below it (its children sit in sessions of their
    own, so killing the demo alone left a broker on the docs' port 1883 and a bridge in some ROS domain)."""
    below = list(_descendants(pid))
    for victim in [pid, *below]:
        try:
            os.kill(victim, signal.SIGKILL)
        except ProcessLookupError:
            pass


def _alive(pids) -> list[int]:
    return [p for p in pids if Path(f"/proc/{p}").exists() and "Z" not in
            (Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()[:1] or ["Z"])]


def _read_until(proc: subprocess.Popen, marker: str, timeout: float = 60) -> str:
    lines: list[str] = []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            break
        lines.append(line)
        if marker in line:
            return "".join(lines)
    raise AssertionError(f"{marker!r} not seen:\n{''.join(lines)}")


def _kill(pids) -> None:
    """A failed test leaves no orphans for the rest of the suite."""
    for pid in pids:
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass


def _wait_gone(pids, timeout: float = 15) -> list[int]:
    left = list(pids)

    def gone() -> bool:
        left[:] = _alive(pids)
        return not left

    try:
        wait_until("the processes gone", gone, timeout=timeout, period=0.1)
    except AssertionError:
        pass  # the caller kills and names what is left
    return left


@pytest.mark.parametrize("how", ["kill make (SIGTERM), no Node.js on PATH", "terminal closed (SIGHUP), ports taken"])
def test_make_demo_stops_every_process_it_started_on_sigterm_and_sighup(tmp_path, how) -> None:
    """``kill`` of ``make demo`` and a closed terminal stop the broker, sim and bridge (they used to be left running
    on 1883, and the next demo quietly moved to another port); a taken port is named with who holds it; without
    npm the demo says so and runs."""
    no_node = how.startswith("kill")
    args = ["--logs", str(tmp_path / "logs"), *OUR_DOMAIN]
    holders: list[socket.socket] = []
    if not no_node:  # hold the fleet's MQTT port, as an earlier demo left running would
        from roslink_mqtt.localproc import fleet_copy

        holder = socket.socket()
        holder.bind(("127.0.0.1", 0))
        holder.listen()
        holders.append(holder)
        taken = holder.getsockname()[1]
        args += ["--config", str(fleet_copy(tmp_path / "robots.yaml", ROOT / "config/robots.yaml", port=taken))]
    env = {**os.environ, "PATH": "/nonexistent"} if no_node else dict(os.environ)
    # -o: never rebuild the venv from inside a test, whatever pyproject.toml's time stamp says
    make = subprocess.Popen(["/usr/bin/make", "-s", "-o", ".venv/.installed", "demo", f"DEMO_ARGS={' '.join(args)}"],
                            cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)  # its own session: SIGHUP to the group is the closed terminal
    try:
        text = _read_until(make, "2. simulated robot and bridge")
        for module in ("roslink_mqtt.broker", "roslink_mqtt.sim", "roslink_mqtt.bridge"):
            _child_running(make.pid, module)
        started = _descendants(make.pid)
        names = " ".join(started.values())
        assert all(part in names for part in ("roslink_mqtt.broker", "roslink_mqtt.sim", "roslink_mqtt.bridge")), \
            started
        if no_node:
            assert "Node.js/npm not found: the demo runs without them" in text, text
        else:
            assert f"port {taken} (the fleet's MQTT port" in text and f"taken by pid {os.getpid()}" in text, text
        if no_node:
            os.kill(make.pid, signal.SIGTERM)
        else:
            os.killpg(make.pid, signal.SIGHUP)
        out, _ = make.communicate(timeout=30)
    finally:
        if make.poll() is None:
            _kill_tree(make.pid)
            make.communicate()
        for holder in holders:
            holder.close()
    left = _wait_gone(started)
    _kill(left)
    assert not left, f"left running after {how}: {[started[p] for p in left]}\n{text}{out}"
    assert "received; everything it started is stopped" in out, text + out


def test_a_child_that_dies_ends_the_demo_with_its_log(tmp_path) -> None:
    """A bridge that crashes mid-scene (a segfault once did) is reported with the end of its log, and the demo
    stops, instead of printing "(no result seen)" and carrying on."""
    demo = subprocess.Popen([sys.executable, "-m", "roslink_mqtt.demo", "--logs", str(tmp_path), *OUR_DOMAIN], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        text = _read_until(demo, "2. simulated robot and bridge")
        bridge = _child_running(demo.pid, "roslink_mqtt.bridge.main")
        started = _descendants(demo.pid)
        os.kill(bridge, signal.SIGSEGV)
        t_kill = time.monotonic()
        out, _ = demo.communicate(timeout=30)
        took = time.monotonic() - t_kill
    finally:
        if demo.poll() is None:
            _kill_tree(demo.pid)
            demo.communicate()
    assert demo.returncode == 1, text + out
    assert "the bridge exited (killed by SIGSEGV) while the scene ran" in out, text + out
    assert f"{tmp_path / 'bridge.log'}:" in out and "stopped the other processes" in out, out
    assert took < 10, f"the demo took {took:.1f} s to notice"
    left = _wait_gone(started)
    _kill(left)
    assert not left, "processes outlived the demo"


VDA_SCENE = ("connection: ONLINE; factsheet: ROSLink sim (DIFF, CARRIER), instant actions: startPause, stopPause, "
             "cancelOrder, stateRequest, factsheetRequest",
             "reached a at", "reached b at", "reached c at",
             "waits at c, the decision point, and asks for more (newBaseRequest)",
             "order o1 done", "demo-cancel: FAILED, warning noOrderToCancel")


def test_the_vda5050_demo_drives_an_order_to_its_end(tmp_path) -> None:
    """``make vda5050``: a master control (plain MQTT) drives the simulated robot through an order with a horizon
    and an update, then asks to cancel with nothing left; the demo exits 0 and stops everything."""
    done = subprocess.run([sys.executable, "-m", "roslink_mqtt.demo", "--vda5050", "--logs", str(tmp_path),
                           *OUR_DOMAIN], cwd=ROOT, capture_output=True, text=True, timeout=100)
    text = done.stdout + done.stderr
    assert done.returncode == 0, text
    for expected in VDA_SCENE:
        assert expected in text, f"missing {expected!r} in:\n{text}"
    end = re.search(r"reached d at \(([-\d.]+), ([-\d.]+)\)", text)
    assert end and abs(float(end.group(2)) - 1.0) < 0.2, text  # one metre up from where it started (the centre)
    assert nobody_listens(int(re.search(r"broker on 127\.0\.0\.1:(\d+)", text).group(1)))
