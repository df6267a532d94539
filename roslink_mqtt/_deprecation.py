"""Names that moved, kept working for one release with a ``DeprecationWarning`` that says where they went.

Why a warning and not a silent alias: the next release removes the old name, and a program should learn that from
its test run, not from an ImportError after an upgrade.
"""

from __future__ import annotations

import importlib
import warnings
from collections.abc import Mapping
from typing import Any


def moved_module(old: str, new: str) -> None:
    """Called by a module kept only under its old name (``old``) when it is imported."""
    warnings.warn(f"{old} moved to {new}; the old name goes in the next release", DeprecationWarning, stacklevel=3)


def moved_name(package: str, name: str, moved: Mapping[str, str]) -> Any:
    """A package's ``__getattr__`` for names it no longer exports: ``moved`` maps each to the module it lives in
    now; the value comes from there, with a warning naming the new import. AttributeError for any other name."""
    where = moved.get(name)
    if where is None:
        raise AttributeError(f"module {package!r} has no attribute {name!r}")
    warnings.warn(f"{package}.{name} moved: `from {where} import {name}`; the old name goes in the next release",
                  DeprecationWarning, stacklevel=3)
    return getattr(importlib.import_module(where), name)
