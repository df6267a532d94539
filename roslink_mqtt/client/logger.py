"""``node.get_logger()``: rclpy's logger methods on top of the standard ``logging`` module.

rclpy prints ``[INFO] [time] [node]: text`` to stderr without any setup, and
programs ported from ROS expect to see their log lines, so the first node
installs one stderr handler on the ``roslink_mqtt.node`` logger unless the
application configured logging itself.
"""

from __future__ import annotations

import logging
import sys
import time
from typing import Any

ROOT = "roslink_mqtt.node"


def _ensure_handler() -> None:
    base = logging.getLogger(ROOT)
    if base.handlers or logging.getLogger().handlers:
        return
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("[%(levelname)s] [%(created).6f] [%(node)s]: %(message)s"))
    base.addHandler(handler)
    base.setLevel(logging.INFO)
    base.propagate = False


class Logger:
    """``debug/info/warn/warning/error/fatal``; ``once=True`` and ``throttle_duration_sec=`` as in rclpy."""

    def __init__(self, name: str) -> None:
        _ensure_handler()
        self.name = name
        self._log = logging.getLogger(f"{ROOT}.{name}")
        self._last: dict[tuple[int, str], float] = {}

    def get_child(self, name: str) -> Logger:
        return Logger(f"{self.name}.{name}")

    def set_level(self, level: int) -> None:
        self._log.setLevel(level)

    def _emit(self, level: int, message: Any, once: bool = False, throttle_duration_sec: float | None = None,
              **_ignored: Any) -> bool:
        text = str(message)
        if once or throttle_duration_sec:
            key, now = (level, text), time.monotonic()
            last = self._last.get(key)
            if last is not None and (once or now - last < (throttle_duration_sec or 0)):
                return False
            self._last[key] = now
        self._log.log(level, text, extra={"node": self.name})
        return True

    def debug(self, message: Any, **kwargs: Any) -> bool:
        return self._emit(logging.DEBUG, message, **kwargs)

    def info(self, message: Any, **kwargs: Any) -> bool:
        return self._emit(logging.INFO, message, **kwargs)

    def warning(self, message: Any, **kwargs: Any) -> bool:
        return self._emit(logging.WARNING, message, **kwargs)

    warn = warning

    def error(self, message: Any, **kwargs: Any) -> bool:
        return self._emit(logging.ERROR, message, **kwargs)

    def fatal(self, message: Any, **kwargs: Any) -> bool:
        return self._emit(logging.CRITICAL, message, **kwargs)
