"""The standard's error objects (``state.errors``): type, level, description and references.

A rejected order or instant action is reported as a ``WARNING`` in the vehicle's ``state`` (the standard has no
reply topic): the master control sees it there, with the ``headerId``, ``topic`` and ids it refers to.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

WARNING = "WARNING"
FATAL = "FATAL"


@dataclass(frozen=True, eq=False)
class VdaError(Exception):
    """An entry of ``state.errors``; raised where a message is refused."""

    error_type: str
    description: str
    references: tuple[tuple[str, str], ...] = ()
    level: str = WARNING

    def __str__(self) -> str:
        return f"{self.error_type}: {self.description}"

    def to_dict(self) -> dict[str, Any]:
        return {"errorType": self.error_type, "errorLevel": self.level, "errorDescription": self.description,
                "errorReferences": [{"referenceKey": k, "referenceValue": v} for k, v in self.references]}


def validation_error(description: str, references: list[tuple[str, str]]) -> VdaError:
    return VdaError("validationError", description, tuple(references))


def order_error(description: str, references: list[tuple[str, str]]) -> VdaError:
    return VdaError("orderError", description, tuple(references))


def order_update_error(description: str, references: list[tuple[str, str]]) -> VdaError:
    return VdaError("orderUpdateError", description, tuple(references))
