"""The dashboard reads bodies from the protocol's own declarations: the generated protocol.js is current, and
static/body.js (run by node) reads every case as protocol/body.py's lenient reader does."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path
from typing import Any

import orjson
import pytest

from roslink_mqtt.dashboard.protocol_js import OUTPUT, body_key, render
from roslink_mqtt.protocol import ProtocolError
from roslink_mqtt.protocol.body import read
from roslink_mqtt.protocol.reference import _CONTROL_EXAMPLES, DOCUMENTED_BODIES

pytestmark = pytest.mark.unit
ROOT = Path(__file__).resolve().parents[2]
# values that are wrong for most fields; no floats with a zero fraction (JSON in JavaScript cannot tell 1.0 from 1)
ODD_VALUES: list[Any] = [None, True, 7, -1, 1.5, "", "x", "operator", [], ["a"], [1], {}, {"a": 1}]


def test_protocol_js_is_current() -> None:
    assert OUTPUT.read_text() == render(), "regenerate: python -m roslink_mqtt.dashboard.protocol_js --write"


def python_reads(cls: type, body: Any) -> Any:
    try:
        got = read(cls.FIELDS, body, shape="-", strict=False)  # type: ignore[attr-defined]
    except ProtocolError:
        return None
    return orjson.loads(orjson.dumps(got))  # tuples as arrays, as JSON has them


def cases() -> list[dict[str, Any]]:
    out = []
    for title, _topic, cls in DOCUMENTED_BODIES:
        example = orjson.loads(_CONTROL_EXAMPLES[cls].to_json())
        inputs: list[Any] = [example, {}, [], "x", {**example, "unknown": 1}]
        for field in cls.FIELDS:
            inputs.append({k: v for k, v in example.items() if k != field.name})
            inputs += [{**example, field.name: value} for value in ODD_VALUES]
        out += [{"body": body_key(title), "input": i, "expected": python_reads(cls, i)} for i in inputs]
    return out


def test_the_dashboard_reads_bodies_as_python_does(tmp_path: Path) -> None:
    node = shutil.which("node")
    assert node, "node is needed (make install)"
    table = tmp_path / "cases.json"
    table.write_bytes(orjson.dumps(cases()))
    run = subprocess.run([node, "--test", str(ROOT / "tests" / "js")], capture_output=True, text=True, timeout=60,
                         env={**os.environ, "ROSLINK_BODY_CASES": str(table)}, check=False)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-2000:]
    assert "# pass 2" in run.stdout and "# skipped 0" in run.stdout, run.stdout[-2000:]
