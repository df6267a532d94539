"""``roslink-mqtt acl export``: the fleet's logins and access rules for an external broker."""

from __future__ import annotations

import argparse
import sys

from ..broker.export import ExportError, default_owner, export_mosquitto, unreadable_parent
from ..config import Fleet, load_fleet

FORMATS = ("mosquitto", "mosquitto-dynsec", "rabbitmq", "emqx")


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("acl", help="export the fleet's logins and ACLs for an external broker",
                       description="Access rules derived from robots.yaml (the ones the embedded broker enforces).")
    acl_sub = p.add_subparsers(dest="acl_command", required=True, metavar="ACTION")
    e = acl_sub.add_parser("export", help="write a broker's logins and access rules (Mosquitto, RabbitMQ)",
                           description="mosquitto: write passwd, acl and mosquitto.conf into DIR; run Mosquitto with "
                                       "`mosquitto -c DIR/mosquitto.conf`, send it SIGHUP after exporting again. "
                                       "mosquitto-dynsec: write dynamic-security.json and mosquitto.conf (the "
                                       "dynamic-security plugin) into DIR once; change the running broker with "
                                       "`roslink-mqtt fleet apply --broker-kind mosquitto`. "
                                       "rabbitmq: write definitions.json and rabbitmq.conf (MQTT plugin) into DIR; "
                                       "load them with `rabbitmqctl import_definitions DIR/definitions.json` on "
                                       "any node of the cluster. emqx: write acl.conf (file authorization) and "
                                       "users.csv (built-in database import) into DIR (docs/scaling.md).")
    e.add_argument("--format", choices=FORMATS, default="mosquitto", help="target broker (default: %(default)s)")
    e.add_argument("--passwords", metavar="FILE",
                   help="rabbitmq and emqx: YAML 'login: password' for every login (they cannot use robots.yaml's "
                        "hashes; each password is checked against them)")
    e.add_argument("--vhost", default="roslink", help="rabbitmq only: the fleet's vhost (default: %(default)s)")
    e.add_argument("--out", required=True, metavar="DIR", help="output directory (created if missing)")
    e.add_argument("--config", default="config/robots.yaml", help="fleet file (default: %(default)s)")
    e.add_argument("--owner", metavar="USER", default=None,
                   help="user who owns the files and must read them (default when run as root and that user "
                        "exists: 'mosquitto' for mosquitto, 'rabbitmq' for rabbitmq — who those brokers run as; "
                        "else you)")
    e.set_defaults(run=run_export)


def run_export(args: argparse.Namespace) -> int:
    fleet = load_fleet(args.config, need_hashes=True)
    if args.format in ("rabbitmq", "emqx"):
        return _export_with_passwords(args, fleet)
    if args.passwords:
        print("roslink-mqtt acl export: --passwords is for --format rabbitmq or emqx (Mosquitto uses robots.yaml's "
              "hashes as they are)", file=sys.stderr)
        return 2
    owner = args.owner if args.owner is not None else default_owner()
    if args.format == "mosquitto-dynsec":
        return _export_dynsec(args, fleet, owner)
    try:
        files = export_mosquitto(fleet, args.out, owner=owner)
    except (ExportError, OSError) as err:
        print(f"roslink-mqtt acl export: {err}", file=sys.stderr)
        return 2
    logins = len(fleet.robots) + len(fleet.users)
    print(f"wrote {files.passwd} ({logins} logins), {files.acl}, {files.conf}"
          + (f" (owner {owner}, mode 600)" if owner else " (mode 600)"))
    if owner is not None and (blocked := unreadable_parent(files.conf, owner)) is not None:
        print(f"roslink-mqtt acl export: warning: user {owner!r} cannot enter {blocked}, so Mosquitto cannot read "
              f"these files; export to a directory it can reach (e.g. /etc/mosquitto/roslink)", file=sys.stderr)
    print(f"run: mosquitto -c {files.conf}     reload after exporting again: kill -HUP <mosquitto pid>")
    return 0


def _export_with_passwords(args: argparse.Namespace, fleet: Fleet) -> int:
    from ..broker.export_emqx import export_emqx
    from ..broker.export_rabbitmq import RABBITMQ_USER, export_rabbitmq, read_passwords

    if not args.passwords:
        print(f"roslink-mqtt acl export: --format {args.format} needs --passwords FILE ('login: password' for every "
              f"login): {args.format} keeps its own hashes and cannot use robots.yaml's", file=sys.stderr)
        return 2
    logins = len(fleet.robots) + len(fleet.users)
    try:
        passwords = read_passwords(args.passwords)
        if args.format == "emqx":
            emqx = export_emqx(fleet, args.out, passwords)
            print(f"wrote {emqx.acl} and {emqx.users} ({logins} logins, mode 600)")
            print("load: authorization source `type = file, path = <acl.conf>`; import users.csv into the "
                  "built-in database authenticator (sha256, salt suffix) — docs/scaling.md")
            return 0
        owner = args.owner if args.owner is not None else default_owner(RABBITMQ_USER)
        files = export_rabbitmq(fleet, args.out, passwords, vhost=args.vhost, owner=owner)
    except (ExportError, OSError) as err:
        print(f"roslink-mqtt acl export: {err}", file=sys.stderr)
        return 2
    print(f"wrote {files.definitions} ({logins} logins, vhost {args.vhost}), {files.conf}"
          + (f" (owner {owner}, mode 600)" if owner else " (mode 600)"))
    print(f"load: rabbitmqctl import_definitions {files.definitions}     (once per cluster; again after editing "
          "robots.yaml)")
    return 0


def _export_dynsec(args: argparse.Namespace, fleet: Fleet, owner: str | None) -> int:
    from ..broker.export_dynsec import export_dynsec

    try:
        files = export_dynsec(fleet, args.out, owner=owner)
    except (ExportError, OSError) as err:
        print(f"roslink-mqtt acl export: {err}", file=sys.stderr)
        return 2
    print(f"wrote {files.config} ({len(fleet.robots) + len(fleet.users)} logins), {files.conf}"
          + (f" (owner {owner}, mode 600)" if owner else " (mode 600)"))
    print(f"run: mosquitto -c {files.conf}     change it live: roslink-mqtt fleet apply --broker-kind mosquitto")
    return 0
