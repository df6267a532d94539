"""Payload validation against a :class:`MessageSpec`.

Kept separate from the codec so the SDK can validate what it is about to send
with the same rules the bridge applies to what it receives.
"""

from __future__ import annotations

import binascii
import math
from typing import Any, TypeGuard

from ..compat import strict_b64decode
from .errors import ProtocolError
from .messages import Field, FieldKind, MessageSpec

MAX_LIST_ITEMS = 1_000_000


def printable(text: str) -> str:
    """``text`` with control characters escaped (``\\n``): a refusal's reason stays one line, whatever was sent."""
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else c.encode("unicode_escape").decode("ascii") for c in text)


def show_key(key: Any, limit: int = 64) -> str:
    """A field name from untrusted input, as error messages show it: one line, bounded."""
    text = printable(str(key))
    return text if len(text) <= limit else text[: limit - 3] + "..."


def describe(value: Any) -> str:
    """Short, safe rendering of an offending value for error messages."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        text = value if len(value) <= 32 else value[:29] + "..."
        return '"' + printable(text) + '"'
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, list):
        return f"an array of {len(value)}"
    if isinstance(value, dict):
        return "an object"
    return type(value).__name__


def _is_number(value: object) -> TypeGuard[int | float]:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _check_number(path: str, value: object) -> float:
    if not _is_number(value):
        raise ProtocolError(f"{path}: expected number, got {describe(value)}")
    if isinstance(value, float) and not math.isfinite(value):
        raise ProtocolError(f"{path}: non-finite number {value!r} is not allowed")
    return value


def _check_int(path: str, value: object, bounds: tuple[int, int] | None) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        else:
            raise ProtocolError(f"{path}: expected integer, got {describe(value)}")
    if bounds is not None and not bounds[0] <= value <= bounds[1]:
        raise ProtocolError(f"{path}: expected integer {bounds[0]}..{bounds[1]}, got {value}")
    return value


def _check_list(path: str, value: Any) -> list[Any]:
    if not isinstance(value, list):
        raise ProtocolError(f"{path}: expected array, got {describe(value)}")
    if len(value) > MAX_LIST_ITEMS:
        raise ProtocolError(f"{path}: array of {len(value)} items exceeds {MAX_LIST_ITEMS}")
    return value


def check_field(path: str, field: Field, value: Any) -> Any:
    """Return the value in canonical form, or raise ProtocolError naming ``path``."""
    kind = field.kind
    if kind is FieldKind.FLOAT:
        return _check_number(path, value)
    if kind is FieldKind.INT:
        return _check_int(path, value, field.bounds)
    if kind is FieldKind.STR:
        if not isinstance(value, str):
            raise ProtocolError(f"{path}: expected string, got {describe(value)}")
        return value
    if kind is FieldKind.BOOL:
        if not isinstance(value, bool):
            raise ProtocolError(f"{path}: expected boolean, got {describe(value)}")
        return value
    if kind is FieldKind.FLOAT_LIST:
        for i, item in enumerate(_check_list(path, value)):
            _check_number(f"{path}[{i}]", item)
        return value
    if kind is FieldKind.RANGE_LIST:
        for i, item in enumerate(_check_list(path, value)):
            if item is not None:
                _check_number(f"{path}[{i}]", item)
        return value
    if kind is FieldKind.INT_LIST:
        for i, item in enumerate(_check_list(path, value)):
            _check_int(f"{path}[{i}]", item, field.bounds)
        return value
    if kind is FieldKind.BASE64:
        if not isinstance(value, str):
            raise ProtocolError(f"{path}: expected base64 string, got {describe(value)}")
        try:
            strict_b64decode(value)
        except (binascii.Error, ValueError) as err:
            raise ProtocolError(f"{path}: invalid base64 ({err})") from None
        return value
    raise AssertionError(kind)  # pragma: no cover - every FieldKind is handled above


def validate_payload(spec: MessageSpec, payload: Any, path: str = "payload") -> dict[str, Any]:
    """Check ``payload`` against ``spec`` and return it with defaults filled in.

    Unknown fields are refused rather than ignored: a typo such as ``"lxx"`` in
    a velocity command must not silently become a zero.
    """
    if not isinstance(payload, dict):
        raise ProtocolError(f"{path}: expected object for {spec.name}, got {describe(payload)}")
    out: dict[str, Any] = {}
    matched = 0
    for field in spec.fields:
        if field.name in payload:
            matched += 1
            out[field.name] = check_field(f"{path}.{field.name}", field, payload[field.name])
        elif field.required:
            raise ProtocolError(f"{path}: missing field '{field.name}' for {spec.name}")
        else:
            out[field.name] = list(field.default) if isinstance(field.default, list) else field.default
    if matched != len(payload):
        unknown = sorted(k for k in payload if k not in out)
        known = ", ".join(f.name for f in spec.fields) or "none"
        raise ProtocolError(f"{path}: unknown field '{show_key(unknown[0])}' for {spec.name} (fields: {known})")
    return out
