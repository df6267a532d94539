"""A corpus of bad inputs: each is refused with ProtocolError naming what is wrong."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from roslink_mqtt.protocol import SPECS_BY_ID, MessageId, ProtocolError, decode, encode

TWIST = MessageId.TWIST

CORPUS = [
    # (bytes, topic-implied id, expected fragment of the message)
    (b"", TWIST, "not JSON"),
    (b"not json", TWIST, "not JSON"),
    (b'{"lx": 0.1', TWIST, "not JSON"),
    (b"\xff\xfe", TWIST, "not JSON"),
    (b"[1, 2]", TWIST, "expected a JSON object, got an array of 2"),
    (b'"twist"', TWIST, "expected a JSON object"),
    (b"42", TWIST, "expected a JSON object"),
    (b'{"lx": 0.1}', None, "missing field 'message_id'"),
    (b'{"message_id": 77, "payload": {}}', None, "unknown message_id 77"),
    (b'{"message_id": "100", "payload": {}}', None, 'message_id: expected integer, got "100"'),
    (b'{"message_id": 100}', None, "missing field 'payload'"),
    (b'{"message_id": 101, "payload": {"x": 1, "y": 2}}', TWIST, "does not match the topic"),
    (b'{"message_id": 100, "payload": []}', None, "payload: expected object for twist"),
    (b'{"message_id": 101, "payload": {"x": 1}}', None, "missing field 'y' for go_to_waypoint"),
    (b'{"lx": "fast"}', TWIST, 'payload.lx: expected number, got "fast"'),
    (b'{"lx": true}', TWIST, "payload.lx: expected number, got true"),
    (b'{"lx": null}', TWIST, "payload.lx: expected number, got null"),
    (b'{"lx": 1e999}', TWIST, "non-finite number"),
    (b'{"lx": -1e400}', TWIST, "non-finite number"),
    (b'{"lx": NaN}', TWIST, "not JSON"),
    (b'{"lx": Infinity}', TWIST, "not JSON"),
    (b'{"lxx": 0.1}', TWIST, "unknown field 'lxx' for twist"),
    (b'{"message_id": 100, "payload": {}, "key": "secret"}', None, "field 'key' is not accepted"),
    (b'{"message_id": 100, "payload": {}, "extra": 1}', None, "unknown field 'extra' in envelope"),
    (b'{"message_id": 100, "payload": {}, "sequence_number": -1}', None, "sequence_number: expected integer 0.."),
    (b'{"message_id": 100, "payload": {}, "system_id": 70000}', None, "system_id: expected integer 0..65535"),
    (b'{"message_id": 100, "payload": {}, "sequence_number": 1.5}', None, "sequence_number: expected integer"),
    (b'{"mode": 3}', MessageId.SET_MODE, "payload.mode: expected string, got 3"),
    (b'{"altitude": "high"}', MessageId.TAKEOFF, "payload.altitude: expected number"),
    (b'{"frame_type": 300, "x": 1, "y": 2}', MessageId.GO_TO_WAYPOINT, "frame_type: expected integer 0..255, got 300"),
    (b'{"frame_type": 1.5, "x": 1, "y": 2}', MessageId.GO_TO_WAYPOINT, "frame_type: expected integer"),
    (b'{"width": 1, "height": 1, "resolution": 0.1, "origin_x": 0, "origin_y": 0, "data": [101]}',
     MessageId.MAP, "payload.data[0]: expected integer -1..100, got 101"),
    (b'{"format": "jpeg", "data": "!!notbase64"}', MessageId.IMAGE, "payload.data: invalid base64"),
    (b'{"format": "jpeg", "data": 5}', MessageId.IMAGE, "payload.data: expected base64 string"),
    (b'{"range_min": 0, "range_max": 1, "angle_min": 0, "angle_max": 1, "angle_increment": 0.1, '
     b'"ranges": [1, "x"]}', MessageId.RANGE_FINDER_DATA, 'payload.ranges[1]: expected number, got "x"'),
    (b'{"range_min": 0, "range_max": 1, "angle_min": 0, "angle_max": 1, "angle_increment": 0.1, '
     b'"ranges": 3}', MessageId.RANGE_FINDER_DATA, "payload.ranges: expected array, got 3"),
]


@pytest.mark.parametrize(("data", "expected", "fragment"), CORPUS, ids=[repr(c[0][:30]) for c in CORPUS])
def test_malformed_input_is_refused_with_reason(data: bytes, expected, fragment: str) -> None:
    with pytest.raises(ProtocolError) as info:
        decode(data, expected)
    assert fragment in str(info.value)


def test_oversized_payload_refused_before_parsing() -> None:
    with pytest.raises(ProtocolError, match="oversized payload: 2001 bytes exceeds the limit of 2000"):
        decode(b" " * 2001, TWIST, max_bytes=2000)


def test_null_ranges_mean_no_return() -> None:
    msg = decode(b'{"range_min": 0, "range_max": 1, "angle_min": 0, "angle_max": 1, "angle_increment": 0.1, '
                 b'"ranges": [0.5, null]}', MessageId.RANGE_FINDER_DATA)
    assert msg.payload["ranges"] == [0.5, None]


MAX_REASON = 300  # a reason goes back to the sender in an error report: it names the problem, not the input


def check_decode(data: bytes, expected: int | None) -> None:
    """Either a ProtocolError with a one-line reason of bounded length, or a valid message of the expected kind
    that survives a round trip; never another exception, an empty reason or a half-checked envelope."""
    try:
        envelope = decode(data, expected)
    except ProtocolError as err:
        reason = str(err)
        assert reason.strip() and "\n" not in reason and len(reason) <= MAX_REASON, repr(reason)
        return
    if expected is not None:
        assert envelope.message_id == expected
    assert envelope.message_id in SPECS_BY_ID
    again = decode(encode(envelope), envelope.message_id)  # (a bare payload's missing number is written as 0)
    assert (again.message_id, again.payload, again.client_id) == \
        (envelope.message_id, envelope.payload, envelope.client_id)


@settings(max_examples=200, deadline=None)  # 200 random cases a run keep the unit suite in seconds
@given(st.binary(max_size=200) | st.text(max_size=200).map(str.encode))
def test_random_bytes_raise_only_protocol_error(data: bytes) -> None:
    for expected in (None, TWIST, MessageId.HEARTBEAT):
        check_decode(data, expected)


json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False, allow_infinity=False) | st.text(),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4),
    max_leaves=12)


@settings(max_examples=200, deadline=None)  # 200 random cases a run keep the unit suite in seconds
@given(st.dictionaries(st.sampled_from(["lx", "ly", "az", "message_id", "payload", "sequence_number", "x"]),
                       json_values, max_size=5))
def test_random_json_objects_raise_only_protocol_error(obj) -> None:
    import orjson

    try:
        data = orjson.dumps(obj)
    except TypeError:  # integers beyond 64 bits cannot be encoded; not an input we can receive
        return
    for expected in (None, TWIST):
        check_decode(data, expected)


def test_error_reply_shape() -> None:
    import orjson

    from roslink_mqtt.protocol import error_reply

    body = orjson.loads(error_reply("roslink/t/from/a/cmd/twist", "payload.lx: bad", message_id=100,
                                    sequence_number=5))
    assert body == {"topic": "roslink/t/from/a/cmd/twist", "error": "payload.lx: bad", "message_id": 100,
                    "sequence_number": 5}
    assert orjson.loads(error_reply("t", "x")) == {"topic": "t", "error": "x"}


@pytest.mark.parametrize("data", [
    b'{"payload": {"\\n": null}}',  # found by the property test above: a field name with a newline
    b'{"message_id": 100, "payload": {"lx": 0}, "\\u2028\\n": 1}',
    b'{"message_id": 100, "payload": {"lx": "fa\\nst"}}',
])
def test_reasons_stay_one_line_whatever_the_names_and_values(data: bytes) -> None:
    check_decode(data, 100)
