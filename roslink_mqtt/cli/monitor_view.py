"""What ``roslink-mqtt monitor`` shows, as plain strings: the fleet table without MQTT and without rich.

Kept apart from the command so the formatting rules (what "stale" means, how a
rate is estimated, that a missing or non-finite value shows as ``-`` instead of
raising) can be tested with a fake clock and hand-made messages. The client's
dispatcher thread feeds it while the main thread renders it, so every public
method takes one lock.
"""

from __future__ import annotations

import collections
import enum
import math
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, NamedTuple

from ..client.directory import RobotInfo
from ..client.errors import RobotError
from ..client.messages import Ack, GlobalMotion, GpsRawInfo, RobotStatus
from ..protocol import AckResult, SystemStatus
from ..protocol.lease import ControlState
from ..protocol.link import LinkReport
from ..topics import Kind, TopicTree

# The state streams the monitor subscribes to for every robot it watches (topic leaves under state/).
STATE_NAMES = ("robot_status", "global_motion", "gps_raw_info", "ack")
RATE_WINDOW = 2.0  # s: long enough to smooth a 1 Hz stream, short enough to show a stall quickly
MISSING = "-"

# MAVLink fix types, which the bridge's gps_raw_info preset produces from sensor_msgs/NavSatStatus
_FIX_NAMES = {0: "no gps", 1: "no fix", 2: "2D", 3: "3D", 4: "DGPS", 5: "RTK float", 6: "RTK fixed"}


class Row(NamedTuple):
    """One robot as display strings, in column order (a tuple for renderers, named fields for tests)."""

    robot: str
    presence: str
    status: str
    type: str
    mode: str
    owner: str
    battery: str
    voltage: str
    x: str
    y: str
    yaw: str
    vx: str
    wz: str
    gps: str
    lat: str
    lon: str
    rate: str
    age: str
    link: str
    ack: str


HEADERS = Row("robot", "presence", "status", "type", "mode", "driven by", "batt", "volt", "x m", "y m", "yaw°",
              "vx m/s", "wz rad/s", "gps", "lat", "lon", "motion Hz", "age", "uplink", "ack / failsafe")


@dataclass
class _Robot:
    info: RobotInfo | None = None
    status: Any = None  # RobotStatus
    motion: Any = None  # GlobalMotion
    gps: Any = None  # GpsRawInfo
    ack: Any = None  # Ack
    link: Any = None  # LinkReport (state/link)
    control: Any = None  # ControlState (state/control): who drives
    newest: float | None = None  # clock time of the newest state message of any kind
    motion_first: float | None = None  # when global_motion first arrived (the rate window is not full before)
    motion_times: collections.deque[float] = field(default_factory=collections.deque)


@dataclass(frozen=True)
class ErrorLine:
    """An error report from a robot, stamped when it arrived (RobotError itself carries no time)."""

    error: RobotError
    at: float


