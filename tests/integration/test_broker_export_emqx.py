"""``acl export --format emqx``: Erlang's own parser reads acl.conf, and its rules decide as the fleet's ACL.

EMQX itself is not run here (no Debian package); Erlang comes with rabbitmq-server (.ci/run installs it).
"""

from __future__ import annotations

import csv
import hashlib
import shutil
import subprocess

import paho.mqtt.client as mqtt
import pytest

from roslink_mqtt.broker.acl import FleetAcl
from roslink_mqtt.broker.export_emqx import export_emqx
from roslink_mqtt.config import load_fleet
from tests.support.acl_matrix import CLASSES, PRINCIPALS, SELF, topic_of
from tests.support.broker_setup import write_fleet
from tests.support.procs import DEMO_PASSWORDS

# Erlang reads the file as EMQX does (file:consult) and prints each rule in a form Python can split.
CONSULT = ('case file:consult("{path}") of {{ok, Terms}} -> lists:foreach(fun'
           '({{allow, {{username, U}}, A, [T]}}) -> io:format("allow\\t~s\\t~s\\t~s~n", [U, A, T]); '
           '({{deny, all}}) -> io:format("deny\\tall~n"); (Other) -> io:format("odd\\t~p~n", [Other]) end, Terms), '
           'halt(0); Error -> io:format("~p~n", [Error]), halt(1) end.')


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    work = tmp_path_factory.mktemp("emqx")
    fleet = load_fleet(write_fleet(work))
    return fleet, export_emqx(fleet, work / "out", DEMO_PASSWORDS)


def test_acl_conf_parses_and_decides_as_the_fleet_acl(exported) -> None:
    fleet, files = exported
    erl = shutil.which("erl")
    assert erl, "erl not found: it comes with rabbitmq-server (apt-get install rabbitmq-server)"
    done = subprocess.run([erl, "-noshell", "-eval", CONSULT.format(path=files.acl)], capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == 0, f"Erlang could not read acl.conf: {done.stdout}{done.stderr}"
    rules = [line.split("\t") for line in done.stdout.splitlines()]
    assert rules[-1] == ["deny", "all"] and not any(r[0] == "odd" for r in rules)

    def allowed(login: str, topic: str, action: str) -> bool:  # first match wins, as EMQX
        for rule in rules:
            if rule[0] == "deny":
                return False
            _, user, act, pattern = rule
            if user == login and act in (action, "all") and mqtt.topic_matches_sub(pattern, topic):
                return True
        return False

    acl = FleetAcl(fleet)
    universe = sorted({topic_of(c, SELF[p], publish=pub) for p in PRINCIPALS for c in CLASSES if c != "$SYS"
                       for pub in (False, True)})
    for login in DEMO_PASSWORDS:
        for topic in universe:
            assert allowed(login, topic, "publish") == acl.allows(login, topic, "publish"), (login, topic)
            assert allowed(login, topic, "subscribe") == acl.allows(login, topic, "receive"), (login, topic)


def test_users_csv_hashes_as_emqx_sha256_with_salt_suffix(exported) -> None:
    _, files = exported
    with files.users.open() as f:
        rows = list(csv.DictReader(f))
    assert {r["user_id"] for r in rows} == set(DEMO_PASSWORDS)
    for row in rows:
        expected = hashlib.sha256((DEMO_PASSWORDS[row["user_id"]] + row["salt"]).encode()).hexdigest()
        assert row["password_hash"] == expected
        assert row["is_superuser"] == ("true" if row["user_id"] == "admin" else "false")
