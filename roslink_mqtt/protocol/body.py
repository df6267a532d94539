"""Bodies declared once: a field's type, bounds, default and meaning in one :class:`BodyField`.

Every control body (:mod:`.control`, :mod:`.goals`, :mod:`.params` …) lists its fields in ``FIELDS``; from that
one declaration come

* the parser (:func:`read`): the JSON object check, required fields, each value's type and bounds, unknown
  fields refused where the bridge reads, ids read first so that every later refusal names its request
  (:meth:`ProtocolError.naming`) and nothing parses a payload twice;
* the docs table (docs/protocol.md, :mod:`.reference`): the ``type`` column is the spec's own wording;
* the dashboard's readers (:mod:`.bodies_js`): the same declarations as data, read by the same rules;
* the writer (:func:`write`): a body's ``to_json`` writes the declared fields, so a field added to a body is
  written without a second list of names that could miss it.

A body type adds only what no single field can say (``op: set`` needs ``values``; a type name must be a
service type) after :func:`read` returns.

Two ways to read (``strict``): the bridge refuses what is not exactly as declared; a client reads leniently —
unknown fields ignored, a malformed field with a default takes the default — so the bridge may grow a body
without breaking older clients.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar, Final

import orjson

from .codec import MAX_CLIENT_ID, loads
from .errors import ProtocolError
from .validate import describe, show_key


class _Missing:
    """No default: a required field, or an optional one left out of the result when absent."""

    def __repr__(self) -> str:
        return "MISSING"


MISSING: Final = _Missing()


class _Given:
    def __repr__(self) -> str:
        return "GIVEN"


GIVEN: Final = _Given()  # BodyField.written_if: the other field is not empty


class Spec:
    """What one field's value may be: :meth:`check` returns it (normalised) or raises :class:`_Bad`."""

    KIND: ClassVar[str] = ""

    def words(self) -> str:
        """The type as docs/protocol.md and refusals word it."""
        raise NotImplementedError

    def check(self, value: Any) -> Any:
        raise NotImplementedError

    def as_data(self) -> dict[str, Any]:
        """The spec as JSON data (the dashboard reads bodies from the same declarations)."""
        return {"kind": self.KIND}


class _Bad(Exception):
    """A value that does not fit its spec (the field's name is added by :func:`read`)."""


def _int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


@dataclass(frozen=True)
class Text(Spec):
    """A string of ``min_len``..``max_len`` characters."""

    min_len: int = 0
    max_len: int | None = None
    wording: str = ""  # instead of the generated one, e.g. "string `pkg/srv/Type`"
    KIND: ClassVar[str] = "string"

    def words(self) -> str:
        if self.wording:
            return self.wording
        if self.max_len is not None:
            return f"string, {self.min_len}..{self.max_len} characters"
        return "non-empty string" if self.min_len else "string"

    def check(self, value: Any) -> str:
        if not isinstance(value, str) or len(value) < self.min_len or (
                self.max_len is not None and len(value) > self.max_len):
            raise _Bad
        return value

    def as_data(self) -> dict[str, Any]:
        return {"kind": self.KIND, "min": self.min_len, "max": self.max_len}


@dataclass(frozen=True)
class Integer(Spec):
    low: int | None = None
    high: int | None = None
    KIND: ClassVar[str] = "integer"

    def words(self) -> str:
        if self.low is not None and self.high is not None:
            return f"integer {self.low}..{self.high}"
        return "non-negative integer" if self.low == 0 else "integer"

    def check(self, value: Any) -> int:
        if not _int(value) or (self.low is not None and value < self.low) or (
                self.high is not None and value > self.high):
            raise _Bad
        return int(value)

    def as_data(self) -> dict[str, Any]:
        return {"kind": self.KIND, "low": self.low, "high": self.high}


@dataclass(frozen=True)
class Number(Spec):
    """A finite number (integers too), optionally ``low`` < value (or ≤, ``low_open`` False) ≤ ``high``."""

    low: float | None = None
    high: float | None = None
    low_open: bool = False
    wording: str = ""
    KIND: ClassVar[str] = "number"

    def words(self) -> str:
        if self.wording:
            return self.wording
        if self.low is not None and self.high is not None:
            return f"number, {self.low:g} {'<' if self.low_open else '≤'} value ≤ {self.high:g}"
        return "number"

    def check(self, value: Any) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise _Bad
        if self.low is not None and (value <= self.low if self.low_open else value < self.low):
            raise _Bad
        if self.high is not None and value > self.high:
            raise _Bad
        return float(value)

    def as_data(self) -> dict[str, Any]:
        return {"kind": self.KIND, "low": self.low, "high": self.high, "low_open": self.low_open}


