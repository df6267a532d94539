"""The bridge's optional message trace (roslink_mqtt/bridge/trace.py), used by bench/hops.py."""

from __future__ import annotations

import subprocess
import sys

import orjson
import pytest

from roslink_mqtt.bridge import trace


@pytest.mark.unit
def test_marks_are_written_as_json_lines_in_order_and_bounded(tmp_path, monkeypatch) -> None:
    out = tmp_path / "trace.jsonl"
    monkeypatch.setattr(trace, "LIMIT", 3)
    t = trace.Trace(out)
    for stage in ("mqtt_in", "ros_out", "ros_in", "mqtt_out"):
        t.mark(stage, "roslink/turtle1/state/x")
    t.write()
    events = [orjson.loads(line) for line in out.read_bytes().splitlines()]
    assert [e["stage"] for e in events] == ["mqtt_in", "ros_out", "ros_in"]  # the fourth is over the limit
    assert [e["ns"] for e in events] == sorted(e["ns"] for e in events)


def test_tracing_is_off_unless_the_environment_names_a_file(tmp_path) -> None:
    code = "from roslink_mqtt.bridge import trace; print(trace.TRACE is None)"
    env = {"PATH": "/usr/bin:/bin"}
    off = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=30)
    assert off.stdout.strip() == "True", off.stderr
    path = tmp_path / "t.jsonl"
    code_on = "from roslink_mqtt.bridge import trace; trace.TRACE.mark('mqtt_in', 'a/b')"
    on = subprocess.run([sys.executable, "-c", code_on], capture_output=True, text=True, timeout=30,
                        env={**env, trace.ENV: str(path)})
    assert on.returncode == 0, on.stderr
    assert orjson.loads(path.read_bytes())["topic"] == "a/b"  # written at exit
