"""The one vocabulary for reaching the broker, shared by the bridge, the CLI, the SDK and the examples.

    --url URL             or ROSLINK_URL        (mqtt://, mqtts://, ws://, wss://; default mqtt://127.0.0.1:1883)
    -u/--username NAME    or ROSLINK_USERNAME   (the bridge logs in as its robot and has no such option)
    --password-file FILE  or ROSLINK_PASSWORD   (never a password on the command line: ``ps`` shows it)
    --ca-file FILE        or ROSLINK_CA_FILE

Each program used to spell these its own way (the bridge ``--broker`` and ``ROSLINK_MQTT_PASSWORD``, the
CLI ``--password-env``, the examples ``--password`` on the command line), so a shell set up for one did
not work for the next. Option definitions and the environment lookups live here, once. An option given on
the command line wins over the environment; the caller's own fallback (the bridge's fleet file, the demo
default) comes last.

The old spellings still work for one release and warn when used (a ``DeprecationWarning`` for code, and a
logged line a person running the program sees): ``--broker``, ``--password-env VAR``, ``--password VALUE``
(the examples only) and ``ROSLINK_MQTT_PASSWORD`` (the bridge only).
"""

from __future__ import annotations

import argparse
import logging
import os
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import overload

ENV_URL, ENV_USERNAME, ENV_PASSWORD, ENV_CA_FILE = "ROSLINK_URL", "ROSLINK_USERNAME", "ROSLINK_PASSWORD", \
    "ROSLINK_CA_FILE"
OLD_BRIDGE_PASSWORD_ENV = "ROSLINK_MQTT_PASSWORD"  # the bridge's old name; deprecated
DEFAULT_URL = "mqtt://127.0.0.1:1883"

log = logging.getLogger("roslink_mqtt.deprecated")


def warn_deprecated(old: str, new: str, prog: str) -> None:
    """Say once per use that ``old`` goes away, both to code (DeprecationWarning) and to a person (a log line).

    DeprecationWarning alone is hidden by default outside ``__main__``, so whoever runs the bridge or the CLI
    would never learn that their script needs changing; the log line reaches their terminal or journal
    (with no logging configured, Python's last-resort handler prints warnings to stderr).
    """
    message = f"{old} is deprecated and will be removed in the next release; use {new}"
    warnings.warn(message, DeprecationWarning, stacklevel=3)
    log.warning("%s: %s", prog, message)


def add_connection_options(parser: argparse.ArgumentParser, *, username: bool = True,
                           default_url: str | None = DEFAULT_URL, url_fallback: str = "",
                           old_password_option: bool = False) -> None:
    """Add the connection options (and the hidden old spellings) to ``parser``.

    Defaults stay ``None`` on purpose: the resolvers below must tell "given on the command line" from
    "from the environment", and ``--help`` must not print a password-file path or URL taken from the
    caller's environment as if it were built in. ``url_fallback`` words a caller-specific last resort
    for the help text (the bridge: its fleet file's ``bridge.broker``).
    """
    g = parser.add_argument_group("connection")
    fallback = url_fallback or (f"default {default_url}" if default_url else "")
    g.add_argument("--url", metavar="URL", help=f"broker URL: mqtt://, mqtts://, ws://, wss://; a cluster's nodes "
                   f"comma-separated (failover) (env {ENV_URL}"
                   + (f"; {fallback}" if fallback else "") + ")")
    g.add_argument("--broker", dest="old_broker", metavar="URL", help=argparse.SUPPRESS)
    if username:
        g.add_argument("-u", "--username", metavar="NAME", help=f"login (env {ENV_USERNAME})")
    g.add_argument("--password-file", metavar="FILE",
                   help=f"file whose first line is the password (else env {ENV_PASSWORD}); never a password "
                        "on the command line")
    g.add_argument("--password-env", dest="old_password_env", metavar="VAR", help=argparse.SUPPRESS)
    if old_password_option:
        g.add_argument("--password", dest="old_password", metavar="PASSWORD", help=argparse.SUPPRESS)
    g.add_argument("--ca-file", metavar="FILE", help=f"CA bundle for mqtts:// and wss:// (env {ENV_CA_FILE})")


