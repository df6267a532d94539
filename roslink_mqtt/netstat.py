"""What the kernel knows about one of our TCP connections: bytes not yet acknowledged, bytes delivered, round trip.

Linux only (``SIOCOUTQ``, ``TCP_INFO``), like the rest of the project's deployment targets; on anything else the
functions answer 0/None and the callers fall back to not knowing. Used by the bridge's uplink (how much of its own
data waits in the network) and by the embedded broker (whether a client's connection is backed up).
"""

from __future__ import annotations

import fcntl
import socket
import struct
import termios
from typing import Any

_TCP_INFO_BYTES_ACKED = 120  # offsets in Linux's struct tcp_info (a stable ABI: fields are only ever appended)
_TCP_INFO_MIN_RTT = 148


def raw_socket(sock: Any) -> socket.socket | None:
    """The TCP socket under a paho socket (plain, TLS, or inside its websocket wrapper) or an asyncio
    transport's socket; None when there is none."""
    sock = getattr(sock, "_socket", sock)
    return sock if sock is not None and hasattr(sock, "fileno") else None


def unacked(sock: Any) -> int:
    """Bytes written to ``sock`` that the peer has not acknowledged yet (SIOCOUTQ); 0 when unknown."""
    if sock is None:
        return 0
    try:
        queued: int = struct.unpack("i", fcntl.ioctl(sock.fileno(), termios.TIOCOUTQ, b"\0\0\0\0"))[0]
        return queued
    except (OSError, ValueError, AttributeError):
        return 0


def delivered(sock: Any) -> tuple[int, float | None] | None:
    """(bytes the peer acknowledged since the connection began, the least round trip seen in s), or None."""
    if sock is None:
        return None
    try:
        info = sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_INFO, 160)
    except (OSError, ValueError, AttributeError):
        return None
    if len(info) < _TCP_INFO_MIN_RTT + 4:
        return None
    acked = struct.unpack_from("Q", info, _TCP_INFO_BYTES_ACKED)[0]
    min_rtt = struct.unpack_from("I", info, _TCP_INFO_MIN_RTT)[0]
    return acked, (min_rtt / 1e6 if min_rtt else None)

