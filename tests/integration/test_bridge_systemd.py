"""systemd notifications from a real bridge process: READY, STATUS, WATCHDOG, STOPPING."""

from __future__ import annotations

import signal
import socket
import time

import pytest

from tests.support.fleet_brokers import mosquitto_with_logins
from tests.support.procs import bridge_args, bridge_env, run

pytestmark = pytest.mark.timeout(60)


def test_bridge_notifies_systemd(tmp_path) -> None:
    path = tmp_path / "notify.sock"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(path))
    sock.settimeout(0.5)
    env = {**bridge_env("turtle1"), "NOTIFY_SOCKET": str(path), "WATCHDOG_USEC": "1000000"}
    seen: list[str] = []

    def collect(until: float, wanted: str) -> None:
        while time.monotonic() < until and not any(wanted in m for m in seen):
            try:
                seen.append(sock.recv(1024).decode())
            except TimeoutError:
                pass

    with mosquitto_with_logins(tmp_path) as port, \
            run(bridge_args("turtle1", port), tmp_path / "bridge.log", env) as bridge:
        collect(time.monotonic() + 20, "STATUS=connected")
        collect(time.monotonic() + 3, "WATCHDOG=1")
        bridge.signal(signal.SIGTERM)
        collect(time.monotonic() + 5, "STOPPING=1")
    sock.close()
    assert any(m.startswith("READY=1") for m in seen), seen
    assert any("STATUS=connected to mqtt://127.0.0.1" in m for m in seen), seen
    assert "WATCHDOG=1" in seen and "STOPPING=1" in seen, seen
