"""The fleet for Mosquitto's dynamic-security plugin (``roslink-mqtt acl export --format mosquitto-dynsec``).

With the plugin, Mosquitto keeps its logins and access rules in ``dynamic-security.json`` and changes them live,
through commands an administrator publishes on ``$CONTROL/dynamic-security/v1``: no reload, and a client whose
login or rules change is disconnected by the plugin at once. ``roslink-mqtt fleet apply --broker-kind mosquitto``
(cli/fleet_dynsec.py) sends those commands; this module writes the starting point and says what the plugin must
hold for a fleet, so the export and apply cannot disagree:

* one client per login (robots, users, admins), its ``textname`` saying which (:data:`TEXTNAME`), its password
  the fleet file's PBKDF2-SHA512 hash as the plugin stores it (hash, salt and iterations, base64): robots.yaml's
  ``$7$`` hashes carry over unchanged, no password is needed for the export;
* one role per login (``roslink-<login>``) holding that login's ACL, from the same
  :class:`~roslink_mqtt.broker.acl.AclEntry` list the embedded broker and the other exports use: a READ pattern
  becomes ``publishClientReceive``, a WRITE pattern ``publishClientSend``. Every login may subscribe to any filter
  (``subscribePattern #``): what it receives is filtered per message, live and retained, as the embedded broker
  and the plain Mosquitto export do;
* one difference: a robot's role reads every user's presence (``P/operators/+/#``), not only its granted
  users'. The plugin disconnects every client of a role whose ACL changes; with per-user presence entries, each
  grant given or taken on a robot would drop the robot's bridge (and, as a lost link does, stop the robot). Its
  bridge still listens only to its granted users (their commands are theirs alone to send); what the robot's login
  could read beyond that is who is online in the fleet, not what they send;
* administrators also get the plugin's own control topic (``$CONTROL/dynamic-security/#``);
* everything else is denied (``defaultACLAccess``).

Clients the plugin holds that this module did not make (no ``roslink`` textname: the bootstrap admin of
``mosquitto_ctrl dynsec init``) are left alone by apply.

No amqtt import: this runs on a client install.
"""

from __future__ import annotations

import base64
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..config import Fleet
from ..config.passwords import parse_hash
from ..protocol.body import BodyField, Boolean, Text, read
from ..topics import ANY, DYNSEC_FILTER, filter_levels
from .acl import Access, AclEntry, FleetAcl, topic_matches
from .export import ExportError, _write_private, mosquitto_conf_with, owner_ids

TEXTNAME = {"robot": "roslink robot", "user": "roslink user", "admin": "roslink admin"}
ROLE_PREFIX = "roslink-"
PLUGIN_PATHS = ("/usr/lib/x86_64-linux-gnu/mosquitto_dynamic_security.so",
                "/usr/lib/aarch64-linux-gnu/mosquitto_dynamic_security.so",
                "/usr/lib/mosquitto_dynamic_security.so", "/usr/local/lib/mosquitto_dynamic_security.so")


@dataclass(frozen=True, slots=True)
class DynsecFiles:
    config: Path  # dynamic-security.json
    conf: Path  # mosquitto.conf


def role_name(login: str) -> str:
    return ROLE_PREFIX + login


def kind_of(fleet: Fleet, login: str) -> str:
    return "robot" if login in fleet.robots else "admin" if fleet.users[login].admin else "user"


def role_acls(fleet: Fleet, login: str, acl: FleetAcl | None = None) -> list[dict[str, Any]]:
    """The ACL entries of ``login``'s role, in the plugin's words (``acltype``, ``topic``, ``allow``)."""
    acl = acl or FleetAcl(fleet)
    out: list[dict[str, Any]] = [{"acltype": "subscribePattern", "topic": "#", "allow": True}]
    entries = list(acl.entries(login))
    if login in fleet.robots:  # grant-independent, so that a grant change never disconnects the robot (below)
        presence = fleet.topics.operators_filter(ANY, deep=True)
        entries = [e for e in entries if not topic_matches(filter_levels(presence), e.levels)]
        entries.append(AclEntry(presence, Access.READ))
    for entry in entries:
        if entry.access & Access.READ:
            out.append({"acltype": "publishClientReceive", "topic": entry.pattern, "allow": True})
            if entry.pattern.startswith("$"):  # `#` does not reach $-topics (an admin's $SYS, $CONTROL)
                out.append({"acltype": "subscribePattern", "topic": entry.pattern, "allow": True})
        if entry.access & Access.WRITE:
            out.append({"acltype": "publishClientSend", "topic": entry.pattern, "allow": True})
    if kind_of(fleet, login) == "admin":  # the plugin's own control topic
        out += [{"acltype": "publishClientSend", "topic": DYNSEC_FILTER, "allow": True},
                {"acltype": "publishClientReceive", "topic": DYNSEC_FILTER, "allow": True},
                {"acltype": "subscribePattern", "topic": DYNSEC_FILTER, "allow": True}]
    return out


