"""The control body of a log line sent through the link to the robot's ``/rosout`` (docs/protocol.md, "Logging").

An SDK node's ``get_logger().info(…)`` publishes ``from/<user>/log/<node>``; the bridge republishes it as an
``rcl_interfaces/msg/Log`` with the SDK node's name, so ``ros2 topic echo /rosout``, rqt_console and
rosbag see a program without ROS like any ROS node. Levels are ROS's (10 debug … 50 fatal), which are also
Python's ``logging`` numbers.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from ..topics import TopicTree
from .codec import MAX_CLIENT_ID
from .control import BodyField, _dump, _no_unknown, _object, check_client_id
from .errors import ProtocolError

LEVELS = {10: "debug", 20: "info", 30: "warn", 40: "error", 50: "fatal"}
MAX_MSG = 16 * 1024  # characters of one log line; longer ones are cut (with a mark) by the sender
_DOC = TopicTree()


@dataclass(frozen=True, slots=True)
class LogLine:
    """One log line, on ``from/<user>/log/<node>`` (read by the bridge)."""

    level: int
    msg: str
    file: str = ""
    function: str = ""
    line: int = 0
    client_id: str | None = None

    FIELDS = (
        BodyField("level", "integer", True, "10 debug, 20 info, 30 warn, 40 error, 50 fatal"),
        BodyField("msg", "string", True, f"the text (at most {MAX_MSG} characters)"),
        BodyField("file", "string", False, "source file of the call"),
        BodyField("function", "string", False, "function of the call"),
        BodyField("line", "integer", False, "line of the call"),
        BodyField("client_id", f"string, 1..{MAX_CLIENT_ID} characters", False, "the sender's id"),
    )
    QOS = 0  # a log stream: a lost line is not worth a retransmission queue
    RETAINED = False

    def to_json(self) -> bytes:
        body: dict[str, Any] = {"level": self.level, "msg": self.msg}
        if self.file:
            body.update(file=self.file, function=self.function, line=self.line)
        return _dump(body, self.client_id)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> LogLine:
        body = _object(data, 'expected a JSON object {"level": 20, "msg": "…"}')
        client_id = check_client_id(body["client_id"]) if "client_id" in body else None
        try:
            return cls._checked(body, client_id)
        except ProtocolError as err:
            raise err.naming(None, client_id) from None

    @classmethod
    def _checked(cls, body: dict[str, Any], client_id: str | None) -> LogLine:
        _no_unknown(body, ("level", "msg", "file", "function", "line", "client_id"))
        level, msg = body.get("level"), body.get("msg")
        if level not in LEVELS or isinstance(level, bool):
            raise ProtocolError(f"level: expected one of {', '.join(map(str, LEVELS))}, got {level!r}"[:200])
        if not isinstance(msg, str) or len(msg) > MAX_MSG:
            raise ProtocolError(f"msg: expected a string of at most {MAX_MSG} characters")
        file, function, line = body.get("file", ""), body.get("function", ""), body.get("line", 0)
        if not isinstance(file, str) or not isinstance(function, str) or len(file) + len(function) > 1024:
            raise ProtocolError("file, function: expected strings (together at most 1024 characters)")
        if not isinstance(line, int) or isinstance(line, bool) or not 0 <= line < 2**31:
            raise ProtocolError("line: expected a non-negative integer")
        return cls(level, msg, file, function, line, client_id)


ROSOUT_BODIES: tuple[tuple[str, str, type], ...] = (
    ("log line", f"`{_DOC.log('<robot>', '<user>', '<node>')}`", LogLine),
)
