"""The fleet for an EMQX cluster (``roslink-mqtt acl export --format emqx``): an authorization file and users.

Writes into one directory:

* ``acl.conf`` -- EMQX's file authorization source (Erlang terms, one rule per line, first match wins): for each
  login the :class:`~roslink_mqtt.broker.acl.AclEntry` list the embedded broker enforces (READ → ``subscribe``,
  WRITE → ``publish``, both → ``all``), then ``{deny, all}.``;
* ``users.csv`` -- ``user_id,password_hash,salt,is_superuser`` for the built-in database's user import, hashed
  ``sha256`` with the salt as suffix (EMQX's ``password_hash_algorithm {name = sha256, salt_position = suffix}``),
  from ``--passwords`` like the RabbitMQ export (EMQX's PBKDF2 takes its salt as text, robots.yaml's are bytes).

EMQX checks a subscription's filter against the rules as a whole, like RabbitMQ: a filter wider than the login's
grant is refused (SUBACK 0x80), not filtered. Not run here (no EMQX package in Debian); tests/ checks the file's
syntax with Erlang's own parser and its decisions against the fleet's ACL.
"""

from __future__ import annotations

import csv
import hashlib
import io
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from ..config import Fleet
from .acl import Access, FleetAcl
from .export import HEADER, ExportError, _write_private
from .export_rabbitmq import check_passwords

ACTIONS = {Access.READ: "subscribe", Access.WRITE: "publish", Access.READWRITE: "all"}


@dataclass(frozen=True, slots=True)
class EmqxFiles:
    acl: Path
    users: Path


def _erlang_string(text: str) -> str:
    if any(c in text for c in '"\\\n\r'):
        raise ExportError(f"{text!r} cannot be written to an EMQX acl.conf string (quotes, backslashes, newlines)")
    return f'"{text}"'


def acl_conf_text(fleet: Fleet) -> str:
    acl = FleetAcl(fleet)
    lines = [HEADER.format(file=fleet.file).replace("#", "%", 1),
             "%% EMQX file authorization (authorization.sources: type = file). First match wins; anything not\n"
             "%% allowed below is denied. A subscription filter wider than a login's grant is refused.\n"]
    for login in acl.logins:
        who = f"{{username, {_erlang_string(login)}}}"
        lines.append(f"\n%% {'robot' if login in fleet.robots else 'user'} {login}\n")
        for entry in acl.entries(login):
            lines.append(f"{{allow, {who}, {ACTIONS[entry.access]}, [{_erlang_string(entry.pattern)}]}}.\n")
    lines.append("\n{deny, all}.\n")
    return "".join(lines)


def emqx_password_hash(password: str, salt: str) -> str:
    """EMQX ``sha256`` with ``salt_position = suffix``: hex(SHA-256(password ‖ salt))."""
    return hashlib.sha256((password + salt).encode()).hexdigest()


def users_csv_text(fleet: Fleet, passwords: Mapping[str, str]) -> str:
    check_passwords(fleet, passwords)
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(["user_id", "password_hash", "salt", "is_superuser"])
    for login in [*fleet.robots, *fleet.users]:
        salt = os.urandom(8).hex()
        admin = login in fleet.users and fleet.users[login].admin
        writer.writerow([login, emqx_password_hash(passwords[login], salt), salt, str(admin).lower()])
    return out.getvalue()


def export_emqx(fleet: Fleet, out_dir: str | Path, passwords: Mapping[str, str]) -> EmqxFiles:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True, mode=0o755)
    files = EmqxFiles(out / "acl.conf", out / "users.csv")
    _write_private(files.acl, acl_conf_text(fleet), None)
    _write_private(files.users, users_csv_text(fleet, passwords), None)
    return files
