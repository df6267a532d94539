"""ROS message ↔ JSON-ready dict, with one specialised converter built per type.

``to_dict`` is generated Python source per message type (attribute reads,
``tolist()`` for arrays, base64 for byte arrays), compiled once and cached, so
the hot ROS→MQTT path does no per-message introspection. ``from_dict`` walks a
table of checkers built once per type; it is strict because its input is untrusted:
unknown fields, wrong types, out-of-range integers, wrong array lengths and
bad base64 are :class:`ConversionError` naming the field path.

JSON conventions (those rosbridge clients know): nested messages are objects,
``uint8[]``/``byte[]`` are base64 strings, time is ``{"sec", "nanosec"}``.
JSON has no NaN or infinity, so non-finite floats travel as the strings
``"NaN"``, ``"Infinity"`` and ``"-Infinity"`` and round-trip exactly.

``to_cbor`` (a rule's ``encoding: cbor``, docs/protocol.md "State encodings") builds the same object with
numeric arrays kept binary: ``uint8[]``/``byte[]`` a CBOR byte string, other integer and float arrays an
RFC 8746 typed array (a tag over their little-endian bytes), and non-finite floats as CBOR's own NaN/±∞.
"""

from __future__ import annotations

import array
import base64
import binascii
import math
import struct
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, cast

import numpy as np
import orjson
from rosidl_parser import definition as d

from ...protocol.validate import describe, show_key
from ...ros_names import interface_name
from ..core.refusals import ConversionError as ConversionError  # the converters raise it: callers name it here
from ..core.ros_types import load_interface

_pack_f = struct.Struct("<f").pack
NON_FINITE = {"NaN": math.nan, "Infinity": math.inf, "-Infinity": -math.inf}
_INT_RANGES = {
    "int8": (-(2**7), 2**7 - 1), "uint8": (0, 2**8 - 1), "int16": (-(2**15), 2**15 - 1), "uint16": (0, 2**16 - 1),
    "int32": (-(2**31), 2**31 - 1), "uint32": (0, 2**32 - 1), "int64": (-(2**63), 2**63 - 1),
    "uint64": (0, 2**64 - 1), "char": (0, 255), "wchar": (0, 2**16 - 1),
}
_FLOATS = ("float", "double", "long double")
_BYTE_LIKE = ("uint8", "octet")  # carried as base64


def _nf(x: float) -> Any:
    """JSON form of a float: itself when finite, else its name."""
    if x != x:
        return "NaN"
    return "Infinity" if x > 0 else "-Infinity"


def _nf_list(values: list[float]) -> list[Any]:
    return [v if math.isfinite(v) else _nf(v) for v in values]


def _b64(data: Any) -> str:
    if isinstance(data, (bytes, bytearray)):
        raw = bytes(data)
    elif isinstance(data, array.array) or hasattr(data, "tobytes"):
        raw = data.tobytes()
    else:  # list of 1-byte bytes objects (byte[]) or ints
        raw = b"".join(x if isinstance(x, bytes) else bytes((x,)) for x in data)
    return base64.b64encode(raw).decode("ascii")


def _namespaced(t: d.NamespacedType) -> type:
    return load_interface(interface_name(t.namespaces, t.name))


@dataclass
class Converter:
    """Both directions for one ROS message type."""

    ros_type: type
    to_dict: Callable[[Any], dict[str, Any]]  # plain Python values only
    from_dict: Callable[[Any], Any]
    _to_obj: Callable[[Any], dict[str, Any]]  # float arrays stay numpy views (for orjson)

    _cbor_obj: Callable[[Any], dict[str, Any]] | None = None  # built on first use: few types are sent as CBOR

    def to_cbor_obj(self, msg: Any) -> dict[str, Any]:
        """``msg`` as the object ``to_cbor`` encodes (bytes and ``CBORTag`` typed arrays inside)."""
        build = self._cbor_obj
        if build is None:
            build = self._cbor_obj = _build_to_dict(self.ros_type, numpy=False, cbor=True)
        return build(msg)

    def to_cbor(self, msg: Any) -> bytes:
        """CBOR bytes of ``msg``: the ``encoding: cbor`` path of ROS→MQTT rules."""
        return cbor_dumps(self.to_cbor_obj(msg))

    def to_json(self, msg: Any) -> bytes:
        """JSON bytes of ``msg``: the hot path of ROS→MQTT rules.

        Float arrays are handed to orjson as zero-copy numpy views, which it
        writes in their shortest form (float32 ``0.1`` stays ``0.1``); that is
        2–3× faster than going through Python lists for a laser scan.
        """
        return orjson.dumps(self._to_obj(msg), option=orjson.OPT_SERIALIZE_NUMPY)


