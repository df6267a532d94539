"""Decode a generic state payload of any rule encoding: ``json``, ``cbor`` or ``raw`` (docs/protocol.md).

A ros_to_mqtt rule publishes JSON unless its ``encoding`` says otherwise; the robot description names the
encoding of each state entry (``encoding``, left out for JSON). The three cannot be confused on the wire, so
:func:`sniff` tells them apart when the description is not at hand: JSON is an object (``{``), CBOR a map
(first byte 0xA0–0xBB, or 0xBF), raw a JPEG (FF D8 FF) or PNG (89 50 4E 47) file.

What each decodes to (:func:`decode_state`):

* ``json`` — the ROS message as a dict, rosbridge conventions (``uint8[]`` base64, ``"NaN"`` names).
* ``cbor`` — the same dict, but ``uint8[]``/``byte[]`` as :class:`bytes`, other numeric arrays (RFC 8746 typed
  arrays) as :class:`array.array` (``.tolist()`` for a list; ``numpy.frombuffer`` takes it without a copy),
  non-finite floats as floats. :func:`to_json_form` turns it into exactly what ``json`` would have given.
* ``raw`` — a ``sensor_msgs/msg/CompressedImage`` without its header: ``{"format": "jpeg" | "png" | "",
  "data": <the image bytes>}`` (the format told from the bytes; "" when they are neither).

``cbor2`` is needed for CBOR only, and imported only when a CBOR payload arrives.
"""

from __future__ import annotations

import array
import base64
import math
import sys
from typing import TYPE_CHECKING, Any

from ..protocol import ProtocolError, loads

if TYPE_CHECKING:
    from cbor2 import CBORTag

JSON, CBOR, RAW = "json", "cbor", "raw"
ENCODINGS = (JSON, CBOR, RAW)

# RFC 8746 typed-array tags → array.array typecode and element size. The bridge writes the little-endian ones
# (and a plain byte string for uint8[]); the big-endian ones are read too, for any other writer.
_TYPED: dict[int, tuple[str, int, bool]] = {}  # tag → (array.array typecode, element size, big-endian)


def _code(kind: str, size: int) -> str:
    """The array.array typecode of an element: kind ``u``/``i``/``f``, ``size`` bytes, on this platform."""
    codes = {"u": "BHILQ", "i": "bhilq", "f": "fd"}[kind]
    return next(c for c in codes if array.array(c).itemsize == size)


for _kind, _size, _big_tag in (("u", 1, 64), ("u", 2, 65), ("u", 4, 66), ("u", 8, 67), ("i", 1, 72), ("i", 2, 73),
                               ("i", 4, 74), ("i", 8, 75), ("f", 4, 81), ("f", 8, 82)):
    _TYPED[_big_tag] = (_code(_kind, _size), _size, _size > 1)
    if _size > 1:
        _TYPED[_big_tag + 4] = (_code(_kind, _size), _size, False)  # little-endian: 69-71, 77-79, 85, 86
_TYPED[68] = (_code("u", 1), 1, False)  # uint8, clamped

JPEG, PNG = b"\xff\xd8\xff", b"\x89PNG"


def sniff(payload: bytes) -> str:
    """The encoding of a generic state payload, told from its first bytes (JSON when in doubt)."""
    if not payload:
        return JSON
    first = payload[0]
    if 0xA0 <= first <= 0xBB or first == 0xBF:
        return CBOR
    if payload.startswith(JPEG) or payload.startswith(PNG):
        return RAW
    return JSON


def image_format(data: bytes) -> str:
    """``jpeg`` or ``png`` from the file's signature, else ``""``."""
    if data.startswith(JPEG):
        return "jpeg"
    if data.startswith(PNG):
        return "png"
    return ""


def cbor_loads(payload: bytes) -> Any:
    """A CBOR payload with its typed arrays as :class:`array.array` (ProtocolError if it is not CBOR)."""
    try:
        import cbor2
    except ImportError:
        raise ProtocolError("this state is CBOR: install cbor2 (pip install cbor2) to read it") from None
    try:
        value = cbor2.loads(payload)
    except Exception as err:  # noqa: BLE001 - cbor2's errors differ between versions
        raise ProtocolError(f"invalid CBOR: {err}") from None
    return _untag(value, cbor2.CBORTag)


def _untag(value: Any, tag_cls: type[CBORTag]) -> Any:
    if isinstance(value, dict):
        return {k: _untag(v, tag_cls) for k, v in value.items()}
    if isinstance(value, list):
        return [_untag(v, tag_cls) for v in value]
    if isinstance(value, tag_cls) and value.tag in _TYPED and isinstance(value.value, bytes):
        code, size, big = _TYPED[value.tag]
        if len(value.value) % size:
            raise ProtocolError(f"typed array (tag {value.tag}) of {len(value.value)} bytes, not a multiple of {size}")
        out = array.array(code, value.value)
        if size > 1 and big != (sys.byteorder == "big"):
            out.byteswap()
        return out
    return value


def decode_state(payload: bytes, encoding: str | None = None) -> Any:
    """A generic state payload as a dict (see the module); ``encoding`` None: told by :func:`sniff`."""
    encoding = encoding or sniff(payload)
    if encoding == RAW:
        return {"format": image_format(payload), "data": bytes(payload)}
    if encoding == CBOR:
        return cbor_loads(payload)
    if encoding == JSON:
        return loads(payload)
    raise ProtocolError(f"unknown state encoding '{encoding}' ({', '.join(ENCODINGS)})")


def _nf(x: float) -> Any:
    if math.isfinite(x):
        return x
    return "NaN" if x != x else ("Infinity" if x > 0 else "-Infinity")


def to_json_form(value: Any) -> Any:
    """A decoded CBOR state as the JSON encoding gives it: bytes → base64, typed arrays → lists, ∞/NaN → names."""
    if isinstance(value, dict):
        return {k: to_json_form(v) for k, v in value.items()}
    if isinstance(value, list):
        return [to_json_form(v) for v in value]
    if isinstance(value, (bytes, bytearray)):
        return base64.b64encode(value).decode("ascii")
    if isinstance(value, array.array):
        items = value.tolist()
        return [_nf(x) for x in items] if value.typecode in "fd" else items
    if isinstance(value, float):
        return _nf(value)
    return value
