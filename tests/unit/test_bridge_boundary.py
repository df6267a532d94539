"""The bridge's ROS boundary, kept: ``bridge/core`` imports no ROS (rclpy, rosidl, message packages) and no amqtt, not
even through another module of the package or inside a function, and nothing of the ROS adapter (``bridge/ros``) or
the entry point (``bridge/main.py``). What the core needs from ROS it is handed as typed ports.

Two proofs: the import graph read from the source (names the file and line that crosses, however deep), and a
process that imports every core module where rclpy and amqtt cannot be imported at all.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from collections.abc import Iterator
from functools import cache
from pathlib import Path

from tests.support.no_ros import no_ros_env

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = ROOT / "roslink_mqtt"
CORE = "roslink_mqtt.bridge.core"
ADAPTER = ("roslink_mqtt.bridge.ros", "roslink_mqtt.bridge.main")
ROS_PREFIXES = ("rclpy", "rosidl", "rcl_", "rmw", "ros2", "tf2", "launch", "builtin_interfaces", "rosbag2")
ROS_SUFFIXES = ("_msgs", "_srvs", "_interfaces", "_actions")


def is_ros(module: str) -> bool:
    top = module.split(".")[0]
    return top.startswith(ROS_PREFIXES) or top.endswith(ROS_SUFFIXES)


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


@cache
def modules() -> dict[str, Path]:
    return {module_name(path): path for path in PACKAGE.rglob("*.py")}


def imports_of(name: str) -> Iterator[tuple[str, int]]:
    """Every module ``name`` imports (at any depth of its source: function bodies too), with the line; a package's
    import is also its parents'."""
    path = modules()[name]
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        found: list[str] = []
        if isinstance(node, ast.Import):
            found = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            found = [target] + [f"{target}.{alias.name}" for alias in node.names
                                if f"{target}.{alias.name}" in modules()]
        for target in found:
            parts = target.split(".")
            for i in range(1, len(parts) + 1):
                yield ".".join(parts[:i]), node.lineno


def crossing(name: str, seen: set[str] | None = None) -> list[str] | None:
    """The chain of imports by which ``name`` reaches ROS, amqtt or the adapter (None: it does not)."""
    seen = set() if seen is None else seen
    seen.add(name)
    for target, line in imports_of(name):
        where = f"{modules()[name].relative_to(ROOT)}:{line} imports {target}"
        if is_ros(target) or target.split(".")[0] == "amqtt" or target.startswith(ADAPTER):
            return [where]
        if target in modules() and target not in seen:
            rest = crossing(target, seen)
            if rest is not None:
                return [where, *rest]
    return None


def core_modules() -> list[str]:
    return sorted(name for name in modules() if name == CORE or name.startswith(CORE + "."))


def test_the_core_reaches_no_ros_no_amqtt_and_not_the_adapter_in_its_source() -> None:
    assert len(core_modules()) > 20  # the folder is where this test looks
    crossings = {name: chain for name in core_modules() if (chain := crossing(name)) is not None}
    assert not crossings, "\n".join(f"{name}: " + " → ".join(chain) for name, chain in crossings.items())


def test_the_source_check_finds_a_crossing() -> None:
    """The check itself can fail: the adapter's node reaches rclpy, a core module named as the adapter would."""
    chain = crossing("roslink_mqtt.bridge.ros.node")
    assert chain is not None and any("rclpy" in step for step in chain), chain
    assert is_ros("sensor_msgs.msg") and is_ros("rclpy.node") and not is_ros("roslink_mqtt.ros_names")


def test_every_core_module_imports_where_ros_and_amqtt_cannot(tmp_path: Path) -> None:
    probe = ("import importlib, sys\n"
             f"for name in {core_modules()!r}:\n"
             "    importlib.import_module(name)\n"
             "bad = sorted(m for m in sys.modules if m.split('.')[0] in ('rclpy', 'rosidl_parser', 'amqtt'))\n"
             "print(bad); sys.exit(1 if bad else 0)\n")
    done = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, env=no_ros_env(tmp_path), capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stdout + done.stderr
