"""One paho connection of a command that records or plays (``record``, ``play``): connect once, fail clearly.

The SDK's :class:`~roslink_mqtt.client.RobotClient` brings presence, directories and reconnects that a recorder
or a player does not want; these need a login, one CONNACK and a reason when it is refused.
"""

from __future__ import annotations

import threading
import time
from typing import Any

import paho.mqtt.client as mqtt

from ..mqtt import connack_refusal, make_client, parse_broker_urls
from .errors import ConnectError


class PlainLogin:
    """A paho client for ``username`` at ``url``; :meth:`connect` waits for the broker's answer."""

    def __init__(self, *, url: str, username: str, password: str, ca_file: str | None, role: str) -> None:
        """``role`` names the program in its client id (``bob-record-…``)."""
        self.url, self.username = url, username
        self._connected = threading.Event()
        self._refused: str | None = None
        self.client_id = f"{username}-{role}-{time.monotonic_ns() % 10**9}"
        self.client = make_client(self.client_id, username=username, password=password, url=url, ca_file=ca_file)
        self.client.on_connect = self._on_connect

    def _on_connect(self, client: mqtt.Client, _userdata: Any, _flags: Any, reason: Any, _props: Any = None) -> None:
        if getattr(reason, "value", reason) != 0:
            self._refused = connack_refusal(reason)
        else:
            self.on_connected(client)
        self._connected.set()

    def on_connected(self, client: mqtt.Client) -> None:
        """Called on paho's thread once the login is accepted (subscribe here)."""

    def connect(self, timeout: float = 10.0) -> None:
        broker = parse_broker_urls(self.url)[0]
        self.client.connect(broker.host, broker.port, keepalive=30)
        self.client.loop_start()
        if not self._connected.wait(timeout):
            raise ConnectError(f"{self.url} did not answer within {timeout:g} s")
        if self._refused is not None:
            raise ConnectError(f"{self.url} refused {self.username}: {self._refused}")

    def disconnect(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()