# An ACL entry as the plugin reports it (``listRoles``); what is compared (priority is not used)
ACL_ENTRY_FIELDS = (BodyField("acltype", Text(1), True, "publishClientSend, subscribePattern, …"),
                    BodyField("topic", Text(1), True, "a topic filter"),
                    BodyField("allow", Boolean(), False, "allow or deny", False))


def acl_key(entry: dict[str, Any]) -> tuple[str, str, bool]:
    """An ACL entry, for comparing: (type, topic, allow); ProtocolError when the plugin's is not one."""
    got = read(ACL_ENTRY_FIELDS, entry, shape="expected an ACL entry", strict=False, what="mosquitto ACL")
    return (got["acltype"], got["topic"], got["allow"])


def password_fields(stored: str) -> dict[str, Any]:
    """robots.yaml's ``$7$`` hash as the plugin stores a password: hash, salt (base64) and iterations."""
    scheme, iterations, salt, digest = parse_hash(stored)
    if scheme != "7":
        raise ExportError("Mosquitto's dynamic-security plugin needs PBKDF2-SHA512 ($7$) hashes: hash this "
                          "login's password again with `roslink-mqtt passwd`")
    return {"password": base64.b64encode(digest).decode(), "salt": base64.b64encode(salt).decode(),
            "iterations": iterations}


def dynsec_document(fleet: Fleet) -> dict[str, Any]:
    """dynamic-security.json for ``fleet``: every login, its role and ACL; nothing else allowed."""
    acl = FleetAcl(fleet)
    clients, roles = [], []
    for login in acl.logins:
        stored = fleet.password_hash(login) or ""
        try:
            fields = password_fields(stored)
        except ExportError as err:
            raise ExportError(f"{login}: {err}") from None
        clients.append({"username": login, "textname": TEXTNAME[kind_of(fleet, login)], **fields,
                        "roles": [{"rolename": role_name(login)}]})
        roles.append({"rolename": role_name(login), "acls": role_acls(fleet, login, acl)})
    return {"defaultACLAccess": {"publishClientSend": False, "publishClientReceive": False, "subscribe": False,
                                 "unsubscribe": True},
            "clients": clients, "groups": [], "roles": roles}


def plugin_path() -> str:
    """Where Debian (and most builds) put the plugin; the first that exists, else Debian's amd64 path."""
    return next((p for p in PLUGIN_PATHS if Path(p).exists()), PLUGIN_PATHS[0])


def export_dynsec(fleet: Fleet, out_dir: str | Path, owner: str | None = None) -> DynsecFiles:
    """Write ``dynamic-security.json`` and ``mosquitto.conf`` into ``out_dir``. The plugin rewrites the JSON file
    on every change, so ``owner`` (Mosquitto's user) must own it and the directory must be writable by it."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True, mode=0o755)
    ids = owner_ids(owner)
    files = DynsecFiles(out / "dynamic-security.json", out / "mosquitto.conf")
    document = json.dumps(dynsec_document(fleet), indent=1) + "\n"
    conf = mosquitto_conf_with(
        fleet, ["# Logins and access rules live in the dynamic-security plugin: change them with `roslink-mqtt fleet "
                "apply\n# --broker-kind mosquitto` (no reload needed). Mosquitto started as root drops to the user\n"
                "# 'mosquitto', which must own the plugin's file and be able to write its directory.\n"],
        [f"plugin {plugin_path()}\n", f"plugin_opt_config_file {files.config.resolve()}\n"])
    _write_private(files.config, document, ids)
    _write_private(files.conf, conf, ids)
    if ids is not None:
        import os

        os.chown(out, *ids)  # the plugin saves its file next to itself (a temporary file, then a rename)
    return files
