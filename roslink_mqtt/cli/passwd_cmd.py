"""``roslink-mqtt passwd``: make a Mosquitto-compatible password hash for robots.yaml."""

from __future__ import annotations

import argparse
import getpass
import sys

from ..config.passwords import DEFAULT_ITERATIONS, hash_password


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("passwd", help="hash a password for robots.yaml (Mosquitto $7$ format)",
                       description="Print a PBKDF2-SHA512 hash that both robots.yaml and Mosquitto accept. "
                                   "The password is read from the terminal, or from stdin with --stdin.")
    p.add_argument("username", nargs="?", help="print a password-file line 'username:hash' instead of the hash")
    p.add_argument("--stdin", action="store_true", help="read the password from the first line of stdin")
    p.add_argument("--iterations", type=int, default=DEFAULT_ITERATIONS,
                   help=f"PBKDF2 iterations (default {DEFAULT_ITERATIONS})")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    if args.stdin:
        password = sys.stdin.readline().rstrip("\r\n")
    else:
        password = getpass.getpass("Password: ")
        if getpass.getpass("Again: ") != password:
            print("roslink-mqtt passwd: passwords differ", file=sys.stderr)
            return 1
    if not password:
        print("roslink-mqtt passwd: empty password refused", file=sys.stderr)
        return 1
    try:
        hashed = hash_password(password, iterations=args.iterations)
    except ValueError as err:
        print(f"roslink-mqtt passwd: {err}", file=sys.stderr)
        return 1
    print(f"{args.username}:{hashed}" if args.username else hashed)
    return 0
