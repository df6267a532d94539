"""Documentation stays true: the generated parts match the code."""

from __future__ import annotations

from pathlib import Path

from roslink_mqtt.protocol import SPECS
from roslink_mqtt.protocol.control import CONTROL_BODIES
from roslink_mqtt.protocol.reference import BEGIN, BEGIN_CONTROL, END, END_CONTROL, render, render_control

DOCS = Path(__file__).resolve().parents[1] / "docs"


def test_protocol_reference_is_current() -> None:
    text = (DOCS / "protocol.md").read_text()
    generated = text[text.index(BEGIN): text.index(END) + len(END)]
    assert generated == render(), "regenerate: python -m roslink_mqtt.protocol.reference"
    for spec in SPECS:
        assert f"### {int(spec.message_id)} {spec.name}" in text


def test_control_body_reference_is_current() -> None:
    """Every control body (fields, topic, QoS, retain flag, id and version rules) is documented as coded."""
    text = (DOCS / "protocol.md").read_text()
    generated = text[text.index(BEGIN_CONTROL): text.index(END_CONTROL) + len(END_CONTROL)]
    assert generated == render_control(), "regenerate: python -m roslink_mqtt.protocol.reference --write docs/…"
    for title, topic, cls in CONTROL_BODIES:
        section = generated[generated.index(f"#### {title}\n"):]
        assert section.split("\n")[2] == (f"Topic: {topic}. Published with QoS {cls.QOS}, "
                                          f"{'retained' if cls.RETAINED else 'not retained'}.")
        for field in cls.FIELDS:
            assert f"| `{field.name}` |" in section
    assert "`roslink_version`" in generated and "read the message as version 2" in generated
    assert "| `client_id` | string, 1..128 characters |" in text  # the envelope header table
