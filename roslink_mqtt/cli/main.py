"""Entry point for ``roslink-mqtt``: builds the parser from the subcommand modules."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from ..config import ConfigError
from . import acl_cmd, call_cmd, echo_cmd, fleet_cmd, monitor_cmd, passwd_cmd, pub_cmd, robots_cmd, teleop_cmd

DEFAULT_CONFIG = "config/robots.yaml"
SUBCOMMANDS = (robots_cmd, echo_cmd, pub_cmd, call_cmd, teleop_cmd, monitor_cmd, passwd_cmd, fleet_cmd, acl_cmd)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="roslink-mqtt",
        description="Watch and command ROS 2 robots through an MQTT broker (ROSLink over MQTT).")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for module in SUBCOMMANDS:
        module.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.run(args) or 0)
    except ConfigError as err:
        print(f"roslink-mqtt: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