_CACHE: dict[type, Converter] = {}


def converter_for(cls: type) -> Converter:
    """The converter for ``cls``, built on first use and cached for the process."""
    conv = _CACHE.get(cls)
    if conv is None:
        conv = Converter(cls, _build_to_dict(cls, numpy=False), _top_level(_Reader(cls)),
                         _build_to_dict(cls, numpy=True))
        _CACHE[cls] = conv
    return conv


def _float_view(values: Any) -> Any:
    """A numpy view of a float array (array.array or ndarray) if all finite, else a list with names."""
    view = values if type(values) is np.ndarray else np.frombuffer(values, dtype=values.typecode)
    if np.isfinite(view).all():
        return view
    return _nf_list(view.tolist())


def raw_bytes(data: Any) -> bytes:
    """The bytes of a ``uint8[]``/``byte[]`` field (array.array, numpy array, bytes or list of 1-byte bytes)."""
    if isinstance(data, bytes):
        return data
    if isinstance(data, bytearray):
        return bytes(data)
    if isinstance(data, array.array) or hasattr(data, "tobytes"):
        raw: bytes = data.tobytes()  # array.array's or numpy's
        return raw
    return b"".join(x if isinstance(x, bytes) else bytes((x,)) for x in data)


# RFC 8746 typed-array tags, little-endian (what x86 and ARM hold in memory, so no byte swapping anywhere):
# ROS element type → (tag, numpy dtype). uint8/octet arrays are a plain byte string instead (no tag).
TYPED_ARRAY_TAGS: dict[str, tuple[int, str]] = {
    "int8": (72, "<i1"), "uint16": (69, "<u2"), "int16": (77, "<i2"), "uint32": (70, "<u4"),
    "int32": (78, "<i4"), "uint64": (71, "<u8"), "int64": (79, "<i8"), "float": (85, "<f4"),
    "double": (86, "<f8"),
}


def cbor_dumps(obj: Any) -> bytes:
    import cbor2

    return cbor2.dumps(obj)


def _typed_array(tag: int, dtype: str) -> Callable[[Any], Any]:
    from cbor2 import CBORTag

    def typed(values: Any) -> Any:
        return CBORTag(tag, np.asarray(values, dtype=dtype).tobytes())
    return typed


# -- ROS → dict: generated source ------------------------------------------------------

