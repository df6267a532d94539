"""Commands to a robot: topic, validated payload and a sequence number per command stream.

The robot drops stale and duplicate commands per (user, command) using the
envelope's ``sequence_number``. It cannot tell two programs of one user apart
(MQTT does not say which connection published), so counting from 1 in each
program would make a restarted program look stale, and two programs driving
the same robot would starve one another. Each number is therefore the wall
clock in milliseconds, or one more than the previous number when the clock
has not moved on: a later command is a larger number whichever program sends
it, and serial-number arithmetic handles the wrap every 49 days.

Payloads of ROSLink commands are validated here with the same rules the robot
applies, so a typo fails at the call site, not as an error report.

Every command names its sender (``client_id`` in the envelope, ``$client_id`` in a
generic rule's JSON) so that the robot's error report about it reaches this
program's error handling only, not every program the user runs.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

import orjson

from ..protocol import SPECS, Direction, encode_message, spec_for
from ..protocol.codec import GENERIC_SENDER_KEY
from ..topics import TopicTree, Verb, check_path, join_leaf, split_leaf, trimmed
from .errors import InvalidArgument

MASK, HALF = 0xFFFFFFFF, 2**31


def wall_clock_ms() -> int:
    return int(time.time() * 1000)


COMMAND_NAMES = frozenset(spec.name for spec in SPECS if spec.direction is Direction.COMMAND)


def command_leaf(name: str) -> str:
    """``"twist"`` → ``"cmd/twist"``; ``"cmd/twist"`` and generic rule names (``"led"``) stay as they are."""
    name = trimmed(name)
    leaf = join_leaf(Verb.CMD, name) if name in COMMAND_NAMES else check_path(name, "command")
    verb, _ = split_leaf(leaf)
    if verb is not None and verb is not Verb.CMD:
        raise InvalidArgument(f"'{leaf}' is a '{verb.value}' topic with its own API: use call()/provide()/advertise() "
                              "(or create_client/create_service/create_publisher)")
    return leaf


def roslink_command(leaf: str) -> str | None:
    """The ROSLink command name a leaf carries (``cmd/twist`` → ``twist``), None for generic rules."""
    verb, name = split_leaf(leaf)
    return name if verb is Verb.CMD and name in COMMAND_NAMES else None


class CommandStreams:
    """Builds what to publish for a command; thread-safe (several threads may command)."""

    def __init__(self, topics: TopicTree, user: str, clock: Callable[[], int] = wall_clock_ms, *,
                 client_id: str | None = None) -> None:
        """``client_id`` is put into every command, so that error reports name this program."""
        self.topics, self.user, self._clock, self.client_id = topics, user, clock, client_id
        self._last: dict[tuple[str, str], int] = {}
        self._lock = threading.Lock()

    def next_sequence(self, robot: str, leaf: str) -> int:
        with self._lock:
            now = self._clock() & MASK
            last = self._last.get((robot, leaf))
            if last is not None and not 0 < (now - last) & MASK < HALF:  # clock stood still or stepped back
                now = (last + 1) & MASK
            self._last[(robot, leaf)] = now
            return now

    def build(self, robot: str, name: str, payload: dict[str, Any] | None = None) -> tuple[str, bytes, int | None]:
        """(topic, bytes, sequence_number or None) for ``name`` with ``payload``.

        ROSLink commands go out as envelopes with a sequence number (validated,
        ProtocolError on a bad payload); generic rules carry the ROS message as
        plain JSON, unvalidated (only the robot knows the ROS type).
        """
        leaf = command_leaf(name)
        topic = self.topics.from_user(robot, self.user, leaf)
        message = roslink_command(leaf)
        if message is None:
            body = dict(payload) if payload is not None else {}
            if self.client_id is not None:
                body[GENERIC_SENDER_KEY] = self.client_id
            return topic, orjson.dumps(body), None
        seq = self.next_sequence(robot, leaf)
        data = encode_message(spec_for(message).message_id, dict(payload or {}), sequence_number=seq,
                              client_id=self.client_id)
        return topic, data, seq