@dataclass(frozen=True)
class Boolean(Spec):
    KIND: ClassVar[str] = "boolean"

    def words(self) -> str:
        return "boolean"

    def check(self, value: Any) -> bool:
        if not isinstance(value, bool):
            raise _Bad
        return value


@dataclass(frozen=True)
class Obj(Spec):
    """A JSON object (``max_items`` keys at most)."""

    max_items: int | None = None
    KIND: ClassVar[str] = "object"

    def words(self) -> str:
        return "object" if self.max_items is None else f"object of at most {self.max_items} entries"

    def check(self, value: Any) -> dict[str, Any]:
        if not isinstance(value, dict) or (self.max_items is not None and len(value) > self.max_items):
            raise _Bad
        return value

    def as_data(self) -> dict[str, Any]:
        return {"kind": self.KIND, "max": self.max_items}


@dataclass(frozen=True)
class Strings(Spec):
    """An array of strings (non-empty ones with ``non_empty``), ``max_items`` at most; read as a tuple."""

    max_items: int | None = None
    non_empty: bool = False
    KIND: ClassVar[str] = "strings"

    def words(self) -> str:
        items = "non-empty strings" if self.non_empty else "strings"
        return f"array of {items}" if self.max_items is None else f"array of at most {self.max_items} {items}"

    def check(self, value: Any) -> tuple[str, ...]:
        if not isinstance(value, list) or (self.max_items is not None and len(value) > self.max_items) or \
                not all(isinstance(v, str) and (v or not self.non_empty) for v in value):
            raise _Bad
        return tuple(value)

    def as_data(self) -> dict[str, Any]:
        return {"kind": self.KIND, "max": self.max_items, "non_empty": self.non_empty}


@dataclass(frozen=True)
class TextMap(Spec):
    """A JSON object whose values are all strings (a name → name mapping)."""

    wording: str = "object of strings"
    KIND: ClassVar[str] = "text_map"

    def words(self) -> str:
        return self.wording

    def check(self, value: Any) -> dict[str, str]:
        if not isinstance(value, dict) or not all(isinstance(v, str) for v in value.values()):
            raise _Bad
        return dict(value)


@dataclass(frozen=True)
class Objects(Spec):
    """An array of JSON objects (each one read by its own entry type); read as a tuple."""

    KIND: ClassVar[str] = "objects"

    def words(self) -> str:
        return "array of objects"

    def check(self, value: Any) -> tuple[dict[str, Any], ...]:
        if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
            raise _Bad
        return tuple(value)


@dataclass(frozen=True)
class Choice(Spec):
    """One of a few strings."""

    values: tuple[str, ...]
    KIND: ClassVar[str] = "choice"

    def words(self) -> str:
        return " or ".join(f'"{v}"' for v in self.values) if len(self.values) <= 2 else \
            f"one of {', '.join(self.values)}"

    def check(self, value: Any) -> str:
        if value not in self.values or not isinstance(value, str):
            raise _Bad
        return value

    def as_data(self) -> dict[str, Any]:
        return {"kind": self.KIND, "values": list(self.values)}


@dataclass(frozen=True)
class Levels(Spec):
    """One of a few integers (log levels)."""

    values: tuple[int, ...]
    KIND: ClassVar[str] = "levels"

    def words(self) -> str:
        return f"integer, one of {', '.join(map(str, self.values))}"

    def check(self, value: Any) -> int:
        if not _int(value) or value not in self.values:
            raise _Bad
        return int(value)

    def as_data(self) -> dict[str, Any]:
        return {"kind": self.KIND, "values": list(self.values)}


@dataclass(frozen=True)
class Id(Spec):
    """A request's own id: a string of 1..``max_len`` characters or an integer (``strings_only``: no integers)."""

    max_len: int = 128
    strings_only: bool = False
    min_len: int = 1
    KIND: ClassVar[str] = "id"

    def words(self) -> str:
        text = f"string, {self.min_len}..{self.max_len} characters" if self.min_len else \
            f"string (≤ {self.max_len} characters)"
        return text if self.strings_only else f"{text} or integer"

    def check(self, value: Any) -> str | int:
        if isinstance(value, str) and self.min_len <= len(value) <= self.max_len:
            return value
        if _int(value) and not self.strings_only:
            return int(value)
        raise _Bad

    def as_data(self) -> dict[str, Any]:
        return {"kind": self.KIND, "min": self.min_len, "max": self.max_len, "strings_only": self.strings_only}


