"""Control bodies (``protocol.control``): every refusal is worded exactly, and every body survives a round trip.

The bridge sends these reasons back verbatim on reply and error topics, so their wording is part of the
protocol; the round trips prove ``to_json`` writes what ``from_json`` reads (the SDK and the bridge are
two ends of one wire).
"""

from __future__ import annotations

import re
from pathlib import Path

import orjson
import pytest
from hypothesis import given
from hypothesis import strategies as st

from roslink_mqtt.protocol import ProtocolError
from roslink_mqtt.protocol.control import (
    CONTROL_BODIES,
    Advertisement,
    CallReply,
    CallRequest,
    ProviderRequest,
    ProviderResponse,
    ServiceOffer,
)

json_scalars = st.none() | st.booleans() | st.integers(-(2**53), 2**53) | st.text(max_size=20) \
    | st.floats(allow_nan=False, allow_infinity=False)
json_values = st.recursive(json_scalars, lambda inner: st.lists(inner, max_size=3)
                           | st.dictionaries(st.text(max_size=8), inner, max_size=3), max_leaves=8)
objects = st.dictionaries(st.text(min_size=1, max_size=8), json_values, max_size=4)
client_ids = st.text(min_size=1, max_size=128)
call_ids = st.none() | st.integers(-(2**53), 2**53) | st.text(max_size=128)


def refusal(cls: type, body: object) -> str:
    raw = body if isinstance(body, bytes) else orjson.dumps(body)
    with pytest.raises(ProtocolError) as err:
        cls.from_json(raw)
    return str(err.value)


@pytest.mark.parametrize(("body", "reason"), [
    ([1], 'expected a JSON object {"id": …, "args": {…}}, got an array of 1'),
    ({"id": "1", "arg": {}}, "unknown field 'arg' (fields: id, args, client_id)"),
    ({"id": "1", "client_id": ""}, "client_id: expected string, 1..128 characters, got \"\""),
    ({"id": True}, "id: expected string (≤ 128 characters) or integer or null, got true"),
    ({"id": 1.5}, "id: expected string (≤ 128 characters) or integer or null, got 1.5"),
    ({"id": "x" * 129}, "id: expected string (≤ 128 characters) or integer or null, got "
                        '"xxxxxxxxxxxxxxxxxxxxxxxxxxxxx..."'),
    ({"id": "1", "args": []}, "args: expected object, got an array of 0"),
    (b"{", None),  # not JSON: the codec's reason
])
def test_call_request_refusals(body: object, reason: str | None) -> None:
    got = refusal(CallRequest, body)
    if reason is not None:
        assert got == reason
    else:
        assert got.startswith("not JSON")


def test_call_request_defaults() -> None:
    assert CallRequest.from_json(b"{}") == CallRequest(None, {}, None)


@given(call_ids, objects, st.none() | client_ids)
def test_call_request_round_trip(call_id: object, args: dict, client_id: str | None) -> None:
    call = CallRequest(call_id, args, client_id)
    assert CallRequest.from_json(call.to_json()) == call


@pytest.mark.parametrize(("body", "reason"), [
    ("ok", 'reply: expected a JSON object {"id": …, "result": …}, got "ok"'),
])
def test_call_reply_refusals(body: object, reason: str) -> None:
    assert refusal(CallReply, body) == reason


def test_call_reply_is_as_lenient_as_the_sdk_always_was() -> None:
    """Unknown fields are ignored, non-object values read as {}, any result but true is a failure."""
    assert CallReply.from_json(b'{"id": "a", "result": true, "values": 3, "new": 1}') == CallReply("a", True, {})
    assert CallReply.from_json(b'{"id": "a", "result": "yes", "error": ""}') == CallReply("a", False, error=None)
    assert CallReply.from_json(b'{"id": "a", "result": false, "error": 7}').error is None  # not a reason
    assert CallReply.from_json(b'{"id": [1], "result": true}').id is None  # no call has that id