def _build_to_dict(cls: type[Any], numpy: bool, cbor: bool = False) -> Callable[[Any], dict[str, Any]]:
    env: dict[str, Any] = {"_nf": _nf, "_nf_list": _nf_list, "_b64": _b64, "isfinite": math.isfinite,
                           "all": all, "map": map, "_float_view": _float_view, "_raw": raw_bytes}
    if cbor:
        return _build_to_cbor(cls, env)
    nested = "_to_obj" if numpy else "to_dict"
    items = []
    pre = []  # statements computing array values before the dict literal
    for i, (name, slot) in enumerate(zip(cls.get_fields_and_field_types(), cls.SLOT_TYPES, strict=True)):
        attr = f"m.{name}"
        if isinstance(slot, d.BasicType):
            if slot.typename in _FLOATS:
                pre.append(f"v{i} = {attr}\n    if not isfinite(v{i}): v{i} = _nf(v{i})")
                items.append(f"{name!r}: v{i}")
            elif slot.typename == "octet":
                items.append(f"{name!r}: {attr}[0]")  # bytes of length 1 -> int
            else:
                items.append(f"{name!r}: {attr}")
        elif isinstance(slot, d.AbstractGenericString):
            items.append(f"{name!r}: {attr}")
        elif isinstance(slot, d.NamespacedType):
            env[f"c{i}"] = getattr(converter_for(_namespaced(slot)), nested)
            items.append(f"{name!r}: c{i}({attr})")
        elif isinstance(slot, d.AbstractNestedType):
            inner = slot.value_type
            if isinstance(inner, d.BasicType) and inner.typename in _BYTE_LIKE:
                items.append(f"{name!r}: _b64({attr})")
            elif isinstance(inner, d.BasicType) and inner.typename in _FLOATS and numpy:
                items.append(f"{name!r}: _float_view({attr})")
            elif isinstance(inner, d.BasicType) and inner.typename in _FLOATS:
                pre.append(f"v{i} = {attr}.tolist()\n    if not all(map(isfinite, v{i})): v{i} = _nf_list(v{i})")
                items.append(f"{name!r}: v{i}")
            elif isinstance(inner, d.BasicType):  # numpy arrays for numbers; plain lists for bool[N]
                items.append(f"{name!r}: ({attr}.tolist() if hasattr({attr}, 'tolist') else list({attr}))")
            elif isinstance(inner, d.NamespacedType):
                env[f"c{i}"] = getattr(converter_for(_namespaced(inner)), nested)
                items.append(f"{name!r}: [c{i}(x) for x in {attr}]")
            else:  # strings
                items.append(f"{name!r}: list({attr})")
        else:  # pragma: no cover - rosidl has no other member kinds
            raise TypeError(f"{cls.__name__}.{name}: unsupported field type {slot!r}")
    body = "".join(f"    {stmt}\n" for stmt in pre)
    src = f"def to_dict(m):\n{body}    return {{{', '.join(items)}}}\n"
    exec(compile(src, f"<to_dict {cls.__module__}.{cls.__name__}>", "exec"), env)  # noqa: S102 - our own source
    return cast("Callable[[Any], dict[str, Any]]", env["to_dict"])


def _build_to_cbor(cls: type[Any], env: dict[str, Any]) -> Callable[[Any], dict[str, Any]]:
    """Like the JSON ``to_dict`` but for CBOR: floats as they are, numeric arrays as bytes or typed arrays."""
    items = []
    for i, (name, slot) in enumerate(zip(cls.get_fields_and_field_types(), cls.SLOT_TYPES, strict=True)):
        attr = f"m.{name}"
        if isinstance(slot, d.BasicType):
            items.append(f"{name!r}: {attr}[0]" if slot.typename == "octet" else f"{name!r}: {attr}")
        elif isinstance(slot, d.AbstractGenericString):
            items.append(f"{name!r}: {attr}")
        elif isinstance(slot, d.NamespacedType):
            env[f"c{i}"] = converter_for(_namespaced(slot)).to_cbor_obj
            items.append(f"{name!r}: c{i}({attr})")
        elif isinstance(slot, d.AbstractNestedType):
            inner = slot.value_type
            if isinstance(inner, d.BasicType) and inner.typename in _BYTE_LIKE:
                items.append(f"{name!r}: _raw({attr})")
            elif isinstance(inner, d.BasicType) and inner.typename in TYPED_ARRAY_TAGS:
                env[f"t{i}"] = _typed_array(*TYPED_ARRAY_TAGS[inner.typename])
                items.append(f"{name!r}: t{i}({attr})")
            elif isinstance(inner, d.BasicType):  # bool, char, long double: a plain array
                items.append(f"{name!r}: ({attr}.tolist() if hasattr({attr}, 'tolist') else list({attr}))")
            elif isinstance(inner, d.NamespacedType):
                env[f"c{i}"] = converter_for(_namespaced(inner)).to_cbor_obj
                items.append(f"{name!r}: [c{i}(x) for x in {attr}]")
            else:  # strings
                items.append(f"{name!r}: list({attr})")
        else:  # pragma: no cover - rosidl has no other member kinds
            raise TypeError(f"{cls.__name__}.{name}: unsupported field type {slot!r}")
    src = f"def to_cbor(m):\n    return {{{', '.join(items)}}}\n"
    exec(compile(src, f"<to_cbor {cls.__module__}.{cls.__name__}>", "exec"), env)  # noqa: S102 - our own source
    return cast("Callable[[Any], dict[str, Any]]", env["to_cbor"])


