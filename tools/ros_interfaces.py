"""Generate roslink_mqtt/config/interface_table.py from the installed ROS 2 interface wheels.

    .venv/bin/python tools/ros_interfaces.py          # rewrite the table
    .venv/bin/python tools/ros_interfaces.py --check  # exit 1 when the shipped table differs from the wheels

``roslink-mqtt fleet`` (and the broker, which loads the same file) must check rule types without ROS:
a client machine or a broker host has no rclpy. So the names and fields of the common_interfaces types
(every package the ``ros-common-interfaces`` wheel depends on) are read here, once, from the wheels
themselves — the ament index lists each package's interfaces, and the generated Python classes give
their fields — and shipped as a plain Python table. tests/integration/test_fleet_types.py runs the check.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.metadata as metadata
import os
import pprint
import re
import sys
from pathlib import Path

META_DIST = "ros-common-interfaces"  # the wheel of the common_interfaces meta-package
ROOT = Path(__file__).resolve().parents[1]
TABLE = ROOT / "roslink_mqtt" / "config" / "interface_table.py"
HEADER = '''"""The ROS 2 common_interfaces message and service types, with their fields. GENERATED: do not edit.

Written by tools/ros_interfaces.py from the installed ROS wheels ({source});
tests/integration/test_fleet_types.py checks it against them. Read by roslink_mqtt.config.interfaces, which
must not import ROS.
"""

# ruff: noqa: E501

'''


def packages() -> list[str]:
    """The interface packages of common_interfaces, from the meta-package wheel's dependencies."""
    names = []
    for requirement in metadata.requires(META_DIST) or []:
        dist = re.match(r"[A-Za-z0-9_.-]+", requirement).group(0)
        names.append(dist.removeprefix("ros-").replace("-", "_"))
    return sorted(names)


def interfaces(package: str) -> list[str]:
    """``msg/Twist``, ``srv/Trigger`` … of one package, from its ament index entry (what ROS itself reads)."""
    os.environ.setdefault("AMENT_PREFIX_PATH", sys.prefix)
    from ament_index_python import get_resource

    content, _ = get_resource("rosidl_interfaces", package)
    found = set()
    for line in content.splitlines():
        kind, _, file = line.partition("/")
        if kind in ("msg", "srv") and file.endswith(".idl"):
            found.add(f"{kind}/{file.removesuffix('.idl')}")
    return sorted(found)


def build_table() -> dict:
    """{"source", "packages", "msg": {type: {field: type}}, "srv": {type: {"request": …, "response": …}}}."""
    table: dict = {"source": "", "packages": packages(), "msg": {}, "srv": {}}
    for package in table["packages"]:
        for interface in interfaces(package):
            kind, name = interface.split("/")
            cls = getattr(importlib.import_module(f"{package}.{kind}"), name)
            full = f"{package}/{kind}/{name}"
            if kind == "msg":
                table["msg"][full] = dict(cls.get_fields_and_field_types())
            else:
                table["srv"][full] = {"request": dict(cls.Request.get_fields_and_field_types()),
                                      "response": dict(cls.Response.get_fields_and_field_types())}
    table["source"] = f"{META_DIST} {metadata.version(META_DIST)}, ROS 2 {_distro()}"
    return table


def _distro() -> str:
    for dist in metadata.distributions():
        name = dist.metadata["Name"] or ""
        if name.startswith("ros-") and name.endswith("-common-interfaces") and name != META_DIST:
            return name.removeprefix("ros-").removesuffix("-common-interfaces")
    return os.environ.get("ROS_DISTRO", "unknown")


def render(table: dict) -> str:
    return HEADER.format(source=table["source"]) + "TABLE = " + pprint.pformat(table, width=120, sort_dicts=True) \
        + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--check", action="store_true", help="compare only; exit 1 when the table is out of date")
    args = p.parse_args(argv)
    text = render(build_table())
    if args.check:
        current = TABLE.read_text() if TABLE.exists() else ""
        if current != text:
            print(f"{TABLE.relative_to(ROOT)} differs from the installed wheels: run tools/ros_interfaces.py")
            return 1
        print(f"{TABLE.relative_to(ROOT)} matches the installed wheels")
        return 0
    TABLE.write_text(text)
    print(f"wrote {TABLE.relative_to(ROOT)}: {len(text)} bytes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
