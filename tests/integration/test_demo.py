"""`make demo` runs end to end and shows the real thing (broker, robot, bridge, clients)."""

from __future__ import annotations

import re
import signal
import socket
import subprocess
import sys
import time
import urllib.request

import pytest

from tests.support.procs import ROOT

pytestmark = pytest.mark.timeout(120)


def test_demo_runs(tmp_path) -> None:
    out = subprocess.run([sys.executable, "-m", "roslink_mqtt.demo", "--logs", str(tmp_path)], cwd=ROOT,
                         capture_output=True, text=True, timeout=100)
    text = out.stdout + out.stderr
    assert out.returncode == 0, text
    for expected in ("bob sees roslink/turtle1/heartbeat: turtle1 ACTIVE",
                     "bob sees roslink/turtle1/state/global_motion",
                     "bob sees roslink/turtle1/state/range_finder_data",
                     "payload.lx: expected number, got \"fast\"",
                     "/to/alice/reply/reset", '"result":true',
                     'goal_status: {"id":"demo-goal","status":"accepted"}', "feedback: ",
                     'result: {"id":"demo-goal","status":"succeeded","result":{"sequence":[0,1,1,2,3,5,8]}}',
                     '/to/alice/param_reply/sim_robot: {"id":"demo-speed","result":true,"values":{"max_speed":'
                     '{"successful":true,"reason":""}}}', "the robot drives at vx=0.20 m/s",
                     "dead-man"):
        assert expected in text, f"missing {expected!r} in:\n{text}"
    moved = [line for line in text.splitlines() if "the robot moved" in line]
    assert moved and float(moved[0].split("moved ")[1].split(" m")[0]) > 0.1, text


def nobody_listens(port: int) -> bool:
    """No process accepts connections on ``port`` (binding it is no test: the broker's closed connections may
    leave it in TIME_WAIT for a minute)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.settimeout(2)
        return s.connect_ex(("127.0.0.1", port)) != 0


def test_demo_dashboard_mode_serves_the_page_and_stops_cleanly(tmp_path) -> None:
    """``make dashboard``: the scene plus the web dashboard until Ctrl-C; nothing is left running after it."""
    proc = subprocess.Popen([sys.executable, "-m", "roslink_mqtt.demo", "--logs", str(tmp_path), "--dashboard",
                             "--dashboard-port", "0"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)
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
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, "".join(lines) + out
    assert "Done: stopping" in out
    assert nobody_listens(broker_port), "the broker outlived the demo"
    with pytest.raises(OSError):
        urllib.request.urlopen(url.group(1), timeout=2)