def finite(value: Any) -> float | None:
    """The value as a float when it is a finite number; None for None, NaN, inf, bools and text."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        return None
    return float(value)


def number(value: Any, spec: str = ".2f", suffix: str = "") -> str:
    """``format(value, spec)`` for a finite number, ``-`` for anything else: a display must never raise."""
    v = finite(value)
    return MISSING if v is None else f"{v:{spec}}{suffix}"


def enum_name(value: Any) -> str:
    """``active`` for SystemStatus.ACTIVE; a bare number for a value the enum does not know."""
    if isinstance(value, enum.Enum):
        return value.name.lower()
    return MISSING if value is None else str(value)


def presence(info: RobotInfo | None, now: float) -> str:
    """online / offline / stale, as RobotInfo.online decides but telling its two reasons apart.

    *offline* is the bridge's last-will (it said goodbye or the broker lost it);
    *stale* is a heartbeat that stopped coming without a will (frozen bridge, or
    an old retained heartbeat) — different problems for whoever is watching.
    """
    if info is None:
        return "unseen"
    if info.system_status == SystemStatus.OFFLINE:
        return "offline"
    if now - info.received_at > info.stale_after:
        return "stale"
    return "online"


def short_topic(topic: str, topics: TopicTree) -> str:
    """``cmd/twist`` for ``roslink/turtle1/from/alice/cmd/twist``: the robot and user are shown elsewhere."""
    parsed = topics.parse(topic)
    if parsed is not None and parsed.kind is Kind.FROM:
        return parsed.leaf
    return topic or MISSING


def age(seconds: float | None) -> str:
    if seconds is None or not math.isfinite(seconds):
        return MISSING
    seconds = max(0.0, seconds)
    return f"{seconds:.1f}s" if seconds < 60 else f"{seconds / 60:.0f}m"


class FleetView:
    """The latest heartbeat and state of each watched robot, turned into table rows on demand.

    ``clock`` must be the clock of RobotInfo.received_at (time.monotonic) so
    that presence is judged correctly; tests pass a fake one and build
    RobotInfo on it.
    """

    def __init__(self, clock: Callable[[], float] = time.monotonic, rate_window: float = RATE_WINDOW,
                 max_errors: int = 20, topics: TopicTree | None = None) -> None:
        """``topics``: the fleet's topic tree (its prefix), to show refused topics short."""
        self.clock = clock
        self.topics = topics or TopicTree()
        self.rate_window = rate_window
        self._robots: dict[str, _Robot] = {}
        self._errors: collections.deque[ErrorLine] = collections.deque(maxlen=max_errors)
        self._lock = threading.Lock()

    # -- feeding (any thread) ---------------------------------------------------------------
    def watch(self, robot: str) -> None:
        """Show ``robot`` even before anything arrives from it (named on the command line)."""
        with self._lock:
            self._robots.setdefault(robot, _Robot())

    def update_robots(self, robots: Mapping[str, RobotInfo]) -> None:
        """Take the client's directory snapshot: new heartbeats, and robots whose retained heartbeat was cleared."""
        with self._lock:
            for name, entry in self._robots.items():
                if name not in robots:
                    entry.info = None
            for name, info in robots.items():
                self._robots.setdefault(name, _Robot()).info = info

    def record(self, message: Any, at: float | None = None) -> None:
        """Keep a typed state message (RobotStatus, GlobalMotion, GpsRawInfo, Ack); ignore anything else.

        Anything else includes a generic rule's plain dict on one of these names:
        the monitor only understands the ROSLink presets.
        """
        kind = {RobotStatus: "status", GlobalMotion: "motion", GpsRawInfo: "gps", Ack: "ack"}.get(type(message))
        if kind is None or not getattr(message, "robot", ""):
            return
        now = self.clock() if at is None else at
        with self._lock:
            entry = self._robots.setdefault(message.robot, _Robot())
            setattr(entry, kind, message)
            entry.newest = now if entry.newest is None else max(entry.newest, now)
            if kind == "motion":
                if entry.motion_first is None:
                    entry.motion_first = now
                entry.motion_times.append(now)
                self._trim(entry, now)

    def record_link(self, robot: str, report: Any) -> None:
        """Keep a robot's uplink report (state/link, a LinkReport); ignore anything else on that name."""
        if not isinstance(report, LinkReport):
            return
        with self._lock:
            self._robots.setdefault(robot, _Robot()).link = report

    def record_control(self, robot: str, state: Any) -> None:
        """Keep who drives a robot (state/control, a ControlState); ignore anything else on that name."""
        if not isinstance(state, ControlState):
            return
        with self._lock:
            self._robots.setdefault(robot, _Robot()).control = state

    def record_error(self, error: RobotError, at: float | None = None) -> None:
        """Keep an error report (RobotClient.on_error) for the footer."""
        with self._lock:
            self._errors.append(ErrorLine(error, self.clock() if at is None else at))

    # -- reading (render thread) -------------------------------------------------------------
    def names(self) -> list[str]:
        with self._lock:
            return sorted(self._robots)

    def seen(self) -> list[str]:
        """Robots something arrived from (a heartbeat or state): named-but-silent robots do not count."""
        with self._lock:
            return sorted(n for n, e in self._robots.items() if e.info is not None or e.newest is not None)

    def rate(self, robot: str, now: float | None = None) -> float | None:
        """global_motion messages per second over the last ``rate_window`` s; None before the first one."""
        now = self.clock() if now is None else now
        with self._lock:
            entry = self._robots.get(robot)
            return None if entry is None else self._rate(entry, now)

    def rows(self, now: float | None = None) -> list[Row]:
        now = self.clock() if now is None else now
        with self._lock:
            return [self._row(name, entry, now) for name, entry in sorted(self._robots.items())]

    def errors(self, limit: int = 5, now: float | None = None) -> list[str]:
        """The newest ``limit`` error reports, oldest first, one line each."""
        now = self.clock() if now is None else now
        with self._lock:
            lines = list(self._errors)[-limit:] if limit > 0 else []
        return [f"{e.error.robot or MISSING} refused {short_topic(e.error.topic, self.topics)}: "
                f"{e.error.error or MISSING} "
                f"({age(now - e.at)} ago)" for e in lines]

    # -- internals (lock held) ---------------------------------------------------------------
    def _trim(self, entry: _Robot, now: float) -> None:
        times = entry.motion_times
        while times and times[0] <= now - self.rate_window:
            times.popleft()

    def _rate(self, entry: _Robot, now: float) -> float | None:
        if entry.motion_first is None:
            return None
        self._trim(entry, now)
        times = entry.motion_times
        if now - entry.motion_first >= self.rate_window:
            return len(times) / self.rate_window
        # The window is not full yet: dividing by it would understate the rate, so use the spacing seen so far.
        if len(times) >= 2 and times[-1] > times[0]:
            return (len(times) - 1) / (times[-1] - times[0])
        return None

    def _row(self, name: str, e: _Robot, now: float) -> Row:
        info, status, motion, gps, ack = e.info, e.status, e.motion, e.gps, e.ack
        remaining = finite(getattr(status, "battery_remaining", None))  # -1 = unknown
        fix = getattr(gps, "fix_type", None)
        located = isinstance(fix, int) and fix >= 2  # lat/lon mean nothing without a fix
        yaw = finite(getattr(motion, "yaw", None))
        rate = self._rate(e, now)
        return Row(
            robot=name,
            presence=presence(info, now),
            status=enum_name(info.system_status) if info else MISSING,
            type=enum_name(info.type) if info else MISSING,
            mode=enum_name(info.mode) if info else MISSING,
            owner=_driver_text(e.control, info),
            battery=number(remaining, ".0f", "%") if remaining is not None and remaining >= 0 else MISSING,
            voltage=number(getattr(status, "voltage_battery", None), ".1f", "V"),
            x=number(getattr(motion, "x", None)),
            y=number(getattr(motion, "y", None)),
            yaw=number(math.degrees(yaw), ".0f") if yaw is not None else MISSING,
            vx=number(getattr(motion, "vx", None)),
            wz=number(getattr(motion, "wz", None)),
            gps=MISSING if fix is None else _FIX_NAMES.get(fix, f"fix {fix}"),
            lat=number(getattr(gps, "lat", None), ".6f") if located else MISSING,
            lon=number(getattr(gps, "lon", None), ".6f") if located else MISSING,
            rate=number(rate, ".1f"),
            age=age(None if e.newest is None else now - e.newest),
            link=link_text(e.link),
            ack=_ack_text(ack),
        )


