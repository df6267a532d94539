"""`make demo` runs end to end and shows the real thing (broker, robot, bridge, clients)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from .support.procs import ROOT

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
                     "dead-man"):
        assert expected in text, f"missing {expected!r} in:\n{text}"
    moved = [line for line in text.splitlines() if "the robot moved" in line]
    assert moved and float(moved[0].split("moved ")[1].split(" m")[0]) > 0.1, text