@dataclass(frozen=True)
class Nullable(Spec):
    """``inner`` or null."""

    inner: Spec
    KIND: ClassVar[str] = "nullable"

    def words(self) -> str:
        return f"{self.inner.words()} or null"

    def check(self, value: Any) -> Any:
        return None if value is None else self.inner.check(value)

    def as_data(self) -> dict[str, Any]:
        return {"kind": self.KIND, "inner": self.inner.as_data()}


@dataclass(frozen=True)
class AnyJson(Spec):
    """Any JSON value (echoed ids, ROS messages checked later by their converter)."""

    wording: str = "any JSON value"
    KIND: ClassVar[str] = "any"

    def words(self) -> str:
        return self.wording

    def check(self, value: Any) -> Any:
        return value


SENDER: Final = Text(1, MAX_CLIENT_ID)


@dataclass(frozen=True)
class BodyField:
    """One field of a control body: its name, what its value may be, whether it must be there, what it means.

    ``default``: the value when the field is absent (and, read leniently, when it is malformed); MISSING
    leaves an absent optional field out. ``names``: ``"request"`` or ``"sender"`` — the field that says which
    request this is (an id) or who sent it (a client id): read before the others, so their refusals name it.
    ``docs_type``: the type column's wording where the spec's own is not enough.

    How :func:`write` writes it (a required field: always, null too): ``written`` — ``"set"`` (the default): an
    optional field unless None; ``"null"``: null too, or its default when it has one (a reply echoes an absent id
    as null, a successful reply's absent values as ``{}``); ``"nonempty"``: unless empty (``""``, 0, ``[]``, ``{}``).
    ``written_if``: only when another field has a value (``("result", True)``; :data:`GIVEN`: is not empty) —
    the outcome's values or its error, a cancel's missing goal.
    """

    name: str
    spec: Spec
    required: bool
    doc: str
    default: Any = MISSING
    names: str = ""
    docs_type: str = ""
    written: str = "set"
    written_if: tuple[str, Any] | None = None

    def __post_init__(self) -> None:
        if self.written not in ("set", "null", "nonempty"):
            raise ValueError(f"{self.name}: written must be 'set', 'null' or 'nonempty', not {self.written!r}")

    def writes(self, obj: Any, value: Any) -> bool:
        """Whether ``value`` (this field's, of body ``obj``) goes into the written body."""
        if self.written_if is not None:
            other, wanted = self.written_if
            got = getattr(obj, other)
            if not (bool(got) if wanted is GIVEN else got == wanted):
                return False
        if self.required or self.written == "null":
            return True
        return bool(value) if self.written == "nonempty" else value is not None

    @property
    def type(self) -> str:
        return self.docs_type or self.spec.words()

    def as_data(self) -> dict[str, Any]:
        out: dict[str, Any] = {"name": self.name, "spec": self.spec.as_data(), "required": self.required}
        if self.default is not MISSING:
            out["default"] = list(self.default) if isinstance(self.default, tuple) else self.default
        return out


def _fresh(default: Any) -> Any:
    """A default as a new value: a shared ``{}`` must not become one body's ROS arguments and another's."""
    return type(default)() if isinstance(default, (dict, list)) and not default else default


def _bad(field: BodyField, value: Any) -> ProtocolError:
    return ProtocolError(f"{field.name}: expected {field.spec.words()}, got {describe(value)}")


_CLIENT_ID: Final = "client_id"  # the field :func:`dump` appends last


def dump(body: dict[str, Any], client_id: str | None) -> bytes:
    """Encode a control body (``read``'s counterpart); ``client_id`` goes last and only when set (bodies without it
    stay as before)."""
    if client_id is not None:
        body[_CLIENT_ID] = client_id
    return orjson.dumps(body)


class NestedBody:
    """A body written inside another body's field (a description's entries, a link report's streams and path, a
    declared parameter): :func:`body_of` writes it as its own :meth:`to_body`."""

    __slots__ = ()

    def to_body(self) -> dict[str, Any]:
        raise NotImplementedError


def _as_written(value: Any) -> Any:
    """A field's value as the body holds it: a nested body as its :meth:`~NestedBody.to_body`, a tuple as an array
    (of those), a name → nested body map as a map of their bodies; anything else as it is (orjson writes it)."""
    if isinstance(value, NestedBody):
        return value.to_body()
    if isinstance(value, tuple):
        return [v.to_body() if isinstance(v, NestedBody) else v for v in value]
    if isinstance(value, dict) and any(isinstance(v, NestedBody) for v in value.values()):
        return {k: v.to_body() if isinstance(v, NestedBody) else v for k, v in value.items()}
    return value


