"""``roslink-mqtt snapshot ROBOT --last 30s -o FILE.mcap``: the seconds before now, as the robot recorded them."""

from __future__ import annotations

import argparse
import sys

from ..topics import check_name
from .connect import PROG, add_connection_options, open_client


def seconds(text: str) -> float:
    """``30``, ``30s``, ``2m``: seconds."""
    scale = 60.0 if text.endswith("m") else 1.0
    try:
        value = float(text.rstrip("sm")) * scale
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected seconds such as 30, 30s or 2m, not {text!r}") from None
    if not 0 < value <= 3600:
        raise argparse.ArgumentTypeError(f"expected 0 < seconds <= 3600, not {text!r}")
    return value


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("snapshot", help="fetch the last seconds of a robot's snapshot topics as MCAP (ros2 bag)",
                       description="Ask the robot for the last seconds of the ROS topics its robot file keeps "
                                   "(snapshot:), as MCAP: the messages as recorded on the robot (CDR, ros2msg "
                                   "schemas), which ros2 bag, Foxglove and the mcap tools read. The robot sends it in "
                                   "chunks behind its live data; a transfer a reconnect broke is resumed, and the "
                                   "file is checked (SHA-256) before it is written.")
    p.add_argument("robot", metavar="ROBOT")
    p.add_argument("--last", type=seconds, default=30.0, metavar="S",
                   help="seconds before now (30, 30s, 2m; default 30); the robot keeps snapshot.seconds")
    p.add_argument("-o", "--output", required=True, metavar="FILE.mcap")
    p.add_argument("--timeout", type=float, default=300.0, metavar="S",
                   help="give up after S seconds (default %(default)g: a thin uplink takes its time)")
    add_connection_options(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from ..client.errors import RoslinkError

    check_name(args.robot, "robot")
    client = open_client(args, robots=[args.robot])
    progress = sys.stderr.isatty()

    def show(got: int, of: int) -> None:
        print(f"\r{args.robot}: {got}/{of} chunks", end="", file=sys.stderr, flush=True)

    try:
        snap = client.snapshot(args.robot, args.last, path=args.output, timeout=args.timeout,
                               on_progress=show if progress else None)
    except RoslinkError as err:
        print(("\n" if progress else "") + f"{PROG} snapshot: {err}", file=sys.stderr)
        return 1
    finally:
        client.close()
    span = (snap.end - snap.start) / 1e9 if snap.messages else 0.0
    print(("\r" if progress else "") + f"{args.robot}: {snap.messages} messages over {span:.1f} s, "
          f"{len(snap.data) / 1000:.0f} kB, SHA-256 {snap.sha256[:12]}… checked"
          + (f", resumed {snap.resumes}×" if snap.resumes else "") + f" → {snap.path}", file=sys.stderr)
    return 0
