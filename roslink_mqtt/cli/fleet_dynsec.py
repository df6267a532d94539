"""``fleet apply --broker-kind mosquitto``: bring Mosquitto's dynamic-security plugin to what robots.yaml says.

Reads the plugin's clients and roles (``listClients``, ``listRoles``), compares them with what
broker/export_dynsec.py derives from the fleet (one client and one role per login), and sends the commands that
close the difference. The plugin applies each at once and disconnects a client whose login or role changed, so a
revoked user is cut off within the round trip. Clients without a ``roslink`` textname are not ours: left alone.

Mosquitto 2.0's plugin takes a new login's password in clear text only (it hashes it itself), so a login that
is new to the broker needs its password from ``--passwords`` (checked against robots.yaml's hash first).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from ..broker.acl import FleetAcl
from ..broker.export_dynsec import (
    ROLE_PREFIX,
    TEXTNAME,
    acl_key,
    kind_of,
    role_acls,
    role_name,
)
from ..broker.export_rabbitmq import read_passwords
from ..config import Fleet
from ..topics import DYNSEC_CONTROL, DYNSEC_RESPONSE
from .fleet_admin import AdminChannel, AdminError, new_login_password

BATCH = 64  # commands per request


def _data(response: dict[str, Any]) -> dict[str, Any]:
    if "error" in response:
        raise AdminError(f"mosquitto {response.get('command')}: {response['error']}")
    data = response.get("data")
    return data if isinstance(data, dict) else {}


def _send(channel: AdminChannel, commands: list[dict[str, Any]]) -> None:
    for start in range(0, len(commands), BATCH):
        batch = commands[start:start + BATCH]
        for command, response in zip(batch, channel.request(DYNSEC_CONTROL, DYNSEC_RESPONSE, batch), strict=False):
            if "error" in response:
                what = command.get("username") or command.get("rolename") or ""
                raise AdminError(f"mosquitto refused {command['command']} {what}: {response['error']}")


def live_state(channel: AdminChannel) -> tuple[dict[str, str], dict[str, set[tuple[str, str, bool]]]]:
    """Our clients (login → kind) and our roles (role → ACL keys), as the plugin holds them."""
    clients_resp, roles_resp = channel.request(DYNSEC_CONTROL, DYNSEC_RESPONSE, [
        {"command": "listClients", "verbose": True}, {"command": "listRoles", "verbose": True}])
    kinds = {text: kind for kind, text in TEXTNAME.items()}
    clients = {str(c["username"]): kinds[str(c["textname"])] for c in _data(clients_resp).get("clients", [])
               if isinstance(c, dict) and "username" in c and str(c.get("textname")) in kinds}
    roles = {r["rolename"]: {acl_key(a) for a in r.get("acls", []) if isinstance(a, dict)}
             for r in _data(roles_resp).get("roles", [])
             if isinstance(r, dict) and str(r.get("rolename", "")).startswith(ROLE_PREFIX)}
    return clients, roles


def dynsec_plan(fleet: Fleet, clients: Mapping[str, str], roles: Mapping[str, set[tuple[str, str, bool]]],
                passwords: Mapping[str, str], *, need_passwords: bool = True) -> tuple[list[str], list[dict[str, Any]]]:
    """(plan lines, commands) that make the plugin hold ``fleet``'s logins and access rules. ``need_passwords``
    False (a dry run): a new login without a password is listed as needing one, not refused."""
    acl = FleetAcl(fleet)
    lines: list[str] = []
    commands: list[dict[str, Any]] = []
    for login in acl.logins:
        kind, role = kind_of(fleet, login), role_name(login)
        want = role_acls(fleet, login, acl)
        want_keys = {acl_key(a) for a in want}
        if role not in roles:
            commands.append({"command": "createRole", "rolename": role})
            commands += [{"command": "addRoleACL", "rolename": role, **a} for a in want]
        else:
            extra, missing = roles[role] - want_keys, [a for a in want if acl_key(a) not in roles[role]]
            if extra or missing:
                lines.append(f"acl      {login}: +{len(missing)} -{len(extra)} entries")
                commands += [{"command": "removeRoleACL", "rolename": role, "acltype": t, "topic": topic}
                             for t, topic, _ in sorted(extra)]
                commands += [{"command": "addRoleACL", "rolename": role, **a} for a in missing]
        if login not in clients:
            if login not in passwords and not need_passwords:
                lines.append(f"add      {login}: {kind} (needs its password in --passwords)")
                continue
            password = new_login_password(fleet, login, passwords, "Mosquitto, whose dynamic-security plugin "
                                                                   "takes passwords in clear text only")
            lines.append(f"add      {login}: {kind}")
            commands.append({"command": "createClient", "username": login, "password": password,
                             "textname": TEXTNAME[kind], "roles": [{"rolename": role}]})
        elif clients[login] != kind:
            lines.append(f"kind     {login}: {clients[login]} → {kind}")
            commands.append({"command": "modifyClient", "username": login, "textname": TEXTNAME[kind]})
    for login in sorted(clients):
        if login not in acl.logins:
            lines.append(f"remove   {login}: {clients[login]}")
            commands.append({"command": "deleteClient", "username": login})
    for role in sorted(roles):
        if role[len(ROLE_PREFIX):] not in acl.logins:
            commands.append({"command": "deleteRole", "rolename": role})
    return lines, commands


def apply_mosquitto(channel: AdminChannel, fleet: Fleet, *, passwords_file: str | None, dry_run: bool) -> int:
    """Plan and (unless ``dry_run``) send the plugin's commands; how many logins changed."""
    from .fleet_apply import print_plan

    passwords = read_passwords(passwords_file) if passwords_file else {}
    clients, roles = live_state(channel)
    lines, commands = dynsec_plan(fleet, clients, roles, passwords, need_passwords=not dry_run)
    print_plan(f"mosquitto (dynamic security) {channel.login.url}:", lines)
    if dry_run or not commands:
        return 0
    _send(channel, commands)
    left, _ = dynsec_plan(fleet, *live_state(channel), passwords)
    if left:
        raise AdminError("Mosquitto still differs after apply: " + "; ".join(left))
    return len(lines)
