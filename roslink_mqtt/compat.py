"""What the core (protocol, config, SDK, CLI, broker) needs from a Python newer than 3.10, in one place.

The core installs on Python 3.10 to 3.13 (pyproject's requires-python); the bridge runs where ROS 2 Jazzy's rclpy
does (the ROS wheels: 3.11; a sourced ROS installation: its own Python).
"""

from __future__ import annotations

import binascii
import re
import sys
from enum import Enum

if sys.version_info >= (3, 11):
    from enum import StrEnum
else:  # pragma: no cover - Python 3.10

    class StrEnum(str, Enum):
        """``enum.StrEnum`` of Python 3.11: members are strings whose ``str()`` and format are their value."""

        def __str__(self) -> str:
            return str(self.value)

        def __format__(self, spec: str) -> str:
            return format(str(self.value), spec)


_BASE64 = re.compile(r"(?:[A-Za-z0-9+/]{4})*(?:[A-Za-z0-9+/]{2}==|[A-Za-z0-9+/]{3}=)?")


def strict_b64decode(text: str) -> bytes:
    """Standard base64 with nothing but the alphabet and exact padding (``binascii.Error`` otherwise): Python 3.11's
    ``a2b_base64(strict_mode=True)``, the same rules checked by a pattern on 3.10."""
    if sys.version_info >= (3, 11):
        return binascii.a2b_base64(text, strict_mode=True)
    if not _BASE64.fullmatch(text):  # pragma: no cover - Python 3.10
        raise binascii.Error("not strict base64: only A-Z a-z 0-9 + / and exact '=' padding")
    return binascii.a2b_base64(text)  # pragma: no cover - Python 3.10


__all__ = ["StrEnum", "strict_b64decode"]
