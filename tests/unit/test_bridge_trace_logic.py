"""Pure logic of tests/integration/test_bridge_trace.py: no processes, no sockets."""

from __future__ import annotations

import orjson

from roslink_mqtt.bridge.core import trace


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
