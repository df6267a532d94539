"""Importing the SDK's context does not import its node module (issue 14, SDK surface).

rclpy's shape: ``node.py`` imports the context, never the other way round at
run time. A fresh interpreter is the only honest check: in this process the
node module is loaded already by other tests.
"""

from __future__ import annotations

import subprocess
import sys

_CHECK = """
import sys
import roslink_mqtt.client.rclpy
loaded = sorted(m for m in sys.modules if m == "roslink_mqtt.client.rclpy.node")
assert not loaded, loaded
from roslink_mqtt.client.rclpy import create_node
from roslink_mqtt.client.rclpy.node import Node
assert "roslink_mqtt.client.rclpy.node" in sys.modules
"""


def test_context_does_not_import_node() -> None:
    result = subprocess.run([sys.executable, "-c", _CHECK], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr


def test_package_exports_still_resolve() -> None:
    import types

    import roslink_mqtt.client as sdk

    assert len(set(sdk.__all__)) == len(sdk.__all__), "a name exported twice"
    for name in sdk.__all__:
        value = getattr(sdk, name)  # AttributeError: __all__ names something the package does not define
        assert not isinstance(value, types.ModuleType), f"{name}: a module, not part of the API"
        assert getattr(value, "__module__", "roslink_mqtt").startswith("roslink_mqtt"), (name, value)
