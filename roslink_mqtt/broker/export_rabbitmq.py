"""The fleet's logins and access rules for RabbitMQ's MQTT plugin (``roslink-mqtt acl export --format rabbitmq``).

Writes into one directory:

* ``definitions.json`` -- users, the fleet's vhost, each login's vhost permissions and its topic permissions on
  the MQTT exchange, in the format ``rabbitmqctl import_definitions`` (and ``load_definitions`` at boot) reads;
* ``rabbitmq.conf`` -- the MQTT plugin's settings: the fleet's vhost and exchange, anonymous logins off, the
  listener at the fleet's host and port, the payload limit, and the definitions file.

RabbitMQ keeps its own password hashes (salted SHA-256) and cannot use robots.yaml's PBKDF2 ones, so the export
needs each login's password: ``--passwords FILE`` (a YAML mapping ``login: password``). Each is checked against
robots.yaml's hash first, so the broker can never accept a password the fleet file does not.

Topic permissions are regular expressions over AMQP routing keys, in which RabbitMQ's MQTT plugin writes an MQTT
topic with ``/`` turned into ``.`` (and ``+``/``#`` of a subscription into ``*``/``#``). Each login's
:class:`~roslink_mqtt.broker.acl.AclEntry` list -- the one the embedded broker and the Mosquitto export use, so
they cannot drift -- becomes one ``write`` and one ``read`` expression. A subscription is checked as a whole
against ``read``: a filter wider than the login's grant (``roslink/+/heartbeat`` for a user) is refused, not
filtered as Mosquitto and the embedded broker do; the SDK copes (it then watches the robots it names).

No amqtt or RabbitMQ import: this runs on a client install.
"""

from __future__ import annotations

import base64
import hashlib
import json
import os
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from ..config import Fleet
from ..config.passwords import verify_password
from ..topics import filter_levels
from .acl import Access, AclEntry, FleetAcl
from .export import HEADER, ExportError, _write_private, owner_ids

VHOST = "roslink"  # one vhost per fleet: its logins see nothing of other vhosts' exchanges and queues
EXCHANGE = "amq.topic"  # the MQTT plugin's default exchange
HASHING = "rabbit_password_hashing_sha256"
# What MQTT clients need on the vhost's resources: the plugin declares one queue per client and QoS
# (``mqtt-subscription-<client id>qos0/1``) and binds it to the exchange; a last-will is published to the exchange.
QUEUES = r"^mqtt-subscription-.*$"
EXCHANGE_OR_QUEUES = rf"^({re.escape(EXCHANGE)}|mqtt-subscription-.*)$"
NOTHING = "^$"  # an empty-string regex would match everything: RabbitMQ reads "" as "any"


@dataclass(frozen=True, slots=True)
class RabbitFiles:
    definitions: Path
    conf: Path


def rabbit_password_hash(password: str, salt: bytes | None = None) -> str:
    """RabbitMQ's ``rabbit_password_hashing_sha256``: base64(salt ‖ SHA-256(salt ‖ password)), 4-byte salt."""
    salt = os.urandom(4) if salt is None else salt
    return base64.b64encode(salt + hashlib.sha256(salt + password.encode()).digest()).decode()


def _level_regex(level: str) -> str:
    if level == "+":
        return r"[^.]+"  # one level; also matches a subscription's '*' itself
    if "." in level or "*" in level:
        raise ExportError(f"topic level {level!r}: RabbitMQ's MQTT plugin maps '.' and '*' in topics to routing "
                          "key syntax, so a name with them cannot be authorised exactly (rename it)")
    return re.escape(level)


def filter_regex(pattern: str) -> str:
    """One MQTT filter as a regex over routing keys; ``a/#`` matches ``a``, ``a.x.y`` and a binding ``a.#``."""
    parts = filter_levels(pattern)
    if parts[-1] == "#":
        head = r"\.".join(_level_regex(p) for p in parts[:-1])
        return rf"{head}(\..*)?" if head else ".*"
    return r"\.".join(_level_regex(p) for p in parts)


def topic_permission_regex(entries: Iterable[AclEntry], access: Access) -> str:
    """Every pattern with ``access`` as one anchored alternation; ``^$`` (nothing) when there is none."""
    alternatives = [filter_regex(e.pattern) for e in entries
                    if e.access & access and not e.pattern.startswith("$")]  # no $SYS topics in RabbitMQ
    if not alternatives:
        return NOTHING
    if ".*" in alternatives:
        return "^.*$"
    return "^(" + "|".join(dict.fromkeys(alternatives)) + ")$"


def read_passwords(path: str | Path) -> dict[str, str]:
    """``login: password`` lines (YAML); a clear error for anything else."""
    try:
        data = yaml.safe_load(Path(path).read_text())
    except (OSError, yaml.YAMLError) as err:
        raise ExportError(f"--passwords {path}: {err}") from None
    if not isinstance(data, dict) or not all(isinstance(k, str) and isinstance(v, str) for k, v in data.items()):
        raise ExportError(f"--passwords {path}: expected a mapping of login: password (strings)")
    return data


