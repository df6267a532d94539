"""A broker listening beyond this machine: plain listeners need broker.allow_plaintext, demo passwords are refused."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from roslink_mqtt.config import hash_password, load_fleet
from roslink_mqtt.config.exposure import demo_logins, exposure_problems, is_loopback
from roslink_mqtt.config.model import TlsSettings

DEMO = Path(__file__).resolve().parents[2] / "config" / "robots.yaml"


@pytest.fixture(scope="module")
def demo():
    return load_fleet(DEMO)


def _fresh(fleet, **broker):
    """The demo fleet with new passwords for every login (and broker settings changed)."""
    robots = {n: dataclasses.replace(r, password_hash=hash_password(f"{n}-fresh!", iterations=1000))
              for n, r in fleet.robots.items()}
    users = {n: dataclasses.replace(u, password_hash=hash_password(f"{n}-fresh!", iterations=1000))
             for n, u in fleet.users.items()}
    return dataclasses.replace(fleet, robots=robots, users=users,
                               broker=dataclasses.replace(fleet.broker, **broker))


@pytest.mark.parametrize(("host", "loopback"), [("127.0.0.1", True), ("127.0.1.1", True), ("::1", True),
                                                ("localhost", True), ("0.0.0.0", False), ("10.0.0.5", False),
                                                ("::", False), ("broker.example.org", False)])
def test_only_loopback_is_loopback(host: str, loopback: bool) -> None:
    assert is_loopback(host) is loopback


def test_the_demo_fleet_on_loopback_is_fine(demo) -> None:
    assert exposure_problems(demo) == [] and exposure_problems(demo, "127.0.0.1") == []


def test_the_demo_fleet_on_every_interface_is_refused_for_both_reasons(demo) -> None:
    plain, passwords = exposure_problems(demo, "0.0.0.0")
    assert "broker.host 0.0.0.0 is not loopback, and plain MQTT and MQTT over WebSocket would carry" in plain
    assert "broker.allow_plaintext: true" in plain
    assert passwords.startswith("turtle1, turtle2, alice, bob, carol, admin still log in with the demo fleet's")
    assert sorted(demo_logins(demo)) == sorted([*demo.robots, *demo.users])


def test_fresh_passwords_and_allow_plaintext_pass_and_each_is_needed(demo) -> None:
    assert exposure_problems(_fresh(demo, allow_plaintext=True), "0.0.0.0") == []
    only_plain = exposure_problems(_fresh(demo, ws_port=None), "0.0.0.0")
    assert len(only_plain) == 1 and "plain MQTT would carry" in only_plain[0]  # no WebSocket listener to name
    only_demo = exposure_problems(dataclasses.replace(demo, broker=dataclasses.replace(demo.broker,
                                                                                        allow_plaintext=True)),
                                  "0.0.0.0")
    assert len(only_demo) == 1 and "demo fleet's published passwords" in only_demo[0]


def test_a_public_tls_listener_beside_loopback_plain_ones_needs_fresh_passwords_only(demo) -> None:
    """broker.tls.host 0.0.0.0 with host 127.0.0.1: plain MQTT stays on this machine, so allow_plaintext is not
    needed; the demo's published passwords are refused on the TLS address as anywhere public."""
    tls = TlsSettings(8883, "cert.pem", "key.pem", host="0.0.0.0")
    [passwords] = exposure_problems(dataclasses.replace(demo, broker=dataclasses.replace(demo.broker, tls=tls)))
    assert "demo fleet's published passwords" in passwords and passwords.endswith("listens on 0.0.0.0")
    assert exposure_problems(_fresh(demo, tls=tls)) == []
    assert _fresh(demo, tls=tls).broker.tls_host() == "0.0.0.0"
    # plain ones public too: both reasons, both addresses named once
    both = exposure_problems(dataclasses.replace(demo, broker=dataclasses.replace(demo.broker, tls=tls)), "10.0.0.5")
    assert len(both) == 2 and both[1].endswith("listens on 10.0.0.5 and 0.0.0.0")
    assert "broker.tls.host" in both[0]


def test_a_tls_only_broker_on_a_public_host_needs_fresh_passwords_only(demo) -> None:
    """port: 0 and ws_port: 0 turn the plain listeners off: on 0.0.0.0 only TLS listens, nothing in clear text, so
    allow_plaintext is not needed; a plain listener turned back on by the command line is refused again."""
    tls = TlsSettings(8883, "cert.pem", "key.pem")
    tls_only = _fresh(demo, host="0.0.0.0", port=0, ws_port=None, tls=tls)
    assert exposure_problems(tls_only) == []
    [plain] = exposure_problems(tls_only, port=1883)
    assert "plain MQTT would carry every login's password in clear text" in plain and "port: 0" in plain
    [ws] = exposure_problems(tls_only, ws_port=8083)
    assert "MQTT over WebSocket would carry" in ws


def test_a_websocket_listener_on_an_address_of_its_own_is_judged_there(demo) -> None:
    """broker.ws_host: the WebSocket listener's own address. Public, it is refused (clear text) while plain MQTT on
    loopback is not named; on loopback beside a public wss:// listener (tls.ws_port) nothing is in clear text."""
    [plain] = exposure_problems(_fresh(demo, ws_host="0.0.0.0"))
    assert plain.startswith("broker.ws_host 0.0.0.0 is not loopback, and MQTT over WebSocket would carry")
    wss = TlsSettings(8883, "cert.pem", "key.pem", host="0.0.0.0", ws_port=8084)
    assert exposure_problems(_fresh(demo, tls=wss)) == []
    [passwords] = exposure_problems(dataclasses.replace(demo, broker=dataclasses.replace(demo.broker, tls=wss)))
    assert "demo fleet's published passwords" in passwords
