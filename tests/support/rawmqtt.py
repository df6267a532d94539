"""Hand-built MQTT 3.1.1 packets for attack tests: what a hostile client sends, byte by byte.

paho refuses to send most of these (200,000 filters in one SUBSCRIBE, a PUBLISH that
announces 1 MB and stops, a wildcard topic, a will with QoS 3), so the attacks here use a
plain socket. Only the framing of MQTT 3.1.1 §2-3; nothing here validates.
"""

from __future__ import annotations

import socket
import struct
import time


def remaining_length(n: int) -> bytes:
    out = bytearray()
    while True:
        byte, n = n % 128, n // 128
        out.append(byte | (0x80 if n else 0))
        if not n:
            return bytes(out)


def utf8(text: str | bytes) -> bytes:
    data = text.encode() if isinstance(text, str) else text
    return struct.pack("!H", len(data)) + data


def connect_packet(client_id: str, username: str | None = None, password: str | None = None, *,
                   keepalive: int = 30, clean: bool = True,
                   will: tuple[str | bytes, bytes, int, bool] | None = None) -> bytes:
    flags = 0x02 if clean else 0
    payload = utf8(client_id)
    if will is not None:
        topic, message, qos, retain = will
        flags |= 0x04 | (qos << 3) | (0x20 if retain else 0)
        payload += utf8(topic) + utf8(message)
    if username is not None:
        flags |= 0x80
        payload += utf8(username)
    if password is not None:
        flags |= 0x40
        payload += utf8(password)
    body = utf8("MQTT") + bytes([4, flags]) + struct.pack("!H", keepalive) + payload
    return bytes([0x10]) + remaining_length(len(body)) + body


def subscribe_packet(filters: list[str], packet_id: int = 1, qos: int = 0) -> bytes:
    body = struct.pack("!H", packet_id) + b"".join(utf8(f) + bytes([qos]) for f in filters)
    return bytes([0x82]) + remaining_length(len(body)) + body


def publish_packet(topic: str | bytes, payload: bytes, *, qos: int = 0, retain: bool = False,
                   packet_id: int = 1) -> bytes:
    body = utf8(topic) + (struct.pack("!H", packet_id) if qos else b"") + payload
    return bytes([0x30 | (qos << 1) | int(retain)]) + remaining_length(len(body)) + body


def publish_header(topic: str, announced: int) -> bytes:
    """The start of a QoS 0 PUBLISH whose body claims ``announced`` bytes (the attacker sends fewer)."""
    return bytes([0x30]) + remaining_length(announced) + utf8(topic)


class RawClient:
    """A TCP connection that speaks raw bytes; ``login()`` sends CONNECT and returns the CONNACK code."""

    def __init__(self, port: int, timeout: float = 5.0, source: str = "") -> None:
        """``source`` picks the client's address within 127.0.0.0/8 (a second "machine" on loopback)."""
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=timeout,
                                             source_address=(source, 0) if source else None)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    def login(self, client_id: str, username: str | None, password: str | None, **kw) -> int:
        self.sock.sendall(connect_packet(client_id, username, password, **kw))
        connack = self.recv_exactly(4)
        return connack[3]

    def send(self, data: bytes) -> None:
        self.sock.sendall(data)

    def recv_exactly(self, n: int) -> bytes:
        data = b""
        while len(data) < n:
            chunk = self.sock.recv(n - len(data))
            if not chunk:
                raise ConnectionError(f"closed after {len(data)} of {n} bytes")
            data += chunk
        return data

    def closed_within(self, seconds: float) -> bool:
        """True when the broker closes this connection within ``seconds`` (data before that is discarded)."""
        deadline = time.monotonic() + seconds
        while (left := deadline - time.monotonic()) > 0:
            self.sock.settimeout(left)
            try:
                if not self.sock.recv(65536):
                    return True
            except TimeoutError:
                return False
            except OSError:
                return True
        return False

    def close(self) -> None:
        try:
            self.sock.close()
        except OSError:
            pass
