"""Fingerprints of a third-party library's internals that the project relies on (tests/unit/test_*_fingerprint.py).

A private method, an attribute made in ``__init__``, the order in which a library calls its own methods: an upgrade
can change any of them without breaking an import, and the code that relies on them then stops working silently.
So the source text of each one is hashed (sha256 of ``inspect.getsource``) and compared with a recorded hash; the
test names what changed, disappeared, or is listed and not recorded.
"""

from __future__ import annotations

import hashlib
import importlib
import inspect
from collections.abc import Iterable, Mapping

CHANGED, GONE, UNRECORDED, UNLISTED = "changed", "gone", "not recorded", "no longer listed"


def source_of(name: str) -> str | None:
    """The source text of ``module:qualified.name``, or None when the library no longer has it (where we said)."""
    module_name, _, qualname = name.partition(":")
    try:
        obj: object = importlib.import_module(module_name)
        for attr in qualname.split("."):
            # a class attribute must be the class's own: inherited or moved elsewhere is "gone"
            obj = vars(obj)[attr] if inspect.isclass(obj) else getattr(obj, attr)
        if isinstance(obj, property):
            obj = obj.fget
        if isinstance(obj, classmethod | staticmethod):
            obj = obj.__func__
        return inspect.getsource(obj)  # type: ignore[arg-type]
    except (ImportError, AttributeError, KeyError, TypeError, OSError):
        return None


def digest(source: str) -> str:
    return hashlib.sha256(source.encode("utf-8")).hexdigest()


def fingerprints(names: Iterable[str]) -> dict[str, str | None]:
    """name -> sha256 of its source today (None: it cannot be found)."""
    out: dict[str, str | None] = {}
    for name in names:
        source = source_of(name)
        out[name] = digest(source) if source is not None else None
    return out


def differences(recorded: Mapping[str, str], current: Mapping[str, str | None]) -> list[tuple[str, str]]:
    """(name, what) for every name whose source changed or disappeared, and for a list and record out of step."""
    out = []
    for name in sorted(set(recorded) | set(current)):
        if name not in current:
            out.append((name, UNLISTED))
        elif name not in recorded:
            out.append((name, UNRECORDED))
        elif current[name] is None:
            out.append((name, GONE))
        elif current[name] != recorded[name]:
            out.append((name, CHANGED))
    return out


def report(found: list[tuple[str, str]], reasons: Mapping[str, str]) -> str:
    """One line per difference, with why the project relies on that name."""
    return "\n".join(f"  {what}: {name}" + (f" -- {reasons[name]}" if name in reasons else "") for name, what in found)
