"""Login errors say one thing everywhere (issue 30 item 5), through the real CLI and SDK against the embedded broker.

A wrong password and an unknown user both read "wrong username or password" (CONNACK 5 from the broker, which
never says which logins exist), and an ``mqtt://`` URL that names the broker's TLS listener says so at once
("this port speaks TLS: use mqtts://…") instead of "no answer within 10 s". The dashboard's side is in
tests/browser/test_dashboard_browser.py; the bridge's in tests/integration/test_bridge_start_order.py.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from collections.abc import Iterator

import pytest

from roslink_mqtt.client import LoginRefused, RobotClient
from roslink_mqtt.mqtt import WRONG_LOGIN
from tests.support.broker_setup import write_fleet
from tests.support.embedded_broker import EmbeddedBrokerProcess
from tests.support.net import free_port
from tests.support.procs import ROOT

pytestmark = [pytest.mark.timeout(90),
              pytest.mark.skipif(shutil.which("openssl") is None, reason="openssl not installed")]


@pytest.fixture(scope="module")
def broker(tmp_path_factory) -> Iterator[tuple[int, int]]:
    """(plain MQTT port, TLS port) of one embedded broker of the demo fleet."""
    work = tmp_path_factory.mktemp("login-errors")
    subprocess.run(["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "1", "-subj", "/CN=127.0.0.1",
                    "-addext", "subjectAltName=IP:127.0.0.1", "-keyout", str(work / "key.pem"),
                    "-out", str(work / "cert.pem")], check=True, capture_output=True)
    tls_port = free_port()
    fleet = write_fleet(work, read_only_service=False, edit=lambda t: t.replace(
        "  ws_port: 0\n", f"  ws_port: 0\n  tls: {{port: {tls_port}, certfile: cert.pem, keyfile: key.pem}}\n"))
    with EmbeddedBrokerProcess(work, fleet) as process:
        yield process.port, tls_port


def cli(url: str, user: str, password: str) -> tuple[subprocess.CompletedProcess, float]:
    started = time.monotonic()
    done = subprocess.run([sys.executable, "-m", "roslink_mqtt.cli.main", "robots", "--url", url, "-u", user],
                          capture_output=True, text=True, env={**os.environ, "ROSLINK_PASSWORD": password}, cwd=ROOT,
                          timeout=30, stdin=subprocess.DEVNULL)
    return done, time.monotonic() - started


def test_wrong_password_and_unknown_user_read_the_same(broker) -> None:
    url = f"mqtt://127.0.0.1:{broker[0]}"
    wrong, _ = cli(url, "alice", "not-her-password")
    unknown, _ = cli(url, "mallory", "anything")
    print(f"\nwrong password: {wrong.stderr.strip()}\nunknown user:   {unknown.stderr.strip()}")
    for done, user in ((wrong, "alice"), (unknown, "mallory")):
        assert done.returncode == 1, done.stdout + done.stderr
        assert f"broker {url} refused {user}: {WRONG_LOGIN}" in done.stderr, done.stderr
        assert "authori" not in done.stderr.lower() and "Traceback" not in done.stderr
    assert wrong.stderr.replace("alice", "X") == unknown.stderr.replace("mallory", "X")  # nothing tells them apart

    with pytest.raises(LoginRefused, match=f"refused alice: {WRONG_LOGIN}$"):  # the SDK says it in the same words
        RobotClient("alice", "not-her-password", url=url, presence=False).connect()


def test_plain_mqtt_at_the_tls_port_says_use_mqtts(broker) -> None:
    done, took = cli(f"mqtt://127.0.0.1:{broker[1]}", "alice", "alice-demo")
    print(f"\nmqtt:// at the TLS port ({took:.1f} s): {done.stderr.strip()}")
    assert done.returncode == 1, done.stdout + done.stderr
    assert f"this port speaks TLS: use mqtts://127.0.0.1:{broker[1]}" in done.stderr, done.stderr
    assert took < 6, f"took {took:.1f} s: the broker hung up at once, so should the client"  # was 10 s of waiting