# -- dict → ROS: strict reader over a field table built once -------------------------------
#
# Checkers take a value and return what to assign, or raise ConversionError with
# a reason; the field path is added only while an error travels up (err.inside),
# so valid input — the common case — builds no path strings at all. Arrays of
# plain numbers take one fast pass over the list before any per-item work.

_FLT_MAX = 3.4028234663852886e38
Check = Callable[[Any], Any]


class _Reader:
    def __init__(self, cls: type[Any]) -> None:  # a rosidl message class (untyped: get_fields_and_field_types…)
        self.cls = cls
        self.fields: dict[str, Check] = {
            name: _checker(slot) for name, slot in zip(cls.get_fields_and_field_types(), cls.SLOT_TYPES, strict=True)
        }
        self.names = ", ".join(self.fields) or "none"

    def read(self, data: Any) -> Any:
        return self.fill(self.cls(), data)

    def fill(self, msg: Any, data: Any) -> Any:
        """Set ``msg``'s fields from ``data``; nested messages are filled in place, not built twice."""
        if not isinstance(data, dict):
            raise ConversionError(f"expected an object, got {describe(data)}")
        fields = self.fields
        for key, value in data.items():
            check = fields.get(key)
            if check is None:
                raise ConversionError(f"unknown field for {self.cls.__name__} (fields: {self.names})", show_key(key))
            try:
                if type(check) is _Nested:
                    check.reader().fill(getattr(msg, key), value)
                else:
                    setattr(msg, key, check(value))
            except ConversionError as err:
                raise err.inside(key) from None
        return msg


class _Nested:
    """Checker for a nested message field: its reader, built on first use (most fields are never sent)."""

    __slots__ = ("slot", "_reader")
    _reader: _Reader | None

    def __init__(self, slot: d.NamespacedType) -> None:
        self.slot, self._reader = slot, None

    def reader(self) -> _Reader:
        if self._reader is None:
            self._reader = _Reader(_namespaced(self.slot))
        return self._reader

    def __call__(self, v: Any) -> Any:  # as an array item: a new message
        return self.reader().read(v)


def _top_level(reader: _Reader) -> Callable[[Any], Any]:
    def from_dict(data: Any) -> Any:
        try:
            return reader.read(data)
        except ConversionError as err:
            if err.path:
                raise
            raise ConversionError(err.reason, "message") from None
    return from_dict


def _checker(slot: Any) -> Check:
    if isinstance(slot, d.BasicType):
        return _scalar_checker(slot.typename)
    if isinstance(slot, d.AbstractGenericString):
        limit = getattr(slot, "maximum_size", None)

        def check_string(v: Any) -> str:
            if not isinstance(v, str):
                raise ConversionError(f"expected string, got {describe(v)}")
            if "\0" in v:  # ROS strings end at NUL: the rest would vanish silently
                raise ConversionError("string contains a NUL character")
            if limit is not None and len(v) > limit:
                raise ConversionError(f"string longer than {limit}")
            return v
        return check_string
    if isinstance(slot, d.NamespacedType):
        return _Nested(slot)
    return _sequence_checker(slot)


def _sequence_checker(slot: Any) -> Check:
    inner = slot.value_type
    exact = slot.size if isinstance(slot, d.Array) else None
    maximum = getattr(slot, "maximum_size", None) if isinstance(slot, d.BoundedSequence) else None

    def check_length(n: int) -> None:
        if exact is not None and n != exact:
            raise ConversionError(f"expected exactly {exact} items, got {n}")
        if maximum is not None and n > maximum:
            raise ConversionError(f"expected at most {maximum} items, got {n}")

    if isinstance(inner, d.BasicType) and inner.typename in _BYTE_LIKE:
        return _bytes_checker(inner.typename == "octet", isinstance(slot, d.Array), check_length)

    item_check = _checker(inner)
    all_plain = _plain_items_test(inner)

    def check_list(v: Any) -> Any:
        if not isinstance(v, list):
            raise ConversionError(f"expected array, got {describe(v)}")
        check_length(len(v))
        if all_plain is not None and all_plain(v):
            return v
        out = []
        for i, x in enumerate(v):
            try:
                out.append(item_check(x))
            except ConversionError as err:
                raise err.inside(f"[{i}]") from None
        return out
    return check_list