@given(call_ids, st.booleans(), objects, st.text(min_size=1, max_size=40), st.none() | client_ids)
def test_call_reply_round_trip(call_id: object, ok: bool, values: dict, error: str, client_id: str | None) -> None:
    reply = CallReply(call_id, True, values, client_id=client_id) if ok else \
        CallReply(call_id, False, error=error, client_id=client_id)
    assert CallReply.from_json(reply.to_json()) == reply


def test_call_reply_wire_format() -> None:
    """Byte for byte what the bridge has always sent (key order included)."""
    assert CallReply(7, True, {"a": 1}).to_json() == b'{"id":7,"result":true,"values":{"a":1}}'
    assert CallReply(None, False, error="no", client_id="c").to_json() == \
        b'{"id":null,"result":false,"error":"no","client_id":"c"}'


@pytest.mark.parametrize(("body", "reason"), [
    ([], 'expected {"type": "pkg/srv/Type"} (optional "timeout", "client_id"), got an array of 0'),
    ({"timeout": 1}, 'type: missing; expected {"type": "pkg/srv/Type"} (optional "timeout", "client_id")'),
    ({"type": "a/srv/B", "tmeout": 1}, "unknown field 'tmeout' (fields: type, timeout, client_id)"),
    ({"type": "a/srv/B", "client_id": 3}, "client_id: expected string or null, got 3"),
    ({"type": "a/srv/B", "timeout": 0}, "timeout: expected number, 0 < value ≤ 3600, got 0"),
    ({"type": "a/srv/B", "timeout": 3600.5}, "timeout: expected number, 0 < value ≤ 3600, got 3600.5"),
    ({"type": "a/srv/B", "timeout": True}, "timeout: expected number, 0 < value ≤ 3600, got true"),
    ({"type": "a/srv/B", "timeout": "5"}, 'timeout: expected number, 0 < value ≤ 3600, got "5"'),
    ({"type": "std_msgs/msg/Bool"}, "'std_msgs/msg/Bool' is not a service type (pkg/srv/Type)"),
])
def test_service_offer_refusals(body: object, reason: str) -> None:
    assert refusal(ServiceOffer, body) == reason


def test_service_offer_defaults() -> None:
    assert ServiceOffer.from_json(b'{"type": "a/srv/B", "client_id": null}') == ServiceOffer("a/srv/B", 5.0, None)
    assert ServiceOffer.from_json(b'{"type": "a/srv/B", "timeout": 3600}').timeout == 3600.0


@given(st.from_regex(r"[a-z_]{1,8}/srv/[A-Z][a-zA-Z]{0,8}", fullmatch=True),
       st.floats(min_value=1e-3, max_value=3600), st.none() | client_ids)
def test_service_offer_round_trip(srv_type: str, timeout: float, client_id: str | None) -> None:
    offer = ServiceOffer(srv_type, timeout, client_id)
    assert ServiceOffer.from_json(offer.to_json()) == offer


def test_service_offer_wire_format() -> None:
    """What the SDK has always published (type, timeout, client_id in that order)."""
    assert ServiceOffer("a/srv/B", 5.0, "me").to_json() == b'{"type":"a/srv/B","timeout":5.0,"client_id":"me"}'


@pytest.mark.parametrize(("body", "reason"), [
    (3, 'expected {"id": …, "args": {…}}, got 3'),
    ({"args": {}}, "provider request: id: missing (expected string)"),
])
def test_provider_request_refusals(body: object, reason: str) -> None:
    assert refusal(ProviderRequest, body) == reason


def test_provider_request_defaults() -> None:
    assert ProviderRequest.from_json(b'{"id": "r-1", "args": null, "later": 1}') == ProviderRequest("r-1", {})
    # read leniently, like every body a client reads: a malformed optional field is as if absent
    assert ProviderRequest.from_json(b'{"id": "r-1", "args": [1], "client_id": 1}') == ProviderRequest("r-1", {})


@given(st.text(max_size=40), objects, st.none() | client_ids)
def test_provider_request_round_trip(call_id: str, args: dict, client_id: str | None) -> None:
    request = ProviderRequest(call_id, args, client_id)
    assert ProviderRequest.from_json(request.to_json()) == request


