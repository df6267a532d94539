"""systemd readiness and watchdog notifications (``Type=notify``, ``WatchdogSec=``), without a dependency.

The watchdog ping is sent from the bridge's supervision timer, so systemd
restarts a bridge whose executor stopped running the failsafe checks, not
only one whose process died.
"""

from __future__ import annotations

import os
import socket
import time


class SystemdNotifier:
    def __init__(self) -> None:
        address = os.environ.get("NOTIFY_SOCKET", "")
        self._address = "\0" + address[1:] if address.startswith("@") else address
        usec = os.environ.get("WATCHDOG_USEC", "")
        self.watchdog_period = int(usec) / 2e6 if usec.isdigit() and int(usec) > 0 else None  # ping at half
        self._last_ping = 0.0
        self._sock: socket.socket | None = None
        if self._address:
            self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)

    @property
    def enabled(self) -> bool:
        return self._sock is not None

    def notify(self, state: str) -> None:
        if self._sock is None:
            return
        try:
            self._sock.sendto(state.encode(), self._address)
        except OSError:  # systemd went away or the socket is gone: nothing to tell
            pass

    def ready(self, status: str = "") -> None:
        self.notify("READY=1" + (f"\nSTATUS={status}" if status else ""))

    def status(self, status: str) -> None:
        self.notify(f"STATUS={status}")

    def ping(self) -> None:
        """Watchdog keep-alive, rate-limited to half the configured interval."""
        if self.watchdog_period is None:
            return
        now = time.monotonic()
        if now - self._last_ping >= self.watchdog_period:
            self._last_ping = now
            self.notify("WATCHDOG=1")

    def stopping(self) -> None:
        self.notify("STOPPING=1")
