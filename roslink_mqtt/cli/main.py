"""Entry point for ``roslink-mqtt``: builds the parser from the subcommand modules."""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence

from ..client import RoslinkError
from ..config import ConfigError
from ..topics import TopicError
from . import (
    acl_cmd,
    action_cmd,
    call_cmd,
    control_cmd,
    dashboard_cmd,
    echo_cmd,
    estop_cmd,
    fleet_cmd,
    foxglove_cmd,
    info_cmd,
    monitor_cmd,
    param_cmd,
    passwd_cmd,
    play_cmd,
    pub_cmd,
    record_cmd,
    robots_cmd,
    snapshot_cmd,
    teleop_cmd,
    video_cmd,
    whoami_cmd,
)

SUBCOMMANDS = (robots_cmd, echo_cmd, pub_cmd, call_cmd, action_cmd, param_cmd, teleop_cmd, control_cmd, estop_cmd,
               monitor_cmd, record_cmd, play_cmd, snapshot_cmd, video_cmd, foxglove_cmd, passwd_cmd, fleet_cmd,
               acl_cmd, dashboard_cmd, info_cmd, whoami_cmd)
EXIT_BROKEN_PIPE = 128 + 13  # what a shell reports for a program that SIGPIPE ended


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="roslink-mqtt",
        description="Watch and command ROS 2 robots through an MQTT broker (ROSLink over MQTT).")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for module in SUBCOMMANDS:
        module.register(sub)
    return parser


def _stdout_gone() -> int:
    """The reader of our stdout went away (``roslink-mqtt fleet | head``): end quietly, as a Unix tool does.

    Everything already unwound through the commands' ``finally`` blocks (clients closed, presence cleared,
    a teleop's last zero sent), which is why this is an exception handler and not SIG_DFL for SIGPIPE: that
    would kill the process mid-command. stdout is pointed at /dev/null so that the interpreter's final flush
    of the still-buffered text cannot raise (and print "Exception ignored …") a second time.
    """
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError):
        pass
    return EXIT_BROKEN_PIPE


def main(argv: Sequence[str] | None = None) -> int:
    """Run one subcommand; expected failures end with a one-line reason and a non-zero status, never a traceback."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
        code = int(args.run(args) or 0)
        sys.stdout.flush()  # here, where a closed pipe can still be handled, not in the interpreter's exit
        return code
    except BrokenPipeError:
        return _stdout_gone()
    except ConfigError as err:
        print(f"roslink-mqtt: {err}", file=sys.stderr)
        return 2
    except TopicError as err:
        print(f"roslink-mqtt: {err}", file=sys.stderr)
        return 2
    except RoslinkError as err:  # the SDK could not send or would not: not connected, a viewer, a refused login
        print(f"roslink-mqtt: {err}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