@pytest.mark.parametrize(("body", "reason"), [
    ("x", 'expected {"id": …, "result": true, "values": {…}}, got "x"'),
    ({"result": True}, "id: missing (expected string)"),
])
def test_provider_response_refusals(body: object, reason: str) -> None:
    assert refusal(ProviderResponse, body) == reason


def test_provider_response_reads_as_the_bridge_always_did() -> None:
    """Any id (matched only if a string), result false = failure with a default reason, values checked later."""
    assert ProviderResponse.from_json(b'{"id": [1]}') == ProviderResponse([1], True, None)
    failed = ProviderResponse.from_json(b'{"id": "r-1", "result": false}')
    assert not failed.result and failed.failure == "provider reported failure"
    assert ProviderResponse.from_json(b'{"id": "r-1", "result": false, "error": null}').failure == \
        "provider reported failure"
    assert ProviderResponse.from_json(b'{"id": "r-1", "result": 0, "values": 5}').values == 5  # result 0 is not false


@given(json_values, st.booleans(), objects, st.text(min_size=1, max_size=40), st.none() | client_ids)
def test_provider_response_round_trip(call_id: object, ok: bool, values: dict, error: str,
                                      client_id: str | None) -> None:
    response = ProviderResponse(call_id, True, values, client_id=client_id) if ok else \
        ProviderResponse(call_id, False, error=error, client_id=client_id)
    assert ProviderResponse.from_json(response.to_json()) == response


@pytest.mark.parametrize(("body", "reason"), [
    ([], 'expected {"type": "pkg/msg/Type", "client_id": "<presence client id>"}, got an array of 0'),
    ({"type": 1}, "type: expected string `pkg/msg/Type`, got 1"),
    ({"type": "a/msg/B", "qos": 1}, "unknown field 'qos' (fields: type, client_id)"),
    ({"type": "a/msg/B", "client_id": None}, "client_id: expected string, got null"),
    ({"type": "a/msg/B", "client_id": 5}, "client_id: expected string, got 5"),
])
def test_advertisement_refusals(body: object, reason: str) -> None:
    assert refusal(Advertisement, body) == reason


@given(st.text(min_size=1, max_size=30), st.none() | st.text(max_size=128))
def test_advertisement_round_trip(ros_type: str, client_id: str | None) -> None:
    advert = Advertisement(ros_type, client_id)
    assert Advertisement.from_json(advert.to_json()) == advert


def test_every_body_is_documented_and_frozen() -> None:
    """Each control type is in the rendered table list, and its documented fields are the ones it writes."""
    names = {cls for _title, _topic, cls in CONTROL_BODIES}
    assert {CallRequest, CallReply, ServiceOffer, ProviderRequest, ProviderResponse, Advertisement} <= names
    for cls in names:
        assert cls.__dataclass_params__.frozen
        assert cls.__doc__


def test_unknown_roslink_version_is_accepted_not_compared() -> None:
    """What docs/protocol.md says a peer does with another version: reads the message, refuses only out of range."""
    from roslink_mqtt.protocol import decode

    assert decode(b'{"roslink_version": 9, "message_id": 100, "payload": {"lx": 0.1}}').payload["lx"] == 0.1
    with pytest.raises(ProtocolError, match=r"^roslink_version: expected integer 0\.\.255, got 256$"):
        decode(b'{"roslink_version": 256, "message_id": 100, "payload": {}}')


# Reading or building a control body field by field outside protocol.control: dict literals with a body's keys,
# .get() of a body's keys. ROSLink envelopes (protocol/codec.py) and message payloads are not control bodies.
HAND_CHECK = re.compile(r'\{"id":|"args":|\.get\("(id|args|result|values|type|timeout|topic|error|message_id|'
                        r'sequence_number|role|services)"|\["(id|args)"\]')


def test_no_module_outside_protocol_control_checks_a_control_body_by_hand() -> None:
    root = Path(__file__).resolve().parents[2]
    hits = {str(path.relative_to(root)) for path in (root / "roslink_mqtt").rglob("*.py")
            if path.parent.name != "protocol" and HAND_CHECK.search(path.read_text())}
    assert hits == set(), f"parse and write control bodies with roslink_mqtt.protocol.control: {sorted(hits)}"
