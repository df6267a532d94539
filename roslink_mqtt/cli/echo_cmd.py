"""``roslink-mqtt echo ROBOT NAME``: print a robot's state messages as JSON lines.

``NAME`` is a state name (``global_motion``, ``robot_status``, ``ack``, a generic rule's name), ``heartbeat``
(the robot's presence, which lives outside ``state/``), or an MQTT pattern under ``state/`` such as ``'#'``
(every state stream; each line then says which). When nothing comes, echo says why instead of exiting
silently, with an exit status a script can tell apart (see ``EXIT_*``).

``--field PATH`` prints one field of each message (``x``, ``pose.position.x``, ``ranges.0``: dotted, list
indices as numbers) as JSON; a path the message does not have ends echo with status 2 and the fields it has.
``--hz`` prints how often messages arrive instead of the messages, like ``ros2 topic hz``: once a second, and
once more at the end, the average rate over every message so far and the min, max and standard deviation of the
gaps between them. Retained messages (a replay of the last value, not a new one) are not counted. ``--count``
then counts measured messages and ``--timeout`` bounds the measurement, as for echoing.
"""

from __future__ import annotations

import argparse
import math
import queue
import sys
import time
from typing import Any

import orjson

from ..client import NotGranted, RobotClient, RoslinkError
from ..client.messages import RoslinkMessage
from ..client.subscriptions import parse_state_item
from ..protocol import SPECS_BY_NAME, MessageId, ProtocolError, decode
from ..protocol.description import RobotDescription
from ..protocol.messages import Direction
from ..topics import Kind, TopicError, TopicTree, check_filter_path, check_name, state_name, trimmed
from .connect import add_connection_options, open_client

EXIT_OK = 0
EXIT_TIMEOUT = 1  # some messages came, but fewer than --count before --timeout
EXIT_USAGE = 2  # a name that cannot be a state or the robot does not publish, a --field the messages do not have
EXIT_NOTHING = 3  # the robot is online but nothing came on this name: it probably publishes no such state
EXIT_OFFLINE = 4  # the robot was not seen online (offline, or not granted to you): nothing could come
EXIT_INTERRUPTED = 130  # Ctrl-C before --count messages

HEARTBEAT = "heartbeat"
HINT_AFTER = 5.0  # s without a message before a run without --timeout says what the robot does publish
CENSUS_TIME = 1.2  # s to collect the robot's state names (1 Hz streams show up once)
DESCRIPTION_WAIT = 1.0  # s for the robot's retained description (there at once if its bridge ever connected)

EPILOG = (f"exit status: {EXIT_OK} done (or Ctrl-C without --count); {EXIT_TIMEOUT} fewer than COUNT messages "
          f"before --timeout; {EXIT_USAGE} bad arguments, a NAME the robot's description does not list, or --field "
          f"names a field the messages do not have; "
          f"{EXIT_NOTHING} nothing at all on NAME while the robot "
          f"was online (it probably has no such state); {EXIT_OFFLINE} robot not online or not yours to see; "
          f"{EXIT_INTERRUPTED} Ctrl-C before COUNT messages.")


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    every_name = TopicTree().state("ROBOT", "NAME")
    p = sub.add_parser("echo", help="print a robot's state messages (like ros2 topic echo)",
                       description=f"Print each message on {every_name} as one JSON line. NAME may be "
                                   "'heartbeat' (the robot's presence) or a pattern such as '#' (every state; "
                                   'each line is then {"state": NAME, "message": …}).', epilog=EPILOG)
    p.add_argument("robot")
    p.add_argument("name", help="state name, e.g. global_motion, robot_status, ack; heartbeat; or '#'")
    p.add_argument("-n", "--count", type=int, default=0, help="stop after COUNT messages (0 = until Ctrl-C)")
    p.add_argument("--timeout", type=float, default=0.0, help="give up after this many seconds (0 = never)")
    p.add_argument("--field", metavar="PATH", help="print only this field of each message, as JSON (dotted: "
                                                   "x, pose.position.x; list items by number: ranges.0)")
    p.add_argument("--hz", action="store_true", help="print the message rate once a second instead of the "
                                                     "messages, like ros2 topic hz (retained messages not counted)")
    add_connection_options(p)
    p.set_defaults(run=run)


