"""A minimal MQTT 3.1.1 server that refuses chosen subscription filters with SUBACK 0x80.

Mosquitto 2.0 grants every filter (it checks read access per delivery), so
the SDK's handling of a refused wildcard — what the embedded broker does with
filters that cannot match anything readable — needs a broker that says no.
This one accepts any login, grants other filters and acknowledges QoS 1
publishes; it delivers nothing.
"""

from __future__ import annotations

import socket
import threading
from collections.abc import Iterator
from contextlib import contextmanager

CONNECT, PUBLISH, SUBSCRIBE, PINGREQ, DISCONNECT = 1, 3, 8, 12, 14


def _read_exact(conn: socket.socket, n: int) -> bytes:
    data = b""
    while len(data) < n:
        chunk = conn.recv(n - len(data))
        if not chunk:
            raise ConnectionError
        data += chunk
    return data


def _read_packet(conn: socket.socket) -> tuple[int, int, bytes]:
    first = _read_exact(conn, 1)[0]
    length, shift = 0, 0
    while True:
        byte = _read_exact(conn, 1)[0]
        length |= (byte & 0x7F) << shift
        shift += 7
        if not byte & 0x80:
            break
    return first >> 4, first & 0x0F, _read_exact(conn, length)


def _serve(conn: socket.socket, refuse: set[str], subscriptions: list[tuple[str, bool]]) -> None:
    with conn:
        try:
            while True:
                kind, flags, body = _read_packet(conn)
                if kind == CONNECT:
                    conn.sendall(bytes([0x20, 2, 0, 0]))
                elif kind == SUBSCRIBE:
                    packet_id, rest, codes = body[:2], body[2:], []
                    while rest:
                        size = int.from_bytes(rest[:2], "big")
                        topic, qos = rest[2:2 + size].decode(), rest[2 + size]
                        rest = rest[3 + size:]
                        granted = topic not in refuse
                        subscriptions.append((topic, granted))
                        codes.append(qos if granted else 0x80)
                    conn.sendall(bytes([0x90, 2 + len(codes)]) + packet_id + bytes(codes))
                elif kind == PUBLISH and (flags >> 1) & 3:
                    size = int.from_bytes(body[:2], "big")
                    conn.sendall(bytes([0x40, 2]) + body[2 + size:4 + size])
                elif kind == PINGREQ:
                    conn.sendall(bytes([0xD0, 0]))
                elif kind == DISCONNECT:
                    return
        except (ConnectionError, OSError):
            return


@contextmanager
def refusing_broker(refuse: set[str]) -> Iterator[tuple[int, list[tuple[str, bool]]]]:
    """Yield (port, subscriptions seen as (filter, granted)); refuses the filters in ``refuse``."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen()
    subscriptions: list[tuple[str, bool]] = []

    def accept() -> None:
        while True:
            try:
                conn, _ = server.accept()
            except OSError:
                return
            threading.Thread(target=_serve, args=(conn, refuse, subscriptions), daemon=True).start()

    threading.Thread(target=accept, daemon=True).start()
    try:
        yield server.getsockname()[1], subscriptions
    finally:
        server.close()
