"""Unit tests are pure logic: no ROS, no running broker, no processes.

When a run holds only this folder (``pytest tests/unit``, as ``make test`` runs it first), importing rclpy fails at
once, so a test that needs ROS cannot hide here: it belongs in tests/integration/. (amqtt may be imported: the
broker's plugins are tested as pure logic on its classes.)
"""

from __future__ import annotations

import importlib.abc
import sys
from pathlib import Path

import pytest

BLOCKED = ("rclpy", "rosidl_runtime_py", "rosidl_parser")
HERE = Path(__file__).resolve().parent


class _NoRosNoBroker(importlib.abc.MetaPathFinder):
    def find_spec(self, name: str, path: object = None, target: object = None) -> None:
        if name.split(".", 1)[0] in BLOCKED:
            raise ImportError(f"tests/unit must not import {name}: tests that need ROS belong in tests/integration")
        return None


def _only_unit(config: pytest.Config) -> bool:
    paths = [Path(str(a).split("::", 1)[0]).resolve() for a in config.args]
    return bool(paths) and all(p == HERE or HERE in p.parents for p in paths)


def pytest_configure(config: pytest.Config) -> None:
    if _only_unit(config) and not any(isinstance(f, _NoRosNoBroker) for f in sys.meta_path):
        sys.meta_path.insert(0, _NoRosNoBroker())