def check_passwords(fleet: Fleet, passwords: Mapping[str, str]) -> None:
    """Every login has a password, and it is the one robots.yaml's hash was made from."""
    logins = [*fleet.robots, *fleet.users]
    missing = [login for login in logins if login not in passwords]
    if missing:
        raise ExportError(f"no password for {', '.join(missing)}: RabbitMQ cannot use robots.yaml's PBKDF2 hashes, "
                          "so the export needs every login's password (--passwords FILE, 'login: password' lines)")
    unknown = sorted(set(passwords) - set(logins))
    if unknown:
        raise ExportError(f"--passwords names logins that are not in {fleet.file}: {', '.join(unknown)}")
    wrong = [login for login in logins if not verify_password(passwords[login], fleet.password_hash(login) or "")]
    if wrong:
        raise ExportError(f"the password given for {', '.join(wrong)} does not match robots.yaml's hash: "
                          "the broker would accept a password the fleet file does not")


def definitions(fleet: Fleet, passwords: Mapping[str, str], *, vhost: str = VHOST,
                salt: bytes | None = None) -> dict[str, Any]:
    """The definitions document (RabbitMQ 3.10's schema) for the fleet: users, vhost, permissions, topic rules."""
    check_passwords(fleet, passwords)
    acl = FleetAcl(fleet)
    users, permissions, topic_permissions = [], [], []
    for login in acl.logins:
        admin = login in fleet.users and fleet.users[login].admin
        users.append({"name": login, "password_hash": rabbit_password_hash(passwords[login], salt),
                      "hashing_algorithm": HASHING, "tags": []})  # no management tags: MQTT only, even for admins
        permissions.append({"user": login, "vhost": vhost, "configure": QUEUES, "write": EXCHANGE_OR_QUEUES,
                            "read": EXCHANGE_OR_QUEUES})
        entries = acl.entries(login)
        topic_permissions.append({"user": login, "vhost": vhost, "exchange": EXCHANGE,
                                  "write": "^.*$" if admin else topic_permission_regex(entries, Access.WRITE),
                                  "read": "^.*$" if admin else topic_permission_regex(entries, Access.READ)})
    return {"rabbit_version": "3.10.8", "rabbitmq_version": "3.10.8", "users": users,
            "vhosts": [{"name": vhost}], "permissions": permissions, "topic_permissions": topic_permissions,
            "parameters": [], "global_parameters": [], "policies": [], "queues": [], "exchanges": [],
            "bindings": []}


def rabbitmq_conf_text(fleet: Fleet, definitions_file: Path, *, vhost: str = VHOST) -> str:
    b = fleet.broker
    return "".join([
        HEADER.format(file=fleet.file),
        "# Each node of a cluster gets this file; the definitions are imported once (they are cluster-wide).\n",
        # port: 0 (TLS only): no plain listener; RabbitMQ's TLS one (mqtt.listeners.ssl.*) is the operator's to add
        f"mqtt.listeners.tcp.default = {b.host}:{b.port}\n" if b.port else "mqtt.listeners.tcp = none\n",
        "mqtt.allow_anonymous = false\n",
        f"mqtt.vhost = {vhost}\n",
        f"mqtt.exchange = {EXCHANGE}\n",
        # a heartbeat or presence retained on one node is not seen on the others (RabbitMQ 3.10 keeps retained
        # messages per node): docs/scaling.md says what that means for presence
        "mqtt.retained_message_store = rabbit_mqtt_retained_msg_store_dets\n",
        f"max_message_size = {max(b.max_payload, 4096)}\n",
        f"load_definitions = {definitions_file.resolve()}\n",
    ])


RABBITMQ_USER = "rabbitmq"  # the account Debian's RabbitMQ node and rabbitmqctl run as


def export_rabbitmq(fleet: Fleet, out_dir: str | Path, passwords: Mapping[str, str], *,
                    vhost: str = VHOST, owner: str | None = None) -> RabbitFiles:
    """Write ``definitions.json`` and ``rabbitmq.conf`` into ``out_dir`` (mode 600; definitions hold hashes).

    ``owner``: the user who must read them (Debian's ``rabbitmqctl`` and node run as ``rabbitmq``); None: you.
    """
    ids = owner_ids(owner)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True, mode=0o755)
    files = RabbitFiles(out / "definitions.json", out / "rabbitmq.conf")
    doc = definitions(fleet, passwords, vhost=vhost)
    _write_private(files.definitions, json.dumps(doc, indent=2) + "\n", ids)
    _write_private(files.conf, rabbitmq_conf_text(fleet, files.definitions, vhost=vhost), ids)
    return files
