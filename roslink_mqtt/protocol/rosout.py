"""The control body of a log line sent through the link to the robot's ``/rosout`` (docs/protocol.md, "Logging").

An SDK node's ``get_logger().info(…)`` publishes ``from/<user>/log/<node>``; the bridge republishes it as an
``rcl_interfaces/msg/Log`` with the SDK node's name, so ``ros2 topic echo /rosout``, rqt_console and
rosbag see a program without ROS like any ROS node. Levels are ROS's (10 debug … 50 fatal), which are also
Python's ``logging`` numbers.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..topics import TopicTree
from .body import GIVEN, SENDER, BodyField, Integer, Levels, Text, read, refuse, write

LEVELS = {10: "debug", 20: "info", 30: "warn", 40: "error", 50: "fatal"}
MAX_MSG = 16 * 1024  # characters of one log line; longer ones are cut (with a mark) by the sender
MAX_SOURCE = 1024  # characters of file and function, together
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
        BodyField("level", Levels(tuple(LEVELS)), True, "10 debug, 20 info, 30 warn, 40 error, 50 fatal",
                  docs_type="integer"),
        BodyField("msg", Text(0, MAX_MSG), True, f"the text (at most {MAX_MSG} characters)", docs_type="string"),
        BodyField("file", Text(0, MAX_SOURCE), False, "source file of the call", "", written_if=("file", GIVEN)),
        BodyField("function", Text(0, MAX_SOURCE), False, "function of the call", "", written_if=("file", GIVEN)),
        BodyField("line", Integer(0, 2**31 - 1), False, "line of the call", 0, docs_type="integer",
                  written_if=("file", GIVEN)),
        BodyField("client_id", SENDER, False, "the sender's id", None, names="sender"),
    )
    QOS = 0  # a log stream: a lost line is not worth a retransmission queue
    RETAINED = False

    def to_json(self) -> bytes:  # file, function and line together, only when there is a file
        return write(self.FIELDS, self)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> LogLine:
        got = read(cls.FIELDS, data, shape='expected a JSON object {"level": 20, "msg": "…"}')
        if len(got["file"]) + len(got["function"]) > MAX_SOURCE:
            raise refuse(f"file, function: together at most {MAX_SOURCE} characters", got, cls.FIELDS)
        return cls(**got)


ROSOUT_BODIES: tuple[tuple[str, str, type], ...] = (
    ("log line", f"`{_DOC.log('<robot>', '<user>', '<node>')}`", LogLine),
)
