"""Documentation stays true: the generated parts match the code."""

from __future__ import annotations

from pathlib import Path

from roslink_mqtt.protocol import SPECS
from roslink_mqtt.protocol.reference import BEGIN, END, render

DOCS = Path(__file__).resolve().parents[1] / "docs"


def test_protocol_reference_is_current() -> None:
    text = (DOCS / "protocol.md").read_text()
    generated = text[text.index(BEGIN): text.index(END) + len(END)]
    assert generated == render(), "regenerate: python -m roslink_mqtt.protocol.reference"
    for spec in SPECS:
        assert f"### {int(spec.message_id)} {spec.name}" in text