# Columns given up first when the terminal is too narrow for all of them; the rest always stay.
DROP_ORDER = ("lon", "lat", "type", "status", "mode", "voltage", "owner", "gps", "age", "wz", "vx", "yaw", "rate",
              "link")
ACK_MIN_WIDTH = 16  # the ack text may fold onto more lines, so it only needs this much
COLUMN_GAP = 3  # blanks between two columns: a table without edges and one blank of padding each side


def fit_columns(rows: list[Row], width: int) -> list[str]:
    """The columns (Row field names) that fit side by side in ``width`` characters.

    Squeezing nineteen columns into an 80-column terminal makes every cell an
    ellipsis; leaving out the least useful ones keeps the rest readable.
    """
    def natural(key: str) -> int:
        cells = [getattr(HEADERS, key), *(getattr(r, key) for r in rows)]
        widest = max(len(c) for c in cells)
        return min(widest, ACK_MIN_WIDTH) if key == "ack" else widest

    keep = list(Row._fields)
    needed = {key: natural(key) + COLUMN_GAP for key in keep}
    for key in DROP_ORDER:
        if sum(needed[k] for k in keep) - COLUMN_GAP <= width:
            break
        keep.remove(key)
    return keep


def link_text(report: LinkReport | None) -> str:
    """``244k`` (the uplink's estimated rate), ``hidden 85ms`` while the path steers (the queue beyond the robot),
    and the stream furthest behind its rate: ``244k scan 3.9/5``."""
    if report is None:
        return MISSING
    text = f"{'≥' if not (report.measured or report.hidden) else ''}{report.rate_kbit_s:.0f}k"
    if report.hidden and report.path is not None:  # a queue beyond the robot, behind a hop that acknowledges
        text += f" hidden {report.path.queue_ms:.0f}ms"
    behind = [(s.sent_hz / s.offered_hz, name, s) for name, s in report.streams.items()
              if s.offered_hz > 0 and s.sent_hz + 0.05 < s.offered_hz]
    if behind:
        _, name, s = min(behind)
        text += f" {name} {s.sent_hz:.1f}/{s.offered_hz:.0f}"
    return text


def _driver_text(control: ControlState | None, info: RobotInfo | None) -> str:
    """``alice since 12:03:05`` (state/control; ``E-STOP · …`` while motion is blocked), else the heartbeat's
    holder, else ``-``."""
    if control is not None and (info is None or info.online):
        who = MISSING if control.holder is None else control.driver().removeprefix("driven by ")
        return f"E-STOP · {who}" if control.blocked else who
    return (info.owner or MISSING) if info else MISSING


def _ack_text(ack: Any) -> str:
    """``failsafe: operator alice went away``; the result alone when the robot gave no text."""
    if ack is None:
        return MISSING
    result: Any = getattr(ack, "result", None)  # None, or a number that is no AckResult: "result …" below
    try:
        label = AckResult(result).name.lower()
    except ValueError:
        label = f"result {result}"
    text = getattr(ack, "text", "")
    return f"{label}: {text}" if text else label

