"""``roslink-mqtt monitor``: a live table of every robot you may see — presence, battery, pose, GPS, rates.

Watches only (no operator presence, no commands). Robots named on the command
line are shown from the start; every other robot appears when its heartbeat
arrives through the client's ``roslink/+/heartbeat`` wildcard, and its state
streams are followed from then on. Rendering needs ``rich`` (the ``[cli]``
extra), imported only here so the core install stays paho-mqtt + orjson + pyyaml.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from functools import partial
from typing import Any

from ..client import RobotClient
from ..protocol.lease import CONTROL
from ..protocol.link import LINK
from .connect import add_connection_options, open_client
from .monitor_view import ACK_MIN_WIDTH, HEADERS, MISSING, STATE_NAMES, FleetView, Row, fit_columns

MISSING_RICH = "roslink-mqtt monitor needs rich: pip install 'roslink-mqtt[cli]'"
PLAIN_WIDTH = 300  # a file or pipe has no width: wide enough that no column is folded
PRESENCE_STYLE = {"online": "green", "stale": "yellow", "offline": "red", "unseen": "dim"}
RIGHT_ALIGNED = {"battery", "voltage", "x", "y", "yaw", "vx", "wz", "lat", "lon", "rate", "age"}


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("monitor", help="live table of your robots: presence, battery, pose, GPS, rates",
                       description="A live table of every robot you may see: presence, battery, pose, GPS, "
                       "motion rate, latest acknowledgement, and the error reports sent to you.")
    p.add_argument("names", nargs="*", help="robots to show even before they are seen (others appear by heartbeat)")
    p.add_argument("--refresh", type=float, default=4.0, metavar="HZ", help="redraws per second (default %(default)s)")
    p.add_argument("--duration", type=float, default=0.0, metavar="S", help="stop after S seconds (0 = until Ctrl-C)")
    p.add_argument("--once", action="store_true", help="collect for --wait seconds, print the table once and exit")
    p.add_argument("--wait", type=float, default=2.0, metavar="S",
                   help="with --once: seconds to collect before printing (default %(default)s)")
    p.add_argument("--errors", type=int, default=5, metavar="N",
                   help="error reports to show under the table (default %(default)s)")
    add_connection_options(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    try:
        import rich  # noqa: F401  (optional: the [cli] extra)
    except ImportError:
        print(MISSING_RICH, file=sys.stderr)
        return 2
    if not args.refresh > 0:
        raise SystemExit("roslink-mqtt monitor: --refresh must be > 0")
    view = FleetView()
    for name in args.names:
        view.watch(name)
    try:
        client = open_client(args, robots=args.names, presence=False)
    except KeyboardInterrupt:
        return 0
    # Error reports to this user (from its other programs' commands) go to the footer instead of the log,
    # which would tear the live table apart. A monitor shows all of them: it sends nothing itself, and
    # watching what the user's programs get refused is its job (other programs see only their own).
    client.all_errors = True
    view.topics = client.topics
    for error in list(client.recent_errors):
        view.record_error(error)
    client.on_error = view.record_error
    follower = StateFollower(client, view)

    def title() -> str:  # says so while the client reconnects: the rows go stale then, and this is why
        link = "" if client.connected else " — disconnected, reconnecting"
        return f"roslink-mqtt monitor — {args.username} @ {args.url}{link}"

    try:
        if args.once:
            _collect(follower, args.wait, 1.0 / args.refresh)
            _print_plain(view, title(), args.errors)
        elif sys.stdout.isatty():
            _live(follower, view, title, args)
        else:
            _batch(follower, view, title, args)
    except KeyboardInterrupt:
        return 0
    finally:
        client.close()
    if not view.seen():
        print("no robots seen" + ("" if args.names else " (name them if your broker refuses wildcards)"))
        return 1
    return 0


class StateFollower:
    """Keeps the view in step with the client: heartbeats each poll, state streams of every new robot."""

    def __init__(self, client: RobotClient, view: FleetView) -> None:
        self.client, self.view = client, view
        self.followed: set[str] = set()

    def poll(self) -> None:
        """Call from the refresh loop (main thread): subscribing waits for the broker's SUBACK."""
        robots = self.client.robots()
        self.view.update_robots(robots)
        for robot in sorted((set(robots) | set(self.view.names())) - self.followed):
            self.followed.add(robot)
            for name in STATE_NAMES:
                self.client.subscribe(robot, name, self.view.record)
            self.client.subscribe(robot, LINK, partial(self.view.record_link, robot))
            self.client.subscribe(robot, CONTROL, partial(self.view.record_control, robot))


