"""A port whose last connection is in TIME_WAIT is free for the broker, and the demo's check agrees (issue 43, 1).

`make demo` then `make dashboard` within a minute: the first demo's broker closed its connections, so port 1883
sat in TIME_WAIT; the check bound without SO_REUSEADDR, called it taken and moved the demo to another port, and
the README's commands then reached nothing. The check now binds as the broker does (localproc.can_listen).
"""

from __future__ import annotations

import socket
import time
from pathlib import Path

from roslink_mqtt.demo import _pick_port
from roslink_mqtt.localproc import can_listen, port_free
from tests.support.embedded_broker import EmbeddedBrokerProcess
from tests.support.mqtt_client import TestClient
from tests.support.net import free_port
from tests.support.waits import wait_until

TIME_WAIT = "06"  # /proc/net/tcp's state code


def _states(port: int) -> set[str]:
    """The TCP states of every local socket on ``port``."""
    found = set()
    for row in Path("/proc/net/tcp").read_text().splitlines()[1:]:
        fields = row.split()
        if int(fields[1].rsplit(":", 1)[1], 16) == port:
            found.add(fields[3])
    return found


def _leave_in_time_wait(port: int) -> None:
    """A server on ``port`` that closes its accepted connection first: the port's side ends in TIME_WAIT."""
    with socket.socket() as server:
        server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        server.bind(("127.0.0.1", port))
        server.listen()
        client = socket.create_connection(("127.0.0.1", port))
        accepted, _ = server.accept()
        accepted.close()  # the server's side closes first: it is the one left in TIME_WAIT
        deadline = time.monotonic() + 5
        while client.recv(1) and time.monotonic() < deadline:
            pass
        client.close()
    wait_until(f"TIME_WAIT on port {port}", lambda: TIME_WAIT in _states(port), timeout=5, period=0.01)


def test_a_port_in_time_wait_is_kept_by_the_demo_and_bound_by_the_broker(tmp_path, capsys) -> None:
    port = free_port()
    _leave_in_time_wait(port)
    assert not port_free(port)  # the old check's answer: "taken"
    assert can_listen(port)
    assert _pick_port(port, "the fleet's MQTT port") == port
    assert "is taken by" not in capsys.readouterr().out

    broker = EmbeddedBrokerProcess(tmp_path)
    broker.port = port  # the port in TIME_WAIT, as 1883 was after the last demo
    broker.start()
    try:
        with TestClient(port, "admin", "admin-demo") as admin:
            assert admin.connect() == 0
    finally:
        broker.stop()


def test_a_port_with_a_listener_is_still_taken_and_the_demo_says_by_whom(capsys) -> None:
    with socket.socket() as server:
        server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        server.bind(("127.0.0.1", 0))
        server.listen()
        port = server.getsockname()[1]
        assert not can_listen(port)
        other = _pick_port(port, "the fleet's MQTT port")
        assert other != port
        out = capsys.readouterr().out
        assert f"port {port}" in out and "is taken by" in out and "python" in out.lower()
