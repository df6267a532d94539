"""A paho client for broker tests: SUBACK codes, QoS and retain flags of deliveries, wills, sessions.

:class:`tests.support.mqtt_client.TestClient` is made for fleet users; broker tests also need
clean_session=0, wills, WebSocket transport, a chosen source address and the raw CONNACK /
SUBACK codes. A refused login is never retried (paho would otherwise keep reconnecting).
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import paho.mqtt.client as mqtt

from roslink_mqtt.mqtt import set_nodelay

from .queues import drain

REFUSED = 135  # what paho reports for CONNACK 5 (not authorized)


@dataclass
class Msg:
    topic: str
    payload: bytes
    qos: int
    retain: bool
    at: float


class Probe:
    def __init__(self, port: int, username: str | None, password: str | None, client_id: str = "", *,
                 clean: bool = True, keepalive: int = 30, transport: str = "tcp",
                 will: tuple[str, bytes, int, bool] | None = None, bind_address: str = "",
                 host: str = "127.0.0.1") -> None:
        self.client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2,
                                  client_id=client_id or f"probe-{time.monotonic_ns()}", clean_session=clean,
                                  protocol=mqtt.MQTTv311, transport=transport)
        if username is not None:
            self.client.username_pw_set(username, password)
        if will is not None:
            self.client.will_set(*will)
        self.client.on_socket_open = lambda _c, _u, sock: set_nodelay(sock)
        self.client.reconnect_delay_set(0.1, 0.5)  # quick to reconnect, quick to stop when the broker is gone
        self.port, self.keepalive, self.bind_address, self.host = port, keepalive, bind_address, host
        self.messages: queue.Queue[Msg] = queue.Queue()
        self.session_present = False
        self.disconnected = threading.Event()
        self._connack: queue.Queue[int] = queue.Queue()
        self._subacks: dict[int, list[int]] = {}
        self._cond = threading.Condition()
        self.client.on_connect = self._on_connect
        self.client.on_disconnect = lambda *_a: self.disconnected.set()
        self.client.on_message = lambda _c, _u, m: self.messages.put(
            Msg(m.topic, m.payload, m.qos, bool(m.retain), time.monotonic()))
        self.client.on_subscribe = self._on_subscribe

    def _on_connect(self, client, _u, flags, rc, _p) -> None:
        if rc.is_failure:
            client.disconnect()  # never retry a refused login
        self.session_present = bool(flags.session_present)
        self._connack.put(rc.value)

    def _on_subscribe(self, _c, _u, mid, codes, _p) -> None:
        with self._cond:
            self._subacks[mid] = [c.value for c in codes]
            self._cond.notify_all()

    def connect(self, timeout: float = 10.0) -> int:
        """0 when accepted, else paho's reason code (135 = not authorized)."""
        self.client.connect(self.host, self.port, keepalive=self.keepalive, bind_address=self.bind_address)
        self.client.loop_start()
        return self._connack.get(timeout=timeout)

    def subscribe(self, filters: str | list[str], qos: int = 1) -> list[int]:
        """SUBACK return codes, one per filter (128 = refused)."""
        items = [filters] if isinstance(filters, str) else filters
        _, mid = self.client.subscribe([(f, qos) for f in items])
        with self._cond:
            assert self._cond.wait_for(lambda: mid in self._subacks, 10), "no SUBACK"
            return self._subacks.pop(mid)

    def publish(self, topic: str, payload: bytes | str, qos: int = 1, retain: bool = False) -> None:
        info = self.client.publish(topic, payload, qos=qos, retain=retain)
        if qos:
            info.wait_for_publish(10)

    def drain(self, seconds: float) -> list[Msg]:
        return drain(self.messages, seconds)

    def collect(self, count: int, timeout: float = 10.0, then: float = 0.3) -> list[Msg]:
        """The first ``count`` messages (fewer if they do not come in time), plus whatever else
        arrives within ``then`` s after them: exact-list assertions that tolerate a slow host."""
        deadline, out = time.monotonic() + timeout, []
        while len(out) < count and (left := deadline - time.monotonic()) > 0:
            try:
                out.append(self.messages.get(timeout=left))
            except queue.Empty:
                break
        return out + self.drain(then)

    def wait_for(self, predicate: Callable[[Msg], bool], timeout: float = 10.0) -> Msg:
        deadline = time.monotonic() + timeout
        while (left := deadline - time.monotonic()) > 0:
            try:
                msg = self.messages.get(timeout=left)
            except queue.Empty:
                break
            if predicate(msg):
                return msg
        raise TimeoutError(f"no matching message within {timeout} s")

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()

    def __enter__(self) -> Probe:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
