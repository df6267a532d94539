"""``roslink-mqtt passwd``: make a Mosquitto-compatible password hash for robots.yaml."""

from __future__ import annotations

import argparse
import getpass
import sys

from ..config.passwords import DEFAULT_ITERATIONS, hash_password

MIN_LENGTH = 8  # characters: a robot's or user's login faces the Internet


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("passwd", help="hash a password for robots.yaml (Mosquitto $7$ format)",
                       description="Print a PBKDF2-SHA512 hash that both robots.yaml and Mosquitto accept. "
                                   "The password is read from the terminal (twice), or from the first line of "
                                   f"stdin when that is not a terminal or with --stdin; at least {MIN_LENGTH} "
                                   "characters.")
    p.add_argument("username", nargs="?", help="print a password-file line 'username:hash' instead of the hash")
    p.add_argument("--stdin", action="store_true", help="read the password from the first line of stdin")
    p.add_argument("--iterations", type=int, default=DEFAULT_ITERATIONS,
                   help=f"PBKDF2 iterations (default {DEFAULT_ITERATIONS})")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    if args.stdin or not sys.stdin.isatty():  # piped: getpass would warn and read it anyway
        password = sys.stdin.readline().rstrip("\r\n")
    else:
        password = getpass.getpass("Password: ")
        if getpass.getpass("Again: ") != password:
            print("roslink-mqtt passwd: passwords differ", file=sys.stderr)
            return 1
    if len(password) < MIN_LENGTH:
        n = len(password)
        what = "an empty password" if not n else f"a password of {n} character{'' if n == 1 else 's'}"
        print(f"roslink-mqtt passwd: {what} refused: at least {MIN_LENGTH}", file=sys.stderr)
        return 1
    try:
        hashed = hash_password(password, iterations=args.iterations)
    except ValueError as err:
        print(f"roslink-mqtt passwd: {err}", file=sys.stderr)
        return 1
    print(f"{args.username}:{hashed}" if args.username else hashed)
    return 0