class FieldMissing(LookupError):
    """A --field path the message does not have; says which level was missing and what was there."""


def field_value(message: Any, path: str) -> Any:
    """The value at dotted ``path`` in ``message`` (list items by number); FieldMissing saying what is there."""
    value = message
    done: list[str] = []  # the path read so far
    for key in path.split("."):
        if isinstance(value, dict) and key in value:
            value = value[key]
        elif isinstance(value, list) and key.lstrip("-").isdigit() and -len(value) <= int(key) < len(value):
            value = value[int(key)]
        else:
            where = ".".join(done) or "the message"
            if isinstance(value, dict):
                has = f"its fields: {', '.join(value) or 'none'}"
            elif isinstance(value, list):
                has = f"a list of {len(value)}: items 0..{len(value) - 1}" if value else "an empty list"
            else:
                has = f"it is {orjson.dumps(value).decode()[:40]}, not an object"
            raise FieldMissing(f"no field '{path}': {where} has no '{key}' ({has})")
        done.append(key)
    return value


def rate_report(times: list[float]) -> str:
    """``ros2 topic hz``'s two lines for the arrival times ``times`` (monotonic seconds, at least two)."""
    gaps = [b - a for a, b in zip(times, times[1:], strict=False)]
    mean = sum(gaps) / len(gaps)
    std = math.sqrt(sum((g - mean) ** 2 for g in gaps) / len(gaps))
    rate = 1.0 / mean if mean > 0 else float("inf")
    return (f"average rate: {rate:.3f}\n\tmin: {min(gaps):.3f}s max: {max(gaps):.3f}s std dev: {std:.5f}s "
            f"window: {len(times)}")


def _fail(code: int, message: str) -> int:
    print(f"roslink-mqtt echo: {message}", file=sys.stderr)
    return code


def check_state_name(name: str) -> tuple[str, bool]:
    """``(name, is_pattern)`` with ``state/`` removed; TopicError for a name no topic can have.

    ``+`` and ``#`` are allowed as whole levels (MQTT wildcards), ``#`` only last, as the broker requires.
    """
    name = state_name(name)
    if not name:
        raise TopicError("the state name is empty")
    return name, check_filter_path(name, "state name")


class _Stream:
    """Messages of one subscription, parsed on the network thread and handed to the main thread by a queue."""

    def __init__(self, robot: str, topics: TopicTree, *, heartbeat: bool, pattern: bool) -> None:
        self.robot, self.topics, self.heartbeat, self.pattern = robot, topics, heartbeat, pattern
        self.queue: queue.Queue[Any] = queue.Queue(1000)

    def handle(self, topic: str, payload: bytes, retained: bool) -> None:
        arrived = time.monotonic()
        if not payload:  # a cleared retained message (e.g. a deleted heartbeat): nothing to show
            return
        line: Any
        if self.heartbeat:
            try:  # a ROSLink heartbeat: its payload is what people read
                line = decode(payload, MessageId.HEARTBEAT).payload
            except ProtocolError:
                return
        else:
            parsed = self.topics.parse(topic)
            if parsed is None or parsed.kind is not Kind.STATE or not parsed.name:
                return
            leaf = parsed.name
            item = parse_state_item(payload, self.robot, leaf)
            if item is None:
                return
            line = item.payload() if isinstance(item, RoslinkMessage) else item
            if self.pattern:
                line = {"state": leaf, "message": line}
        try:
            self.queue.put_nowait((arrived, retained, line))
        except queue.Full:  # the printer is stuck (a paused terminal): drop rather than grow
            pass


