"""``roslink-mqtt acl export``: the fleet's logins and access rules for an external broker."""

from __future__ import annotations

import argparse
import sys

from ..broker.export import ExportError, export_mosquitto
from ..config import load_fleet

FORMATS = ("mosquitto",)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("acl", help="export the fleet's logins and ACLs for an external broker",
                       description="Access rules derived from robots.yaml (the ones the embedded broker enforces).")
    acl_sub = p.add_subparsers(dest="acl_command", required=True, metavar="ACTION")
    e = acl_sub.add_parser("export", help="write a Mosquitto password file, ACL file and mosquitto.conf",
                           description="Write passwd, acl and mosquitto.conf into DIR. Run Mosquitto with "
                                       "`mosquitto -c DIR/mosquitto.conf`; send it SIGHUP after exporting again.")
    e.add_argument("--format", choices=FORMATS, default="mosquitto", help="target broker (default: %(default)s)")
    e.add_argument("--out", required=True, metavar="DIR", help="output directory (created if missing)")
    e.add_argument("--config", default="config/robots.yaml", help="fleet file (default: %(default)s)")
    e.set_defaults(run=run_export)


def run_export(args: argparse.Namespace) -> int:
    fleet = load_fleet(args.config)
    try:
        files = export_mosquitto(fleet, args.out)
    except (ExportError, OSError) as err:
        print(f"roslink-mqtt acl export: {err}", file=sys.stderr)
        return 2
    logins = len(fleet.robots) + len(fleet.users)
    print(f"wrote {files.passwd} ({logins} logins), {files.acl}, {files.conf}")
    print(f"run: mosquitto -c {files.conf}")
    return 0
