"""The VDA 5050 wire: topic names, message headers and timestamps (the standard's §6.3–6.5 and the header of
every message).

Every message carries ``headerId`` (counted per topic, from 0, by one per message), ``timestamp`` (ISO 8601 in
UTC with milliseconds, ``2026-11-29T08:15:02.125Z``), ``version``, ``manufacturer`` and ``serialNumber``. A master
control orders messages of one topic by ``headerId``, so each topic has its own counter.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime, timezone
from typing import Any

from ..topics import vda5050_topic

VERSION = "2.1.0"

ORDER = "order"
INSTANT_ACTIONS = "instantActions"
STATE = "state"
VISUALIZATION = "visualization"
CONNECTION = "connection"
FACTSHEET = "factsheet"

FROM_MASTER = (ORDER, INSTANT_ACTIONS)
FROM_VEHICLE = (STATE, VISUALIZATION, CONNECTION, FACTSHEET)


def topic(manufacturer: str, serial_number: str, leaf: str) -> str:
    """``uagv/v2/<manufacturer>/<serialNumber>/<leaf>`` (built where every topic is: roslink_mqtt/topics.py)."""
    return vda5050_topic(manufacturer, serial_number, leaf)


def timestamp(at: float | None = None) -> str:
    """``at`` (seconds since the epoch; now when None) as the standard writes it: ISO 8601, UTC, milliseconds."""
    moment = datetime.fromtimestamp(time.time() if at is None else at, tz=timezone.utc)
    return moment.strftime("%Y-%m-%dT%H:%M:%S.") + f"{moment.microsecond // 1000:03d}Z"


@dataclass(slots=True)
class Headers:
    """The header of each message the vehicle sends: one ``headerId`` counter per topic."""

    manufacturer: str
    serial_number: str
    clock: Callable[[], float] = time.time
    _next: dict[str, int] = field(default_factory=dict)

    def topic(self, leaf: str) -> str:
        return topic(self.manufacturer, self.serial_number, leaf)

    def stamp(self, leaf: str, body: dict[str, Any]) -> dict[str, Any]:
        """``body`` with the header in front (a new dict): the next ``headerId`` of ``leaf``'s topic."""
        header_id = self._next.get(leaf, 0)
        self._next[leaf] = header_id + 1
        return {"headerId": header_id, "timestamp": timestamp(self.clock()), "version": VERSION,
                "manufacturer": self.manufacturer, "serialNumber": self.serial_number, **body}
