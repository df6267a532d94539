"""The shared paho client factory: URLs, and TCP_NODELAY on a real connection."""

from __future__ import annotations

import socket
import threading
from pathlib import Path

import pytest

from roslink_mqtt.mqtt import make_client, parse_broker_url
from tests.support.mosquitto import run_mosquitto


@pytest.mark.parametrize(("url", "expected"), [
    ("mqtt://127.0.0.1:1883", ("mqtt", "127.0.0.1", 1883, "tcp", False)),
    ("mqtts://broker.example", ("mqtts", "broker.example", 8883, "tcp", True)),
    ("ws://localhost:8083/mqtt", ("ws", "localhost", 8083, "websockets", False)),
    ("wss://h", ("wss", "h", 8084, "websockets", True)),
    ("127.0.0.1:1999", ("mqtt", "127.0.0.1", 1999, "tcp", False)),
])
def test_parse_broker_url(url: str, expected: tuple) -> None:
    u = parse_broker_url(url)
    assert (u.scheme, u.host, u.port, u.transport, u.tls) == expected


@pytest.mark.parametrize("bad", ["http://x", "mqtt://", "mqtt://h:99999"])
def test_bad_broker_urls(bad: str) -> None:
    with pytest.raises(ValueError):
        parse_broker_url(bad)


def test_nodelay_is_set_on_real_connection(tmp_path: Path) -> None:
    with run_mosquitto(tmp_path, "allow_anonymous true") as port:
        client = make_client("nodelay-test", url=f"mqtt://127.0.0.1:{port}")
        connected = threading.Event()
        client.on_connect = lambda *a: connected.set()
        client.connect("127.0.0.1", port)
        client.loop_start()
        try:
            assert connected.wait(5)
            assert client.socket().getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY) == 1
        finally:
            client.loop_stop()
            client.disconnect()
