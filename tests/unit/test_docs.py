"""Documentation stays true: the generated parts match the code."""

from __future__ import annotations

import re
from pathlib import Path

from roslink_mqtt.protocol import SPECS
from roslink_mqtt.protocol.reference import (
    BEGIN,
    BEGIN_CONTROL,
    BEGIN_VERBS,
    DOCUMENTED_BODIES,
    END,
    END_CONTROL,
    END_VERBS,
    render,
    render_control,
    render_verbs,
)
from roslink_mqtt.topics import Verb

DOCS = Path(__file__).resolve().parents[2] / "docs"


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
    for title, topic, cls in DOCUMENTED_BODIES:
        section = generated[generated.index(f"#### {title}\n"):]
        assert section.split("\n")[2] == (f"Topic: {topic}. Published with QoS {cls.QOS}, "
                                          f"{'retained' if cls.RETAINED else 'not retained'}.")
        for field in cls.FIELDS:
            assert f"| `{field.name}` |" in section
    assert "`roslink_version`" in generated and "read the message as version 2" in generated
    assert "| `client_id` | string, 1..128 characters |" in text  # the envelope header table


def test_verb_table_is_current() -> None:
    """docs/protocol.md lists every verb of the topic grammar, as coded."""
    text = (DOCS / "protocol.md").read_text()
    generated = text[text.index(BEGIN_VERBS): text.index(END_VERBS) + len(END_VERBS)]
    assert generated == render_verbs(), "regenerate: python -m roslink_mqtt.protocol.reference --write docs/…"
    for verb in Verb:
        assert f"| `{verb.value}` | `roslink/<robot>/{'from' if verb.sent_by_user else 'to'}/<user>/{verb.value}" \
            in generated


def test_control_operations_and_the_bridge_claim_are_documented_as_coded() -> None:
    """The lease's operations (topic levels) and the fields a starting bridge announces on state/bridge are
    written by hand in protocol.md's Control section: each one the code knows is there, and no other."""
    from roslink_mqtt.bridge.core.claim import CLAIM_FIELDS
    from roslink_mqtt.protocol.lease import ControlOp

    text = (DOCS / "protocol.md").read_text()
    control = text[text.index("* **Ask**"): text.index("## Robot description")]
    assert sorted(set(re.findall(r"control/(\w+)", control))) == sorted(op.value for op in ControlOp)
    bridges = control[control.index("* **Bridges**"):]
    named = re.findall(r"`(\w+)`", bridges[: bridges.index("; a")])
    assert named == [f.name for f in CLAIM_FIELDS]
    assert f"the same {['four', 'five', 'six'][len(CLAIM_FIELDS) - 4]} fields" in bridges
