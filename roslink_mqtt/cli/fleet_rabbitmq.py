"""``fleet apply --broker-kind rabbitmq``: bring a RabbitMQ cluster's users and permissions to robots.yaml.

RabbitMQ keeps users and permissions cluster-wide, changed with ``rabbitmqctl`` on any node (run apply on a node's
host, or give ``--rabbitmqctl`` a command that reaches one). The target is what ``acl export --format rabbitmq``
writes (broker/export_rabbitmq.py): per login, the vhost permissions and one write and one read expression for the
MQTT exchange. A login new to RabbitMQ needs its password in ``--passwords`` (RabbitMQ hashes it itself).

RabbitMQ checks a topic's read permission when a client subscribes, not per message, so a user whose permissions
changed has their connections closed (their client reconnects and subscribes under the new rules; see
:func:`close_connections_expression` for how). Robots are not
disconnected: a bridge subscribes anew to each user its grants add (checked then) and unsubscribes from those they
remove. Retained messages are kept per node: the grants are published on every node ``--url`` lists.
"""

from __future__ import annotations

import json
import shlex
import subprocess
from collections.abc import Mapping, Sequence
from typing import Any

from ..broker.acl import Access, FleetAcl
from ..broker.export_rabbitmq import (
    EXCHANGE,
    EXCHANGE_OR_QUEUES,
    HASHING,
    QUEUES,
    rabbit_password_hash,
    read_passwords,
    topic_permission_regex,
)
from ..config import Fleet
from .fleet_admin import AdminError, new_login_password

ALL = "^.*$"


class Rabbitmqctl:
    """``rabbitmqctl`` (or the command given), its JSON output read."""

    def __init__(self, command: str = "rabbitmqctl", timeout: float = 60.0) -> None:
        self.argv, self.timeout = shlex.split(command), timeout

    def __call__(self, *args: str, stdin: str | None = None) -> str:
        """Run one command; ``stdin``: what it reads (a new user's password: never on a command line)."""
        try:
            done = subprocess.run([*self.argv, *args], capture_output=True, text=True, timeout=self.timeout,
                                  input=stdin, stdin=None if stdin is not None else subprocess.DEVNULL)
        except (OSError, subprocess.TimeoutExpired) as err:
            raise AdminError(f"{' '.join(self.argv)} {args[0]}: {err}") from None
        if done.returncode != 0:
            raise AdminError(f"{' '.join(self.argv)} {' '.join(args)}: {(done.stderr or done.stdout).strip()}")
        return done.stdout

    def rows(self, *args: str) -> list[dict[str, Any]]:
        out = self(*args, "--formatter", "json", "--quiet")
        try:
            rows = json.loads(out or "[]")
        except json.JSONDecodeError:
            raise AdminError(f"rabbitmqctl {args[0]}: unreadable output {out[:200]!r}") from None
        return [r for r in rows if isinstance(r, dict)] if isinstance(rows, list) else []


def target_permissions(fleet: Fleet) -> dict[str, tuple[str, str]]:
    """login → (topic write, topic read) expressions, as the export writes them."""
    acl = FleetAcl(fleet)
    out = {}
    for login in acl.logins:
        admin = login in fleet.users and fleet.users[login].admin
        entries = acl.entries(login)
        out[login] = (ALL, ALL) if admin else (topic_permission_regex(entries, Access.WRITE),
                                               topic_permission_regex(entries, Access.READ))
    return out


