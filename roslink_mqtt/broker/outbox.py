"""How much may wait on its way to one client, and what happens to a client that stops reading.

amqtt starts one task per delivery; for a client that never reads its socket those tasks
wait on its full socket forever, each holding its message, so broker memory grew without
bound (~86 kB/s in the attack) and every later message to that client queued behind the
stuck write. Like Mosquitto's ``max_queued_messages``/``max_queued_bytes``, an
:class:`Outbox` bounds what waits for one client: over the limit, further messages to it
are dropped (Mosquitto drops them too, whatever their QoS: a bridge flooded with commands
must lose the flood, not its connection), and a client that stays over the limit for
``slow_consumer_timeout`` is disconnected. A dropped client's will is published; it
reconnects and gets the retained state afresh.

Pure logic with an injected clock and buffer size; the broker calls :meth:`Outbox.admit`
per delivery and :meth:`Outbox.done` when the delivery task ends.
"""

from __future__ import annotations

from enum import Enum

from .limits import BrokerLimits


class Verdict(Enum):
    SEND = "send"
    DROP = "drop"  # over the limit: this message is dropped, the client stays
    DISCONNECT = "disconnect"  # over the limit for too long: the client is dropped


class Outbox:
    """Deliveries under way to one client: count, payload bytes, since when over the limit."""

    __slots__ = ("count", "bytes", "over_since", "dropped")

    def __init__(self) -> None:
        self.count = 0
        self.bytes = 0
        self.over_since: float | None = None
        self.dropped = 0

    def admit(self, size: int, buffered: int, now: float, limits: BrokerLimits) -> Verdict:
        """Decide one delivery of ``size`` bytes; ``buffered`` = bytes already in the socket's send buffer."""
        over = ((limits.max_queued_messages and self.count >= limits.max_queued_messages)
                or (limits.max_queued_bytes and buffered + self.bytes + size > limits.max_queued_bytes))
        if over and self.count == 0 and buffered == 0:
            over = False  # a client with nothing waiting takes one message, however large (max_payload bounds it)
        if not over:
            self.over_since = None
            self.count += 1
            self.bytes += size
            return Verdict.SEND
        if self.over_since is None:
            self.over_since = now
        if now - self.over_since > limits.slow_consumer_timeout:
            return Verdict.DISCONNECT
        self.dropped += 1
        return Verdict.DROP

    def done(self, size: int) -> None:
        self.count -= 1
        self.bytes -= size
