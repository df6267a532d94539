"""The bridge's optional message trace (roslink_mqtt/bridge/core/trace.py), used by bench/hops.py."""

from __future__ import annotations

import subprocess
import sys

import orjson

from roslink_mqtt.bridge.core import trace


def test_tracing_is_off_unless_the_environment_names_a_file(tmp_path) -> None:
    code = "from roslink_mqtt.bridge.core import trace; print(trace.TRACE is None)"
    env = {"PATH": "/usr/bin:/bin"}
    off = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=30)
    assert off.stdout.strip() == "True", off.stderr
    path = tmp_path / "t.jsonl"
    code_on = "from roslink_mqtt.bridge.core import trace; trace.TRACE.mark('mqtt_in', 'a/b')"
    on = subprocess.run([sys.executable, "-c", code_on], capture_output=True, text=True, timeout=30,
                        env={**env, trace.ENV: str(path)})
    assert on.returncode == 0, on.stderr
    assert orjson.loads(path.read_bytes())["topic"] == "a/b"  # written at exit