def env_url() -> str | None:
    """``ROSLINK_URL``, or None when unset or empty (an empty export must not become a URL)."""
    return os.environ.get(ENV_URL) or None


def env_username() -> str | None:
    return os.environ.get(ENV_USERNAME) or None


def env_password() -> str | None:
    """``ROSLINK_PASSWORD`` as set: an empty string is a (bad) password, not "ask me", so it is kept."""
    return os.environ.get(ENV_PASSWORD)


def env_ca_file() -> str | None:
    return os.environ.get(ENV_CA_FILE) or None


@overload
def resolve_url(args: argparse.Namespace, prog: str, default: str = ...) -> str: ...
@overload
def resolve_url(args: argparse.Namespace, prog: str, default: str | None) -> str | None: ...
def resolve_url(args: argparse.Namespace, prog: str, default: str | None = DEFAULT_URL) -> str | None:
    """``--url``, else the old ``--broker`` (warns), else ``ROSLINK_URL``, else ``default`` (may be None)."""
    url: str | None = getattr(args, "url", None)
    if url:
        return url
    old_broker: str | None = getattr(args, "old_broker", None)
    if old_broker:
        warn_deprecated("--broker", "--url", prog)
        return old_broker
    return env_url() or default


def resolve_username(args: argparse.Namespace, default: str | None = None) -> str | None:
    return getattr(args, "username", None) or env_username() or default


def resolve_ca_file(args: argparse.Namespace) -> str | None:
    return getattr(args, "ca_file", None) or env_ca_file()


def read_password_file(path: str | Path, prog: str) -> str:
    """First line of ``path``, stripped; exit with the reason when it cannot be read (no traceback)."""
    try:
        return Path(path).read_text(encoding="utf-8").splitlines()[0].strip()
    except (OSError, IndexError, UnicodeDecodeError) as err:
        reason = "it is empty" if isinstance(err, IndexError) else err
        raise SystemExit(f"{prog}: cannot read password file {path}: {reason}") from None


def resolve_password(args: argparse.Namespace, prog: str, *, old_env: str | None = None) -> str | None:
    """The password, or None when nothing names one (the caller asks, falls back or exits).

    Order: ``--password-file``; the old ``--password-env VAR`` and ``--password VALUE`` (warn); ``old_env``
    when the caller used to read one (the bridge's ``ROSLINK_MQTT_PASSWORD``, warns: it still wins over
    ``ROSLINK_PASSWORD`` because it names this program's password specifically, while ``ROSLINK_PASSWORD``
    may be the login a shell exported for the CLI); then ``ROSLINK_PASSWORD``.
    """
    if getattr(args, "password_file", None):
        return read_password_file(args.password_file, prog)
    var = getattr(args, "old_password_env", None)
    if var:
        warn_deprecated("--password-env", f"{ENV_PASSWORD} or --password-file", prog)
        if var in os.environ:
            return os.environ[var]
    old_password: str | None = getattr(args, "old_password", None)
    if old_password is not None:
        warn_deprecated("--password (visible to every user in ps)", f"{ENV_PASSWORD} or --password-file", prog)
        return old_password
    if old_env and os.environ.get(old_env):
        warn_deprecated(old_env, ENV_PASSWORD, prog)
        return os.environ[old_env]
    return env_password()


@dataclass(frozen=True, slots=True)
class Login:
    """Everything a program needs to connect, resolved from its options and the environment."""

    url: str | None
    username: str | None
    password: str | None
    ca_file: str | None


def resolve_login(args: argparse.Namespace, prog: str, *, default_url: str | None = DEFAULT_URL,
                  default_username: str | None = None) -> Login:
    """All four at once, for programs with no fallbacks of their own beyond a default URL and username."""
    return Login(resolve_url(args, prog, default_url), resolve_username(args, default_username),
                 resolve_password(args, prog), resolve_ca_file(args))


__all__ = ["DEFAULT_URL", "ENV_CA_FILE", "ENV_PASSWORD", "ENV_URL", "ENV_USERNAME", "OLD_BRIDGE_PASSWORD_ENV",
           "Login", "add_connection_options", "env_ca_file", "env_password", "env_url", "env_username",
           "read_password_file", "resolve_ca_file", "resolve_login", "resolve_password", "resolve_url",
           "resolve_username", "warn_deprecated"]
