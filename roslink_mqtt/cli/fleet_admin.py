"""An administrator's MQTT connection for ``roslink-mqtt fleet apply``: requests on a broker's control topic
(the embedded broker's ``$CONTROL/roslink/v1``, Mosquitto's ``$CONTROL/dynamic-security/v1``), retained reads and
retained writes (the robots' grants), each waited for.

Plain paho, synchronous: apply is a short script of request → answer steps, and every wait has a deadline that
names what did not come.
"""

from __future__ import annotations

import itertools
import queue
import threading
import time
from typing import Any

import paho.mqtt.client as mqtt

from ..connection_options import Login
from ..mqtt import acknowledged, connack_refusal, make_client
from ..protocol.errors import ProtocolError
from ..protocol.fleet_control import ControlRequest, ControlResponse


class AdminError(RuntimeError):
    """A request was refused or not answered; the message says which and why."""


class AdminChannel:
    """One admin login on one broker, for the length of a ``with`` block."""

    def __init__(self, login: Login, *, timeout: float = 10.0) -> None:
        self.login, self.timeout = login, timeout
        self._client = make_client(f"{login.username}-fleet-apply-{int(time.time() * 1000) % 10**9}",
                                   username=login.username, password=login.password, url=login.url,
                                   ca_file=login.ca_file)
        self._connected = threading.Event()
        self._refused: str | None = None
        self._inbox: queue.Queue[tuple[str, bytes, bool]] = queue.Queue()
        self._acked: set[int] = set()  # SUBACKed message ids (paho's thread may see one before subscribe returns)
        self._acks = threading.Condition()
        self._ids = itertools.count(1)
        self._subscriptions: set[str] = set()  # response topics subscribed to
        self._client.on_connect = self._on_connect
        self._client.on_message = lambda _c, _u, m: self._inbox.put((m.topic, bytes(m.payload), bool(m.retain)))
        self._client.on_subscribe = self._on_subscribe

    def _on_connect(self, _client: Any, _userdata: Any, _flags: Any, reason: Any, _props: Any = None) -> None:
        if reason == 0 or getattr(reason, "value", None) == 0:
            self._connected.set()
        else:
            self._refused = connack_refusal(reason)
            self._connected.set()

    def _on_subscribe(self, _client: Any, _userdata: Any, mid: int, reasons: Any, _props: Any = None) -> None:
        with self._acks:
            self._acked.add(mid)
            self._acks.notify_all()

    def __enter__(self) -> AdminChannel:
        from ..mqtt import parse_broker_urls

        url = parse_broker_urls(self.login.url or "")[0]
        try:
            self._client.connect(url.host, url.port, keepalive=30)
        except OSError as err:
            raise AdminError(f"cannot reach {self.login.url}: {err.strerror or err}") from None
        self._client.loop_start()
        if not self._connected.wait(self.timeout):
            self.close()
            raise AdminError(f"{self.login.url} did not answer within {self.timeout:g} s")
        if self._refused is not None:
            self.close()
            raise AdminError(f"{self.login.url} refused {self.login.username}: {self._refused}")
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._client.disconnect()
        self._client.loop_stop()

    def subscribe(self, topic_filter: str) -> None:
        result, mid = self._client.subscribe(topic_filter, qos=1)
        with self._acks:
            acked = result == mqtt.MQTT_ERR_SUCCESS and self._acks.wait_for(lambda: mid in self._acked, self.timeout)
        if not acked:
            raise AdminError(f"could not subscribe to {topic_filter} on {self.login.url}")

    def publish(self, topic: str, payload: bytes, *, retain: bool = False) -> None:
        if not acknowledged(self._client.publish(topic, payload, qos=1, retain=retain), self.timeout):
            raise AdminError(f"{self.login.url} did not acknowledge the message on {topic}")

    def request(self, topic: str, response_topic: str, commands: list[dict[str, Any]]) -> list[dict[str, Any]]:
        """Send ``commands`` on a control topic; the responses, in order (each has ``data`` or ``error``).

        Requests are matched to responses by an id: ours at the top level (the embedded broker echoes it) and as
        each command's ``correlationData`` (Mosquitto's dynamic-security plugin echoes that per command)."""
        if response_topic not in self._subscriptions:
            self.subscribe(response_topic)
            self._subscriptions.add(response_topic)
        rid = f"apply-{next(self._ids)}"
        tagged = tuple({**c, "correlationData": f"{rid}-{i}"} for i, c in enumerate(commands))
        self.publish(topic, ControlRequest(tagged, rid).to_json())
        deadline = time.monotonic() + self.timeout
        while (left := deadline - time.monotonic()) > 0:
            try:
                got_topic, payload, _ = self._inbox.get(timeout=left)
            except queue.Empty:
                break
            if got_topic != response_topic:
                continue
            try:
                response = ControlResponse.from_json(payload)
            except ProtocolError:
                continue
            if response.answers(rid):
                return list(response.responses)
        raise AdminError(f"no answer on {response_topic} within {self.timeout:g} s (is {self.login.username} an "
                         f"administrator of this broker?)")

    def retained(self, topic_filter: str, quiet: float = 0.5) -> dict[str, bytes]:
        """The retained messages under ``topic_filter`` (collected until none came for ``quiet`` seconds)."""
        self.subscribe(topic_filter)
        out: dict[str, bytes] = {}
        while True:
            try:
                topic, payload, retained = self._inbox.get(timeout=quiet)
            except queue.Empty:
                break
            if retained and mqtt.topic_matches_sub(topic_filter, topic):
                out[topic] = payload
        self._client.unsubscribe(topic_filter)
        return out


def new_login_password(fleet: Any, login: str, passwords: dict[str, str] | Any, broker: str) -> str:
    """The clear-text password of ``login``, new to a broker that hashes passwords itself (``broker`` says which
    and why, for the refusal), checked against robots.yaml's hash: the broker must never accept a password the
    fleet file does not."""
    from ..config import verify_password

    password = passwords.get(login)
    if password is None:
        raise AdminError(f"{login} is new to {broker}: give its password in --passwords FILE ('login: password' "
                         "lines)")
    if not verify_password(password, fleet.password_hash(login) or ""):
        raise AdminError(f"--passwords: the password given for {login} does not match robots.yaml's hash")
    return str(password)
