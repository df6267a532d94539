"""Property tests: every ROSLink message survives encode → decode unchanged."""

from __future__ import annotations

import base64

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from roslink_mqtt.protocol import (
    SPECS,
    Envelope,
    FieldKind,
    MessageSpec,
    decode,
    encode,
    encode_message,
)

finite = st.floats(allow_nan=False, allow_infinity=False, width=64)


def field_strategy(field) -> st.SearchStrategy:
    lo, hi = field.bounds or (-(2**31), 2**31 - 1)
    return {
        FieldKind.INT: st.integers(lo, hi),
        FieldKind.FLOAT: finite | st.integers(-(10**6), 10**6),
        FieldKind.STR: st.text(max_size=40),
        FieldKind.BOOL: st.booleans(),
        FieldKind.FLOAT_LIST: st.lists(finite, max_size=50),
        FieldKind.RANGE_LIST: st.lists(st.none() | finite, max_size=50),
        FieldKind.INT_LIST: st.lists(st.integers(lo, hi), max_size=50),
        FieldKind.BASE64: st.binary(max_size=200).map(lambda b: base64.b64encode(b).decode()),
    }[field.kind]


def payloads(spec: MessageSpec) -> st.SearchStrategy:
    required = {f.name: field_strategy(f) for f in spec.fields if f.required}
    optional = {f.name: field_strategy(f) for f in spec.fields if not f.required}
    return st.fixed_dictionaries(required, optional=optional)


@pytest.mark.parametrize("spec", SPECS, ids=lambda s: s.name)
def test_every_message_round_trips(spec: MessageSpec) -> None:
    @settings(max_examples=60, deadline=None)
    @given(payload=payloads(spec), seq=st.integers(0, 2**32 - 1), system_id=st.integers(0, 65535))
    def check(payload, seq, system_id):
        wire = encode_message(spec.message_id, dict(payload), system_id=system_id, sequence_number=seq)
        got = decode(wire)
        assert got.message_id == spec.message_id
        assert got.sequence_number == seq and got.system_id == system_id
        expected = spec.defaults() | payload
        assert got.payload == expected
        # A bare payload on a topic that names the message decodes to the same payload.
        bare = decode(encode(Envelope(spec.message_id, got.payload)).split(b'"payload":', 1)[1][:-1],
                      spec.message_id)
        assert bare.payload == expected and bare.sequence_number is None

    check()


def test_specs_cover_every_design_message_id() -> None:
    ids = sorted(int(s.message_id) for s in SPECS)
    assert ids == [0, 1, 2, 3, 4, 5, 6, 7, *range(100, 110)]
    assert len({s.name for s in SPECS}) == len(SPECS)