def _plain_items_test(inner: Any) -> Callable[[list[Any]], bool] | None:
    """A one-pass test that a list needs no per-item conversion (then it is assigned as it is)."""
    if not isinstance(inner, d.BasicType):
        return None
    typename = inner.typename
    if typename in _FLOATS:
        single = typename == "float"

        def plain_floats(v: list[Any]) -> bool:
            if not all(type(x) is float for x in v):  # ints, "NaN" names and junk take the slow path
                return False
            return not single or not v or max(map(abs, v)) <= _FLT_MAX
        return plain_floats
    if typename == "boolean":
        return lambda v: all(type(x) is bool for x in v)
    if typename in _INT_RANGES:
        lo, hi = _INT_RANGES[typename]
        return lambda v: all(type(x) is int for x in v) and (not v or (lo <= min(v) and max(v) <= hi))
    return None


def _bytes_checker(as_bytes_list: bool, as_ints: bool, check_length: Callable[[int], None]) -> Check:
    """``uint8[]``/``byte[]``: base64 (our JSON form) or, leniently, a list of 0..255."""
    item = _scalar_checker("uint8")

    def check_bytes(v: Any) -> Any:
        if isinstance(v, str):
            try:
                raw = base64.b64decode(v, validate=True)
            except (binascii.Error, ValueError) as err:
                raise ConversionError(f"invalid base64 ({err})") from None
        elif isinstance(v, list):
            values = []
            for i, x in enumerate(v):
                try:
                    values.append(item(x))
                except ConversionError as err:
                    raise err.inside(f"[{i}]") from None
            raw = bytes(values)
        else:
            raise ConversionError(f"expected base64 string, got {describe(v)}")
        check_length(len(raw))
        if as_bytes_list:  # byte[] is a list of 1-byte bytes objects in rclpy
            return [bytes((b,)) for b in raw]
        return list(raw) if as_ints else raw  # fixed uint8[N] is a numpy array: wants ints
    return check_bytes


def _fits_float32(v: float) -> bool:
    """False when ``v`` would silently become infinity in a float32 (struct rounds like the C layer)."""
    try:
        _pack_f(v)
    except OverflowError:
        return False
    return True


def _scalar_checker(typename: str) -> Check:
    if typename in _FLOATS:
        single = typename == "float"

        def check_float(v: Any) -> float:
            if type(v) is float or (isinstance(v, (int, float)) and not isinstance(v, bool)):
                if single and not _fits_float32(v):
                    raise ConversionError(f"{v!r} is out of range for float32")
                return float(v)
            if isinstance(v, str) and v in NON_FINITE:
                return NON_FINITE[v]
            raise ConversionError(f"expected number, got {describe(v)}")
        return check_float
    if typename == "boolean":
        def check_bool(v: Any) -> bool:
            if not isinstance(v, bool):
                raise ConversionError(f"expected true or false, got {describe(v)}")
            return v
        return check_bool
    if typename == "octet":
        def check_octet(v: Any) -> bytes:
            if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= 255:
                raise ConversionError(f"expected integer 0..255, got {describe(v)}")
            return bytes((v,))
        return check_octet
    lo, hi = _INT_RANGES[typename]

    def check_int(v: Any) -> int:
        if isinstance(v, float) and v.is_integer():
            v = int(v)
        if isinstance(v, bool) or not isinstance(v, int):
            raise ConversionError(f"expected integer, got {describe(v)}")
        if not lo <= v <= hi:
            raise ConversionError(f"expected integer {lo}..{hi}, got {v}")
        return v
    return check_int