def rabbit_plan(fleet: Fleet, users: Sequence[str], topic: Mapping[str, tuple[str, str]], vhost: str,
                passwords: Mapping[str, str], *, need_passwords: bool = True
                ) -> tuple[list[str], dict[str, Any], list[str], list[str]]:
    """(plan lines, definitions to import, users to delete, users whose connections close afterwards).

    New users, their permissions and every changed topic permission go into one definitions document (one
    ``rabbitmqctl import_definitions``, which adds and updates and never deletes: each rabbitmqctl call starts an
    Erlang VM, a second or more); removed users are deleted one by one."""
    want = target_permissions(fleet)
    lines: list[str] = []
    new_users: list[dict[str, Any]] = []
    permissions: list[dict[str, Any]] = []
    topic_permissions: list[dict[str, Any]] = []
    reconnect: list[str] = []
    for login, (write, read) in want.items():
        rule = {"user": login, "vhost": vhost, "exchange": EXCHANGE, "write": write, "read": read}
        if login not in users:
            if login not in passwords and not need_passwords:
                lines.append(f"add      {login} (needs its password in --passwords)")
                continue
            password = new_login_password(fleet, login, passwords, "RabbitMQ, which cannot use robots.yaml's "
                                                                   "hashes")
            lines.append(f"add      {login}")
            new_users.append({"name": login, "password_hash": rabbit_password_hash(password),
                              "hashing_algorithm": HASHING, "tags": []})
            permissions.append({"user": login, "vhost": vhost, "configure": QUEUES, "write": EXCHANGE_OR_QUEUES,
                                "read": EXCHANGE_OR_QUEUES})
            topic_permissions.append(rule)
        elif topic.get(login) != (write, read):
            lines.append(f"acl      {login}: new topic permissions")
            topic_permissions.append(rule)
            if login in fleet.users:
                reconnect.append(login)
    removed = [login for login in users if login not in want and login in topic]  # ours: rights on the vhost
    lines += [f"remove   {login}" for login in removed]
    document = {"users": new_users, "permissions": permissions, "topic_permissions": topic_permissions} \
        if new_users or topic_permissions else {}
    return lines, document, removed, reconnect


def plan_rabbitmq(fleet: Fleet, *, ctl: Rabbitmqctl, vhost: str, url: str, passwords_file: str | None,
                  dry_run: bool) -> tuple[list[str], dict[str, Any], list[str], list[str]]:
    """Read the cluster's users and permissions and print the plan (what :func:`rabbit_plan` returns)."""
    from concurrent.futures import ThreadPoolExecutor

    from .fleet_apply import print_plan

    passwords = read_passwords(passwords_file) if passwords_file else {}
    with ThreadPoolExecutor(2) as pool:  # each call starts an Erlang VM: both at once
        user_rows = pool.submit(ctl.rows, "list_users")
        topic_rows = pool.submit(ctl.rows, "list_topic_permissions", "-p", vhost)
        users = [str(r.get("user")) for r in user_rows.result()]
        topic = {str(r.get("user")): (str(r.get("write")), str(r.get("read")))
                 for r in topic_rows.result() if r.get("exchange") == EXCHANGE}
    planned = rabbit_plan(fleet, users, topic, vhost, passwords, need_passwords=not dry_run)
    print_plan(f"rabbitmq {url} (vhost {vhost}):", planned[0])
    return planned


def run_rabbitmq(ctl: Rabbitmqctl, document: dict[str, Any], removed: list[str], reconnect: list[str]) -> None:
    """Carry the plan out, then close the connections of users whose permissions changed (RabbitMQ checks a
    topic's read permission when a client subscribes: their standing subscriptions were made under the old one)."""
    if document:
        ctl("import_definitions", stdin=json.dumps(document))  # on stdin: it holds password hashes
    for login in removed:
        ctl("delete_user", login)  # RabbitMQ closes the user's connections itself
    if reconnect:
        ctl("eval", close_connections_expression(reconnect))
        print(f"  closed   the connections of {', '.join(reconnect)} (they reconnect under the new rules)")


def close_connections_expression(users: Sequence[str]) -> str:
    """Erlang for ``rabbitmqctl eval``: end every tracked connection of ``users`` on any node.

    RabbitMQ 3.10's ``close_all_user_connections`` and ``close_connection`` see AMQP connections only; an MQTT
    client is a tracked *direct* connection, whose process is ended here (the client sees its connection close).
    Names go in as byte lists, never spliced into Erlang text (a name is any topic level)."""
    names = ", ".join("list_to_binary([" + ",".join(str(b) for b in u.encode()) + "])" for u in users)
    return (f"[exit(P, kill) || U <- [{names}], C <- rabbit_connection_tracking:list_of_user(U), "
            "P <- tuple_to_list(C), is_pid(P)].")
