"""``acl export --format rabbitmq``: the topic expressions decide exactly as the fleet's ACL (pure logic).

The cluster itself (import, logins, the matrix over three nodes) is tests/integration/test_rabbitmq_cluster.py.
"""

from __future__ import annotations

import base64
import hashlib
import json
import os
import pwd
import re
import subprocess
import sys

import pytest

from roslink_mqtt.broker.acl import FleetAcl
from roslink_mqtt.broker.export import ExportError, default_owner
from roslink_mqtt.broker.export_rabbitmq import definitions, rabbit_password_hash, rabbitmq_conf_text
from roslink_mqtt.config import load_fleet
from tests.support.acl_matrix import CLASSES, PRINCIPALS, SELF, WILDCARDS, topic_of
from tests.support.broker_setup import write_fleet
from tests.support.procs import DEMO_PASSWORDS, ROOT


def routing_key(topic: str) -> str:
    """What RabbitMQ's MQTT plugin matches: '/' and '.' swapped, a filter's '+' as '*' ('#' stays)."""
    return "/".join(level.replace("+", "*") for level in topic.split("/")).translate(str.maketrans("/.", "./"))


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    return load_fleet(write_fleet(tmp_path_factory.mktemp("rabbit-export")))


@pytest.fixture(scope="module")
def doc(fleet) -> dict:
    return definitions(fleet, DEMO_PASSWORDS)


def _topic_rules(doc: dict, login: str) -> tuple[re.Pattern, re.Pattern]:
    (rule,) = [t for t in doc["topic_permissions"] if t["user"] == login]
    assert rule["exchange"] == "amq.topic" and rule["vhost"] == "roslink"
    return re.compile(rule["write"]), re.compile(rule["read"])


def test_topic_expressions_decide_as_the_fleet_acl(fleet, doc) -> None:
    acl = FleetAcl(fleet)
    universe = sorted({topic_of(c, SELF[p], publish=pub) for p in PRINCIPALS for c in CLASSES if c != "$SYS"
                       for pub in (False, True)})
    checked = 0
    for login in DEMO_PASSWORDS:
        write, read = _topic_rules(doc, login)
        for topic in universe:
            key = routing_key(topic)
            assert bool(write.fullmatch(key)) == acl.allows(login, topic, "publish"), (login, topic, "write")
            assert bool(read.fullmatch(key)) == acl.allows(login, topic, "receive"), (login, topic, "read")
            checked += 2
    assert checked > 300


def test_a_subscription_passes_only_inside_the_grant(doc) -> None:
    """RabbitMQ checks the whole filter: wildcards within a grant pass, wider ones are refused (not filtered)."""
    def granted(login: str, flt: str) -> bool:
        return bool(_topic_rules(doc, login)[1].fullmatch(routing_key(flt)))

    assert granted("turtle1", "roslink/turtle1/from/+/#")  # the bridge's own subscriptions
    assert granted("turtle1", "roslink/operators/alice/#")
    assert granted("alice", "roslink/turtle1/to/alice/#") and granted("alice", "roslink/turtle1/state/#")
    assert granted("alice", "roslink/turtle1/heartbeat")
    assert not granted("alice", "roslink/+/heartbeat")  # discovery by wildcard: refused outside admin
    assert not granted("bob", "roslink/turtle1/#") and not granted("bob", "roslink/turtle1/to/alice/#")
    assert not granted("carol", "roslink/turtle1/state/#")
    assert all(granted("admin", f) for f in WILDCARDS if not f.startswith("$"))


def test_password_hash_is_rabbitmqs_salted_sha256() -> None:
    stored = base64.b64decode(rabbit_password_hash("alice-demo", salt=b"\x01\x02\x03\x04"))
    assert stored[:4] == b"\x01\x02\x03\x04"
    assert stored[4:] == hashlib.sha256(b"\x01\x02\x03\x04alice-demo").digest()


def test_passwords_must_be_complete_and_match_the_fleet(fleet) -> None:
    partial = {k: v for k, v in DEMO_PASSWORDS.items() if k != "bob"}
    with pytest.raises(ExportError, match="no password for bob"):
        definitions(fleet, partial)
    with pytest.raises(ExportError, match="given for alice does not match"):
        definitions(fleet, {**DEMO_PASSWORDS, "alice": "guess"})
    with pytest.raises(ExportError, match="not in .*: mallory"):
        definitions(fleet, {**DEMO_PASSWORDS, "mallory": "x"})


def test_definitions_shape(fleet, doc, tmp_path) -> None:
    assert {u["name"] for u in doc["users"]} == set(DEMO_PASSWORDS)
    assert all(u["tags"] == [] for u in doc["users"])  # MQTT logins only: none may use the management API
    assert doc["vhosts"] == [{"name": "roslink"}]
    conf = rabbitmq_conf_text(fleet, tmp_path / "definitions.json")
    assert "mqtt.allow_anonymous = false" in conf and "mqtt.vhost = roslink" in conf


def test_cli_writes_both_files_and_refuses_without_passwords(tmp_path) -> None:
    fleet = write_fleet(tmp_path)
    pw = tmp_path / "passwords.yaml"
    pw.write_text("".join(f"{k}: {v}\n" for k, v in DEMO_PASSWORDS.items()))
    base = [sys.executable, "-m", "roslink_mqtt.cli.main", "acl", "export", "--format", "rabbitmq",
            "--config", str(fleet), "--out", str(tmp_path / "out")]
    refused = subprocess.run(base, capture_output=True, text=True, cwd=ROOT)
    assert refused.returncode == 2 and "needs --passwords" in refused.stderr
    done = subprocess.run([*base, "--passwords", str(pw)], capture_output=True, text=True, cwd=ROOT)
    assert done.returncode == 0, done.stderr
    doc = json.loads((tmp_path / "out" / "definitions.json").read_text())
    assert len(doc["topic_permissions"]) == len(DEMO_PASSWORDS)
    written = (tmp_path / "out" / "definitions.json").stat()
    assert written.st_mode & 0o777 == 0o600
    # exported as root where Debian's RabbitMQ is installed: its user owns them (rabbitmqctl and the node run as it)
    expected = default_owner("rabbitmq")
    assert written.st_uid == (pwd.getpwnam(expected).pw_uid if expected else os.geteuid())
    assert (f"owner {expected}" in done.stdout) == (expected is not None)
