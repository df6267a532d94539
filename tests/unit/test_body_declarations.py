"""Bodies declared once (protocol/body.py): each spec's checks, strict and lenient reads, ids read first."""

from __future__ import annotations

import math

import orjson
import pytest

from roslink_mqtt.protocol import ProtocolError
from roslink_mqtt.protocol.body import (
    SENDER,
    AnyJson,
    BodyField,
    Boolean,
    Choice,
    Id,
    Integer,
    Levels,
    Nullable,
    Number,
    Obj,
    Objects,
    Strings,
    Text,
    read,
)
from roslink_mqtt.protocol.reference import DOCUMENTED_BODIES

pytestmark = pytest.mark.unit

FIELDS = (
    BodyField("id", Id(8), True, "the request", names="request"),
    BodyField("n", Integer(0, 10), False, "a count", 1),
    BodyField("tags", Strings(3), False, "labels", ()),
    BodyField("args", Obj(), False, "arguments", {}),
    BodyField("client_id", SENDER, False, "who", None, names="sender"),
)
SHAPE = 'expected {"id": …}'


@pytest.mark.parametrize(("spec", "good", "bad"), [
    (Text(1, 3), ["a", "abc"], ["", "abcd", 1, None]),
    (Integer(0, 5), [0, 5], [-1, 6, 1.0, True, "1"]),
    (Number(0, 1, low_open=True), [0.5, 1], [0, 1.5, math.inf, math.nan, True, "0.5"]),
    (Boolean(), [True, False], [0, 1, "true", None]),
    (Obj(1), [{}, {"a": 1}], [[], {"a": 1, "b": 2}, None]),
    (Objects(), [[], [{}]], [[1], {}, None]),
    (Strings(2, non_empty=True), [[], ["a", "b"]], [["a", "b", "c"], [""], [1], "a"]),
    (Choice(("a", "b")), ["a"], ["c", 1, None]),
    (Levels((10, 20)), [10, 20], [15, True, 10.0]),
    (Id(3), ["abc", 7], ["", "abcd", True, 1.5, None]),
    (Id(3, strings_only=True), ["abc"], [7]),
    (Nullable(Integer()), [None, 3], ["3"]),
    (AnyJson(), [None, [1], {"a": 1}], []),
])
def test_each_spec_takes_what_it_says_and_nothing_else(spec: object, good: list, bad: list) -> None:
    for value in good:
        got = read((BodyField("v", spec, True, ""),), {"v": value}, shape=SHAPE)  # type: ignore[arg-type]
        assert got["v"] == (tuple(value) if isinstance(spec, (Strings, Objects)) else value)
    for value in bad:
        with pytest.raises(ProtocolError, match=r"^v: expected "):
            read((BodyField("v", spec, True, ""),), {"v": value}, shape=SHAPE)  # type: ignore[arg-type]


def test_a_strict_read_refuses_unknown_fields_and_names_the_request_and_its_sender() -> None:
    assert read(FIELDS, b'{"id": "a"}', shape=SHAPE) == {"id": "a", "n": 1, "tags": (), "args": {},
                                                          "client_id": None}
    with pytest.raises(ProtocolError) as err:
        read(FIELDS, {"id": "a", "n": 11, "client_id": "laptop"}, shape=SHAPE)
    assert str(err.value) == "n: expected integer 0..10, got 11"
    assert (err.value.request_id, err.value.client_id) == ("a", "laptop")
    with pytest.raises(ProtocolError) as err:
        read(FIELDS, {"id": "a", "nn": 1}, shape=SHAPE)
    assert str(err.value) == "unknown field 'nn' (fields: id, n, tags, args, client_id)"
    with pytest.raises(ProtocolError) as err:  # a bad id names no request, but still its sender
        read(FIELDS, {"id": "toolongforit", "client_id": "laptop"}, shape=SHAPE)
    assert (err.value.request_id, err.value.client_id) == (None, "laptop")
    with pytest.raises(ProtocolError) as err:
        read(FIELDS, {"client_id": "laptop"}, shape=SHAPE)
    assert str(err.value) == f"id: missing; {SHAPE}" and err.value.client_id == "laptop"
    with pytest.raises(ProtocolError, match=r"^expected \{\"id\": …\}, got an array of 0$"):
        read(FIELDS, b"[]", shape=SHAPE)


def test_a_lenient_read_ignores_unknown_fields_and_takes_defaults_for_malformed_ones() -> None:
    got = read(FIELDS, {"id": "a", "n": "many", "tags": 3, "new": 1, "client_id": ""}, shape=SHAPE, strict=False,
               what="thing")
    assert got == {"id": "a", "n": 1, "tags": (), "args": {}, "client_id": None}
    with pytest.raises(ProtocolError, match=r"^thing: id: expected string, 1\.\.8 characters or integer, got 1\.5$"):
        read(FIELDS, {"id": 1.5}, shape=SHAPE, strict=False, what="thing")  # required, no default


def test_defaults_are_fresh_values() -> None:
    first, second = read(FIELDS, {"id": "a"}, shape=SHAPE), read(FIELDS, {"id": "b"}, shape=SHAPE)
    first["args"]["x"] = 1
    assert second["args"] == {}


def test_every_documented_body_is_declared_and_reads_its_own_json() -> None:
    """Each body's FIELDS are specs (the docs' type column is theirs), and its example survives a round trip."""
    from roslink_mqtt.protocol.reference import _CONTROL_EXAMPLES

    for _title, _topic, cls in DOCUMENTED_BODIES:
        assert all(isinstance(f, BodyField) and f.type for f in cls.FIELDS), cls
        example = _CONTROL_EXAMPLES[cls]
        assert cls.from_json(example.to_json()) == example, cls
        assert set(orjson.loads(example.to_json())) <= {f.name for f in cls.FIELDS}, cls
