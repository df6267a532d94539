"""Errors that refuse one user input with a reason for its sender, ROS-free.

The command endpoint turns each of these into an error report on ``to/<user>/error`` and carries out
nothing; any other exception is a bug and is not dressed up as a refusal.
"""

from __future__ import annotations

from ..protocol import ProtocolError
from .presets.command import CommandRefused
from .safety import UnsafeCommand


class ConversionError(ValueError):
    """Untrusted JSON does not fit the ROS type; the message names the field path (``linear.x: …``)."""

    def __init__(self, reason: str, path: str = "") -> None:
        super().__init__(f"{path}: {reason}" if path else reason)
        self.reason, self.path = reason, path

    def inside(self, segment: str) -> ConversionError:
        """The same error seen from the enclosing field (``segment`` is a field name or ``[i]``)."""
        if not self.path:
            return ConversionError(self.reason, segment)
        return ConversionError(self.reason, segment + (self.path if self.path.startswith("[") else "." + self.path))


# a body that is not ROSLink, does not fit the ROS type, cannot be carried out here, or is not a safe velocity
INPUT_REFUSALS: tuple[type[Exception], ...] = (ProtocolError, ConversionError, CommandRefused, UnsafeCommand)