def split_header(payload: bytes | bytearray | memoryview, what: str, rest: str) -> tuple[bytes, bytes]:
    """(header line, bytes after it) of a body sent as a JSON header line, a newline, then raw bytes (snapshot
    chunks, video frames); ``what`` and ``rest`` word the refusal when there is no newline."""
    line, newline, data = bytes(payload).partition(b"\n")
    if not newline:
        raise ProtocolError(f"{what}: expected a JSON header line, then {rest}")
    return line, data


def body_of(fields: tuple[BodyField, ...], obj: Any) -> dict[str, Any]:
    """``obj``'s declared fields as a body, in declaration order, each as it says it is written
    (:attr:`BodyField.written`: a required field always, an optional one by default only when it is not None);
    ``client_id`` left out (:func:`write` appends it last, as :func:`dump` does)."""
    body: dict[str, Any] = {}
    for field in fields:
        value = getattr(obj, field.name)
        if field.name == _CLIENT_ID or not field.writes(obj, value):
            continue
        if value is None and field.written == "null" and field.default is not MISSING:
            value = _fresh(field.default)
        body[field.name] = _as_written(value)
    return body


def write(fields: tuple[BodyField, ...], obj: Any) -> bytes:
    """Encode ``obj`` as its ``fields`` declare it (:func:`read`'s counterpart, so a body's fields are listed once,
    not again in a hand-written ``to_json`` that could miss one): :func:`body_of`, then ``client_id`` last when
    set — whether it names the sender or echoes a request's."""
    sender = next((getattr(obj, f.name) for f in fields if f.name == _CLIENT_ID), None)
    return dump(body_of(fields, obj), sender)


def read(fields: tuple[BodyField, ...], data: Any, *, shape: str, strict: bool = True,
         what: str = "", known_only: bool | None = None) -> dict[str, Any]:
    """The declared fields of one body, checked: name → value (absent optional fields: their default, or left out).

    ``data``: the payload (bytes or str, decoded here) or a body already decoded (a dict). ``shape``: the
    refusal when it is not a JSON object (it shows the expected form). ``strict`` (the bridge): unknown fields
    and malformed values are refused. Lenient (a client): unknown fields are ignored, a malformed field with a
    default takes it. ``what`` prefixes lenient refusals ("reply: id: expected …"): a client's log names the body.
    ``known_only=False`` with ``strict``: unknown fields are ignored, malformed values still refused (the
    description's entries: a newer bridge may add fields, a wrong one is a broken description).
    """
    if known_only is None:
        known_only = strict
    body = loads(data) if isinstance(data, (bytes, bytearray, memoryview, str)) else data
    if not isinstance(body, Mapping):
        raise ProtocolError(f"{shape}, got {describe(body)}")
    prefix = f"{what}: " if what and not strict else ""
    out: dict[str, Any] = {}
    request: str | int | None = None
    sender: str | None = None

    def take(field: BodyField) -> None:
        if field.name not in body:
            if field.required and (strict or field.default is MISSING):
                raise ProtocolError(f"{field.name}: missing; {shape}" if strict else
                                    f"{prefix}{field.name}: missing (expected {field.type})")
            if field.default is not MISSING:
                out[field.name] = _fresh(field.default)
            return
        try:
            out[field.name] = field.spec.check(body[field.name])
        except _Bad:
            if strict or (field.required and field.default is MISSING):
                raise ProtocolError(f"{prefix}{_bad(field, body[field.name])}") from None
            if field.default is not MISSING:  # read leniently: as if it were absent
                out[field.name] = _fresh(field.default)

    for field in fields:  # who sent it first, then which request: a bad id's refusal still finds its sender
        if field.names == "sender":
            take(field)
            sender = out.get(field.name)
    for field in fields:
        if field.names == "request":
            try:
                take(field)
            except ProtocolError as err:
                raise err.naming(None, sender) from None
            request = out.get(field.name)
    try:
        if known_only:
            known = tuple(f.name for f in fields)
            unknown = sorted(set(body) - set(known))
            if unknown:
                raise ProtocolError(f"unknown field '{show_key(unknown[0])}' (fields: {', '.join(known)})")
        for field in fields:
            if not field.names:
                take(field)
    except ProtocolError as err:
        raise err.naming(request, sender) from None
    return out


def refuse(message: str, values: Mapping[str, Any], fields: tuple[BodyField, ...]) -> ProtocolError:
    """A refusal found after :func:`read` (a rule across fields), naming the request and sender it read."""
    request = next((values.get(f.name) for f in fields if f.names == "request"), None)
    sender = next((values.get(f.name) for f in fields if f.names == "sender"), None)
    return ProtocolError(message).naming(request, sender)

