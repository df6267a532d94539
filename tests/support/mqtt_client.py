"""A small synchronous paho wrapper for tests: connect as a fleet user, collect what arrives."""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import orjson

from roslink_mqtt.client.presence import OperatorPresence
from roslink_mqtt.mqtt import make_client

from .queues import drain


@dataclass
class Received:
    topic: str
    payload: bytes
    retain: bool
    at: float
    qos: int = 0

    def json(self):
        return orjson.loads(self.payload)


class TestClient:
    __test__ = False

    def __init__(self, port: int, username: str | None, password: str | None, client_id: str | None = None,
                 keepalive: int = 30, operator: bool = False) -> None:
        """``operator=True`` runs operator presence (heartbeat + last-will), as commanding clients must."""
        self.client_id = client_id or f"test-{username}-{time.monotonic_ns()}"
        self.client = make_client(self.client_id, username=username, password=password,
                                  url=f"mqtt://127.0.0.1:{port}")
        self.presence = OperatorPresence(self.client, username, self.client_id) if operator else None
        self.messages: queue.Queue[Received] = queue.Queue()
        self.connack: queue.Queue[int] = queue.Queue()
        self.client.on_connect = lambda c, u, f, rc, p: self.connack.put(rc.value)
        self.client.on_message = lambda c, u, m: self.messages.put(
            Received(m.topic, m.payload, bool(m.retain), time.monotonic(), m.qos))
        self.port, self.keepalive = port, keepalive

    def connect(self, timeout: float = 5.0) -> int:
        self.client.connect("127.0.0.1", self.port, keepalive=self.keepalive)
        self.client.loop_start()
        rc = self.connack.get(timeout=timeout)
        if rc == 0 and self.presence is not None:
            self.presence.beat()
            self.presence.start()
        return rc

    def subscribe(self, topic: str, qos: int = 1) -> None:
        done = threading.Event()
        self.client.on_subscribe = lambda *a: done.set()
        self.client.subscribe(topic, qos)
        assert done.wait(5), f"no SUBACK for {topic}"

    def publish(self, topic: str, payload: bytes | str | dict, qos: int = 1, retain: bool = False) -> None:
        if isinstance(payload, dict):
            payload = orjson.dumps(payload)
        info = self.client.publish(topic, payload, qos=qos, retain=retain)
        if qos:
            info.wait_for_publish(5)

    def wait_for(self, predicate: Callable[[Received], bool], timeout: float = 10.0) -> Received:
        deadline = time.monotonic() + timeout
        seen: list[str] = []
        while True:
            remaining = deadline - time.monotonic()
            try:
                if remaining <= 0:
                    raise queue.Empty
                msg = self.messages.get(timeout=remaining)
            except queue.Empty:
                # what did come, so that a CI log that shows only this line still says which wait it was
                topics = sorted(set(seen))
                raise TimeoutError(f"no matching message within {timeout} s ({len(seen)} others on "
                                   f"{', '.join(topics[:6])}{' …' if len(topics) > 6 else ''})") from None
            if predicate(msg):
                return msg
            seen.append(msg.topic)

    def drain(self, seconds: float) -> list[Received]:
        return drain(self.messages, seconds)

    def close(self) -> None:
        if self.presence is not None:
            self.presence.stop()
        self.client.disconnect()
        self.client.loop_stop()

    def __enter__(self) -> TestClient:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
