"""Connection options shared by the commands that talk to a broker (robots, echo, pub, call, teleop)."""

from __future__ import annotations

import argparse
import getpass
import signal
import sys
import threading
from collections.abc import Iterable
from typing import Any

import orjson

from ..client import ConnectError, LoginRefused, RobotClient
from ..connection_options import (
    ENV_PASSWORD,
    ENV_USERNAME,
    resolve_ca_file,
    resolve_password,
    resolve_url,
    resolve_username,
)
from ..connection_options import add_connection_options as _add_options

PROG = "roslink-mqtt"


def add_connection_options(p: argparse.ArgumentParser) -> None:
    """The shared ``--url``/``-u``/``--password-file``/``--ca-file`` (roslink_mqtt.connection_options)."""
    _add_options(p)


def open_client(args: argparse.Namespace, *, robots: Iterable[str] = (), presence: bool = True) -> RobotClient:
    """Connect, or exit with a clear message (no traceback for a refused login or a dead broker).

    The resolved URL and username are written back to ``args`` because commands show them (monitor's title).
    """
    args.url, args.username = resolve_url(args, PROG), resolve_username(args)
    if not args.username:
        raise SystemExit(f"{PROG}: no username: pass -u NAME or set {ENV_USERNAME}")
    password = resolve_password(args, PROG)
    if password is None:
        if not sys.stdin.isatty():
            raise SystemExit(f"{PROG}: no password: set {ENV_PASSWORD} or pass --password-file FILE")
        password = getpass.getpass(f"Password for {args.username}: ")
    args.ca_file = resolve_ca_file(args)
    client = RobotClient(args.username, password, url=args.url, robots=robots, presence=presence,
                         ca_file=args.ca_file)
    try:
        client.connect()
    except (ConnectError, OSError, TimeoutError) as err:  # e.g. "broker … refused alice: wrong username or password"
        client.close()
        raise SystemExit(f"{PROG}: cannot connect as {args.username}: {err}") from None
    _exit_when_login_refused(client)
    return client


def _exit_when_login_refused(client: RobotClient) -> None:
    """End the command with status 1 and the reason when the broker refuses our login on a reconnect.

    The SDK stops retrying then (a changed password must not become an endless loop that also
    throttles the user's other clients), but long-running commands (echo, monitor, teleop, a pub
    stream) wait in loops of their own and would sit there forever. The network thread cannot
    raise into them, so it signals the main thread, whose handler raises SystemExit there: every
    ``finally`` still runs (terminal restored, client closed) and the process exits 1 with the reason.
    """
    if threading.current_thread() is not threading.main_thread():
        return  # signal handlers belong to the main thread (commands always run there)
    reasons: list[LoginRefused] = []
    main_ident = threading.get_ident()  # the main thread's (checked above)

    def raise_in_main(_signum: int, _frame: object) -> None:
        raise SystemExit(f"roslink-mqtt: {reasons[0] if reasons else 'the broker refused our login'}")

    signal.signal(signal.SIGUSR1, raise_in_main)

    def on_failure(failure: LoginRefused) -> None:
        reasons.append(failure)
        signal.pthread_kill(main_ident, signal.SIGUSR1)

    client.connection.on_failure.append(on_failure)


def stop_on_signals() -> threading.Event:
    """An event set by Ctrl-C (SIGINT) or SIGTERM: what a command that runs until stopped (record, play, foxglove)
    waits on, so it can finish its work (a complete file, a robot left offline) instead of dying mid-way."""
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    return stop


def parse_json_object(text: str | bytes, what: str) -> dict[str, Any]:
    """A JSON object (a command line argument, a Foxglove request); ValueError saying what is wrong with it."""
    try:
        value = orjson.loads(text)
    except orjson.JSONDecodeError as err:
        raise ValueError(f"{what} is not JSON: {err}") from None
    if not isinstance(value, dict):
        raise ValueError(f"{what} must be a JSON object")
    return value


def json_object(text: str, what: str) -> dict[str, Any]:
    """Parse a JSON object given on the command line, or exit saying what is wrong with it."""
    try:
        return parse_json_object(text, what)
    except ValueError as err:
        raise SystemExit(f"roslink-mqtt: {err}") from None