def census(client: RobotClient, robot: str, seconds: float = CENSUS_TIME) -> list[str]:
    """The state names ``robot`` publishes, collected for ``seconds`` (retained ones at once)."""
    every_state = client.topics.state_filter(robot)
    names: set[str] = set()

    def seen(topic: str, payload: bytes, _retained: bool) -> None:
        parsed = client.topics.parse(topic)
        if payload and parsed is not None and parsed.kind is Kind.STATE and parsed.name:
            names.add(parsed.name)

    if not client.connection.subscribe(every_state, seen):
        return []
    time.sleep(seconds)
    client.connection.unsubscribe(every_state, seen)
    return sorted(names)


def _print(text: str) -> None:
    sys.stdout.write(text + "\n")
    sys.stdout.flush()


def _what(robot: str, name: str) -> str:
    return f"{robot} {HEARTBEAT}" if name == HEARTBEAT else f"{robot} state/{name}"


def _nothing_reason(client: RobotClient, robot: str, name: str, waited: float) -> tuple[int, str]:
    """Why nothing came on ``name`` in ``waited`` s: the robot is not online (the SDK's one wording of why, as
    ``pub`` and ``call`` say it), or it publishes other states only."""
    info = client.robot(robot)
    if info is None or not info.online:
        return EXIT_OFFLINE, str(client.not_online(robot, waited))
    names = census(client, robot)
    spec = SPECS_BY_NAME.get(name)
    described = _description(client, robot)
    entry = described.state_entry(name) if described is not None else None
    if "#" in name or "+" in name:
        kind = ""
    elif name == "ack":
        kind = " (acks come only when something happens: a failsafe stop, a command a ROS service carried out)"
    elif entry is not None and entry.warning:  # the bridge checked its ROS graph: nobody publishes there
        kind = f" (the rule for {name} {entry.warning})"
    elif entry is not None:
        kind = (f" (a rule of the robot publishes it, from {entry.ros_type or 'ROS'}, but nothing came on its ROS "
                f"topic while we listened)")
    elif described is not None:  # it says it maps no such state (a name it has would not get here)
        kind = " (this robot has no rule that publishes it)"
    elif spec is not None and spec.direction is Direction.STATE:
        kind = " (a ROSLink state; the robot publishes no description, so whether a rule maps it is not known)"
    else:
        kind = " (not a ROSLink state name: only a generic rule of the robot could publish it)"
    published = ", ".join(names) if names else "no state at all"
    return EXIT_NOTHING, f"{robot} is online but sent nothing on state/{name}{kind}; it publishes: {published}"


def _description(client: RobotClient, robot: str) -> RobotDescription | None:
    """The robot's retained description, None when there is none to read (a robot never seen, an older bridge)."""
    try:
        return client.description(robot, DESCRIPTION_WAIT)
    except RoslinkError:
        return None


def _unknown(client: RobotClient, robot: str, name: str) -> str | None:
    """Why ``robot`` never sends ``state/<name>`` (with "did you mean"), from its retained description; None when
    it may (or when there is no description to tell: a robot never seen, an older bridge)."""
    described = _description(client, robot)
    return None if described is None else described.unknown_state(name)


def _checked(args: argparse.Namespace) -> tuple[str, bool] | int:
    """(the state name or heartbeat, whether it is a pattern), or the usage error's exit code (printed)."""
    try:
        name, pattern = (HEARTBEAT, False) if trimmed(args.name) == HEARTBEAT else check_state_name(args.name)
        check_name(args.robot, "robot")
    except TopicError as err:
        return _fail(EXIT_USAGE, str(err))
    if args.count < 0 or args.timeout < 0:
        return _fail(EXIT_USAGE, "--count and --timeout must not be negative")
    if args.field is not None and (args.hz or pattern or not all(args.field.split("."))):
        return _fail(EXIT_USAGE, "--field needs one state name (not a pattern), no --hz, and a path such as "
                                 "x or pose.position.x")
    return name, pattern


