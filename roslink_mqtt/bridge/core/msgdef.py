"""A ROS 2 message type's full ``.msg`` definition, as MCAP's ``ros2msg`` schema encoding and ``ros2 bag`` write it.

The schema of a CDR channel is the type's own ``.msg`` text, then each message type it uses (recursively, each
once, in the order first used) after a line of 80 ``=`` and ``MSG: pkg/Type``: what Foxglove, ``mcap`` and
``mcap-ros2-support`` decode with. The ``.msg`` files come from the installed interface packages
(``<prefix>/share/<pkg>/msg/<Type>.msg`` for each prefix of ``AMENT_PREFIX_PATH``, then this Python's prefix: the
ROS wheels install there), exactly the source ``rosbag2`` reads.
"""

from __future__ import annotations

import importlib.util
import os
import sys
from functools import cache
from pathlib import Path

from ...ros_names import interface_parts, msg_field_message, msg_reference

SEPARATOR = "=" * 80


class DefinitionNotFound(LookupError):
    """No ``.msg`` file for a type (its interface package is not installed where the bridge looks)."""


def _prefixes(package: str) -> list[Path]:
    """Where ``package``'s share directory may be: each ``AMENT_PREFIX_PATH`` entry, the prefix its Python module is
    installed under (``<prefix>/lib/pythonX.Y/site-packages/<package>``: a sourced ROS, or wheels in a venv that
    another venv or PYTHONPATH reaches), then this Python's prefix."""
    paths = [Path(p) for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    spec = importlib.util.find_spec(package)
    if spec is not None and spec.origin:
        paths.append(Path(spec.origin).parents[4])
    return [*paths, Path(sys.prefix)]


@cache
def _msg_text(package: str, name: str) -> str:
    for prefix in _prefixes(package):
        path = prefix / "share" / package / "msg" / f"{name}.msg"
        if path.is_file():
            return path.read_text(encoding="utf-8")
    raise DefinitionNotFound(f"no definition of {package}/msg/{name} (looked for share/{package}/msg/{name}.msg "
                             f"under {', '.join(str(p) for p in _prefixes(package))})")


def _field_types(text: str, package: str) -> list[tuple[str, str]]:
    """The (package, name) of every message type ``text``'s fields use, in order (constants and primitives left
    out)."""
    out = []
    for raw in text.splitlines():
        tokens = raw.split("#", 1)[0].split()
        if len(tokens) < 2 or "=" in tokens[1] or (len(tokens) > 2 and tokens[2].startswith("=")):
            continue  # blank, or a constant: TYPE NAME=VALUE
        used = msg_field_message(tokens[0], package)
        if used is not None:
            out.append(used)
    return out


def full_definition(ros_type: str) -> str:
    """The ``ros2msg`` schema text of ``ros_type`` (``pkg/msg/Type``); :class:`DefinitionNotFound` if a file is
    missing."""
    parts = interface_parts(ros_type)
    if parts is None or parts[1] != "msg":
        raise DefinitionNotFound(f"{ros_type!r} is not a message type (pkg/msg/Type)")
    package, _kind, name = parts
    root = _msg_text(package, name)
    seen: set[tuple[str, str]] = {(package, name)}
    order: list[tuple[str, str]] = []
    pending = list(_field_types(root, package))
    while pending:
        dep = pending.pop(0)
        if dep in seen:
            continue
        seen.add(dep)
        order.append(dep)
        pending = _field_types(_msg_text(*dep), dep[0]) + pending  # depth first, as rosbag2 orders them
    text = [root.rstrip("\n")]
    for pkg, msg in order:
        text += [SEPARATOR, f"MSG: {msg_reference(pkg, msg)}", _msg_text(pkg, msg).rstrip("\n")]
    return "\n".join(text) + "\n"
