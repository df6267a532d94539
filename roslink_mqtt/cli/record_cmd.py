"""``roslink-mqtt record ROBOT… -o FILE.mcap``: keep what you may read of robots as MCAP (client/recorder.py)."""

from __future__ import annotations

import argparse
import sys

from ..connection_options import ENV_PASSWORD, resolve_ca_file, resolve_password, resolve_url, resolve_username
from ..topics import check_name, last_level, state_name
from .connect import PROG, add_connection_options, stop_on_signals


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("record", help="record robots' state, heartbeats and your replies as MCAP (Foxglove)",
                       description="Record what you may read of the robots named: heartbeats, every state topic "
                                   "(or those given with --topic) and what the robots send you, one MCAP channel per "
                                   "topic with a JSON schema, until --duration or Ctrl-C (the file is complete "
                                   "either way). Open it in Foxglove or Lichtblick, or read it with the mcap tools.")
    p.add_argument("robots", nargs="+", metavar="ROBOT")
    p.add_argument("-o", "--output", required=True, metavar="FILE.mcap")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds (default: Ctrl-C)")
    p.add_argument("--topic", action="append", default=[], metavar="NAME",
                   help="only this state (global_motion, ack …; repeatable); heartbeats and your replies always")
    p.add_argument("--split-size", type=float, default=0, metavar="MB", help="start a new file after MB megabytes "
                                                                             "(FILE-001.mcap, …)")
    p.add_argument("--prefix", default="roslink", help="topic prefix of the fleet (default: %(default)s)")
    add_connection_options(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from ..client.errors import ConnectError
    from ..client.recorder import Progress, Recorder

    try:
        import mcap  # noqa: F401
    except ImportError:
        print(f"{PROG} record: needs the mcap package: pip install 'roslink-mqtt[cli]'", file=sys.stderr)
        return 2
    username = resolve_username(args)
    password = resolve_password(args, PROG)
    if not username or password is None:
        print(f"{PROG} record: needs a login: -u NAME and {ENV_PASSWORD} or --password-file", file=sys.stderr)
        return 2
    for robot in args.robots:
        check_name(robot, "robot")
    recorder = Recorder(url=resolve_url(args, PROG), username=username, password=password, robots=args.robots,
                        out=args.output, prefix=args.prefix, ca_file=resolve_ca_file(args),
                        split_size=int(args.split_size * 1_000_000), topics=[state_name(t) for t in args.topic])
    try:
        recorder.connect()
    except (ConnectError, OSError) as err:
        print(f"{PROG} record: {err}", file=sys.stderr)
        return 1
    stop = stop_on_signals()

    def show(progress: Progress, elapsed: float) -> None:
        top = ", ".join(f"{last_level(topic)} {n / elapsed:.1f}/s"
                        for topic, n in progress.per_topic.most_common(4))
        print(f"\r{elapsed:6.1f} s  {progress.messages} messages  {progress.bytes / 1000:.0f} kB of messages"
              + (f"  {progress.dropped} dropped" if progress.dropped else "") + f"  ({top})", end="",
              file=sys.stderr, flush=True)

    progress = recorder.run(duration=args.duration, stop=stop, on_progress=show if sys.stderr.isatty() else None)
    on_disk = sum(p.stat().st_size for p in progress.files if p.exists())  # compressed: less than what came
    print(f"\rrecorded {progress.messages} messages ({progress.bytes / 1000:.0f} kB of messages, "
          f"{len(progress.per_topic)} topics; {on_disk / 1000:.0f} kB on disk) into "
          f"{', '.join(str(p) for p in progress.files)}"
          + (f"; {progress.dropped} dropped" if progress.dropped else ""), file=sys.stderr)
    return 0
