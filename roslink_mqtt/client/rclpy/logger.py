"""``node.get_logger()``: rclpy's logger methods on top of the standard ``logging`` module.

rclpy prints ``[INFO] [time] [node]: text`` to stderr without any setup, and
programs ported from ROS expect to see their log lines, so the first node
installs one stderr handler on the ``roslink_mqtt.node`` logger unless the
application configured logging itself.

A node's logger also sends every line at or above its level through the link to the robot's ``/rosout``
(``sink``), as an rclpy node's logger does; ``set_level`` filters both.
"""

from __future__ import annotations

import logging
import sys
import time
from collections.abc import Callable
from typing import Any

# (logger name, level, text, file, function, line): where a node's log lines go besides the local log
Sink = Callable[[str, int, str, str, str, int], None]

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

    def __init__(self, name: str, sink: Sink | None = None) -> None:
        _ensure_handler()
        self.name, self.sink = name, sink
        self._log = logging.getLogger(f"{ROOT}.{name}")
        if self._log.level == logging.NOTSET:  # rclpy's default severity, whatever the application's root level
            self._log.setLevel(logging.INFO)
        self._last: dict[tuple[int, str], float] = {}

    def get_child(self, name: str) -> Logger:
        return Logger(f"{self.name}.{name}", self.sink)

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
        if self.sink is not None and self._log.isEnabledFor(level):
            caller = sys._getframe(2)  # _emit <- info() <- the program's call
            code = caller.f_code
            try:
                self.sink(self.name, 50 if level >= logging.CRITICAL else level, text, code.co_filename,
                          code.co_name, caller.f_lineno)
            except Exception:  # the link must never break a program's logging
                pass
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