def _collect(follower: StateFollower, seconds: float, period: float) -> None:
    deadline = time.monotonic() + max(0.0, seconds)
    while True:
        follower.poll()
        left = deadline - time.monotonic()
        if left <= 0:
            return
        time.sleep(min(period, left))


def _live(follower: StateFollower, view: FleetView, title: Callable[[], str], args: argparse.Namespace) -> None:
    from rich.console import Console
    from rich.live import Live

    period = 1.0 / args.refresh
    deadline = time.monotonic() + args.duration if args.duration > 0 else None
    follower.poll()
    console = Console()
    with Live(render(view, title(), args.errors, console.width), console=console, auto_refresh=False) as live:
        while deadline is None or time.monotonic() < deadline:
            time.sleep(period)
            follower.poll()
            live.update(render(view, title(), args.errors, console.width), refresh=True)  # width follows resizes


def _batch(follower: StateFollower, view: FleetView, title: Callable[[], str], args: argparse.Namespace) -> None:
    """stdout is a file or pipe: print a plain table every refresh, like ``top -b``."""
    period = 1.0 / args.refresh
    deadline = time.monotonic() + args.duration if args.duration > 0 else None
    while True:
        _collect(follower, period, period)
        _print_plain(view, title(), args.errors)
        if deadline is not None and time.monotonic() >= deadline:
            return


def _print_plain(view: FleetView, title: str, errors: int) -> None:
    from rich.console import Console

    if not view.names():
        return  # nothing to tabulate; run() says "no robots seen"
    console = Console(force_terminal=False, no_color=True, width=PLAIN_WIDTH, highlight=False)
    with console.capture() as captured:
        console.print(render(view, title, errors))
    # rich pads every line to the table's width: trailing blanks only get in the way of grep and diff
    print("\n".join(line.rstrip() for line in captured.get().splitlines()), flush=True)


def render(view: FleetView, title: str, errors: int = 5, width: int | None = None) -> Any:
    """The table and the error footer as one rich renderable; ``width`` drops columns that would not fit."""
    from rich import box
    from rich.console import Group
    from rich.table import Table
    from rich.text import Text

    rows = view.rows()
    columns = list(Row._fields) if width is None else fit_columns(rows, width)
    table = Table(title=title, box=box.SIMPLE_HEAD, title_justify="left", show_edge=False,
                  pad_edge=False)  # fit_columns counts on exactly COLUMN_GAP blanks between columns
    for key in columns:
        header = getattr(HEADERS, key)
        if key == "ack":
            table.add_column(header, overflow="fold", min_width=ACK_MIN_WIDTH)
        else:
            table.add_column(header, no_wrap=True, justify="right" if key in RIGHT_ALIGNED else "left")
    for row in rows:
        # Text, not str: rich would read "[...]" in a robot's ack text as markup.
        cells = []
        for key in columns:
            cell = getattr(row, key)
            style = PRESENCE_STYLE.get(cell, "") if key == "presence" else "bold" if key == "robot" else ""
            cells.append(Text(cell, style="dim" if cell == MISSING else style))
        table.add_row(*cells)
    lines = view.errors(errors)
    if not lines:
        return table
    footer = Text("errors reported to you:\n", style="bold")
    footer.append("\n".join(lines), style="red")
    return Group(table, footer)
