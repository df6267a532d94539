"""Bodies of a broker's control topic, as ``roslink-mqtt fleet apply`` speaks it (docs/protocol.md, "Fleet control").

The embedded broker's ``$CONTROL/roslink/v1`` (broker/admin.py) takes the shape of Mosquitto's dynamic-security
plugin (``$CONTROL/dynamic-security/v1``), so one client drives both: a request is a list of commands, a response
lists one answer per command, each with ``data`` or an ``error``. A request's ``id`` is echoed at the top of the
embedded broker's response; each command's ``correlationData`` is echoed in its answer by both brokers.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from .body import AnyJson, BodyField, NestedBody, Objects, Text, body_of, read, write

MAX_COMMANDS = 16


@dataclass(frozen=True, slots=True)
class ControlRequest:
    """``{"commands": [{"command": "getFleet"}, …], "id": …}``: what an administrator asks a broker."""

    commands: tuple[dict[str, Any], ...]
    id: str | None = None

    FIELDS = (
        BodyField("commands", Objects(), True, "the commands, each `{\"command\": name, …}` (1 to 16)"),
        BodyField("id", Text(1, 64), False, "echoed in the response: the asker finds its answer", None,
                  written="null"),
    )
    QOS = 1
    RETAINED = False

    def to_json(self) -> bytes:  # an absent id is written as null, not left out
        return write(self.FIELDS, self)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> ControlRequest:
        """Strict (the broker reads it); ProtocolError says what is wrong."""
        from .errors import ProtocolError

        got = read(cls.FIELDS, data, shape='expected {"commands": [{"command": "getFleet"}, …]}')
        if not 0 < len(got["commands"]) <= MAX_COMMANDS:
            raise ProtocolError(f"commands: expected 1 to {MAX_COMMANDS} commands, got {len(got['commands'])}")
        return cls(**got)


@dataclass(frozen=True, slots=True)
class ControlResponse:
    """``{"responses": [{"command": …, "data": …} | {"command": …, "error": …}], "id": …}``."""

    responses: tuple[dict[str, Any], ...]
    id: Any = None

    FIELDS = (
        BodyField("responses", Objects(), True, "one answer per command, in order: `data`, or an `error` (text)"),
        BodyField("id", AnyJson(), False, "the request's `id` (the embedded broker; Mosquitto echoes each "
                                          "command's `correlationData` instead)", None, written="null"),
    )
    QOS = 1
    RETAINED = False

    def to_json(self) -> bytes:  # an absent id is written as null, not left out
        return write(self.FIELDS, self)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> ControlResponse:
        """Lenient (a client reads it): unknown fields ignored."""
        return cls(**read(cls.FIELDS, data, shape='expected {"responses": […]}', strict=False,
                          what="control response"))

    def answers(self, request_id: str) -> bool:
        """Whether this answers the request ``request_id`` (by its id, or its commands' correlationData)."""
        return self.id == request_id or any(str(r.get("correlationData", "")).startswith(f"{request_id}-")
                                            for r in self.responses)


@dataclass(frozen=True, slots=True)
class CommandAnswer(NestedBody):
    """One answer of the embedded broker's response: the command, its ``correlationData`` echoed, then ``data`` or
    an ``error``. (Mosquitto's answers have the same keys; a client reads them as dicts, since either broker may
    answer.)"""

    command: str
    correlationData: Any = None  # noqa: N815 - the key Mosquitto's dynamic-security plugin names it by
    data: Any = None
    error: str | None = None

    FIELDS = (
        BodyField("command", Text(), True, "the command answered (empty: the request was not understood)"),
        BodyField("correlationData", AnyJson(), False, "the command's own, echoed", None),
        BodyField("data", AnyJson(), False, "what it returned (getFleet, reload: the fleet the broker enforces)",
                  None),
        BodyField("error", Text(), False, "why it failed", None),
    )

    def to_body(self) -> dict[str, Any]:
        return body_of(self.FIELDS, self)