def _outcome(args: argparse.Namespace, client: RobotClient, name: str, seen: int, times: list[float],
             waited: float) -> int:
    """The exit code once the messages asked for came, or the wait ended (the reason printed)."""
    if args.hz:
        if len(times) >= 2:
            _print(rate_report(times))
        elif seen:
            return _fail(EXIT_TIMEOUT, f"only 1 message on {_what(args.robot, name)} within "
                                       f"{args.timeout:g} s: no rate")
    if seen and (not args.count or seen >= args.count):
        return EXIT_OK  # COUNT messages, or "print what comes for --timeout seconds" and some came
    if seen:
        return _fail(EXIT_TIMEOUT, f"timeout: {seen} of {args.count} messages on {_what(args.robot, name)} "
                                   f"within {args.timeout:g} s")
    code, reason = _nothing_reason(client, args.robot, name, waited)
    return _fail(code, f"nothing on {_what(args.robot, name)} within {args.timeout:g} s: {reason}")


def run(args: argparse.Namespace) -> int:
    checked = _checked(args)
    if isinstance(checked, int):
        return checked
    name, pattern = checked
    client = open_client(args, robots=[args.robot], presence=False)
    if name != HEARTBEAT and not pattern and (why := _unknown(client, args.robot, name)) is not None:
        client.close()
        return _fail(EXIT_USAGE, why)
    topics = client.topics
    topic = topics.heartbeat(args.robot) if name == HEARTBEAT else topics.state_filter(args.robot, name)
    stream = _Stream(args.robot, topics, heartbeat=name == HEARTBEAT, pattern=pattern)
    seen = 0
    times: list[float] = []  # --hz: arrival of each measured message
    start = last_report = time.monotonic()
    deadline = start + args.timeout if args.timeout else None
    hinted = False
    try:
        if not client.connection.subscribe(topic, stream.handle):
            absent = client.not_online(args.robot, time.monotonic() - start)
            if isinstance(absent, NotGranted):  # the robot's name, or the user's grant (with "did you mean")
                return _fail(EXIT_OFFLINE, str(absent))
            return _fail(EXIT_OFFLINE, f"the broker refused a subscription to {topic} (is {args.robot} granted to "
                                      f"{client.username}?)")
        while not args.count or seen < args.count:
            now = time.monotonic()
            if deadline is not None and now >= deadline:
                break
            if not hinted and deadline is None and not seen and now - start >= HINT_AFTER:
                hinted = True  # say once why nothing shows, then keep waiting as asked
                print(f"roslink-mqtt echo: nothing yet: {_nothing_reason(client, args.robot, name, now - start)[1]}; "
                      f"still waiting (Ctrl-C to stop)", file=sys.stderr)
                continue
            if args.hz and len(times) >= 2 and now - last_report >= 1.0:
                last_report = now
                _print(rate_report(times))
            try:
                arrived, retained, line = stream.queue.get(
                    timeout=max(0.0, min(1.0, deadline - now) if deadline is not None else 1.0))
            except queue.Empty:
                continue
            if args.hz:
                if retained:
                    continue  # the broker's copy of an old value: no arrival to time
                times.append(arrived)
            elif args.field is not None:
                try:
                    line = field_value(line, args.field)
                except FieldMissing as err:
                    return _fail(EXIT_USAGE, f"{_what(args.robot, name)}: {err}")
                _print(orjson.dumps(line).decode())
            else:
                _print(orjson.dumps(line).decode())
            seen += 1
        return _outcome(args, client, name, seen, times, time.monotonic() - start)
    except KeyboardInterrupt:
        if args.hz and len(times) >= 2:
            _print(rate_report(times))
        return EXIT_INTERRUPTED if args.count and seen < args.count else EXIT_OK
    finally:
        client.close()
