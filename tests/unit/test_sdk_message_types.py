"""The SDK's message classes are source a type checker reads, and they follow the protocol schema.

They used to be built with ``make_dataclass`` at import time, invisible to
type checkers and IDEs. Now roslink_mqtt.client.message_codegen writes them
into messages.py; these tests fail when the schema changes and the block was
not regenerated, so the schema stays the one place a field is declared.
"""

from __future__ import annotations

import ast
import dataclasses

import pytest

from roslink_mqtt.client import message_codegen, messages
from roslink_mqtt.protocol import SPECS, Field, FieldKind


def test_generated_block_matches_the_schema() -> None:
    assert message_codegen.current(message_codegen.TARGET.read_text()) == message_codegen.render(), \
        "messages.py is stale: run python -m roslink_mqtt.client.message_codegen"
    assert message_codegen.main(["--check"]) == 0


def test_a_schema_change_is_caught(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    first = SPECS[0]
    grown = dataclasses.replace(first, fields=(*first.fields, Field("extra", FieldKind.FLOAT, 0.0, None, "new")))
    monkeypatch.setattr(message_codegen, "SPECS", (grown, *SPECS[1:]))
    assert message_codegen.main(["--check"]) == 1  # --check never writes
    assert "stale" in capsys.readouterr().err


def test_every_message_is_a_class_in_the_source() -> None:
    tree = ast.parse(message_codegen.TARGET.read_text())
    defined = {node.name for node in tree.body if isinstance(node, ast.ClassDef)}
    for spec in SPECS:
        name = message_codegen.class_name(spec)
        assert name in defined, f"{name} is not written out in messages.py"
        cls = messages.MESSAGE_CLASSES[spec.name]
        assert cls is getattr(messages, name) and cls.SPEC is spec and cls.MESSAGE_ID is spec.message_id


@pytest.mark.parametrize("spec", SPECS, ids=lambda spec: spec.name)
def test_fields_follow_the_spec(spec) -> None:
    cls = messages.MESSAGE_CLASSES[spec.name]
    own = [f for f in dataclasses.fields(cls) if not f.kw_only]  # the base's metadata fields are keyword-only
    expected = sorted(spec.fields, key=lambda f: not f.required)
    assert [f.name for f in own] == [f.name for f in expected]
    for field, schema in zip(own, expected, strict=True):
        assert field.metadata["doc"] == schema.doc
        if schema.required:
            assert field.default is dataclasses.MISSING
        else:
            assert field.default == (tuple(schema.default) if isinstance(schema.default, list) else schema.default)
