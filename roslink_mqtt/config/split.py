"""``roslink-mqtt fleet split``: one robot's part of the fleet file, for its bridge, with nobody's secrets.

The bridge needs its robot (rules, services, actions, parameters, bridge settings) and the broker's address; it
never checks a password. The fleet file (robots.yaml) also holds every login's PBKDF2 hash and every robot's key:
copied to a robot, a stolen robot would carry material for an offline attack on every login. A robot file keeps
the robot's own key (its ACL root, which the robot has anyway) and nothing about other logins: who may use the
robot reaches its bridge from the broker (``P/<robot>/grants``, protocol/grants.py), so a grant changes without
touching the robot. The loader refuses a password or a ``users`` section in it (``robot_file``), and the broker
refuses to run from it.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import yaml

from .loader import load_fleet, parse_fleet
from .model import ROBOT_FILE, Fleet
from .yamlsource import ConfigError

HEADER = ("# The robot file of {robot}: its part of {source}, written by `roslink-mqtt fleet split`.\n"
          "# No password hash of any login, no other robot's key, no users (its grants come from the broker):\n"
          "# safe to copy to the robot. Do not edit;\n"
          "# change {source} and split again. The robot's own password comes from ROSLINK_PASSWORD or\n"
          "# --password-file.\n")


def robot_file_data(raw: dict[str, Any], fleet: Fleet, robot: str) -> dict[str, Any]:
    """The robot file of ``robot`` as YAML data, from the fleet file's data ``raw`` (anchors expanded) and its
    loaded ``fleet``."""
    if robot not in fleet.robots:
        raise ConfigError(f"no robot '{robot}' in the fleet (robots: {', '.join(fleet.robots)})", file=fleet.file)
    own = {k: v for k, v in raw["robots"][robot].items() if k != "password"}
    data: dict[str, Any] = {ROBOT_FILE: robot}
    if "prefix" in raw:
        data["prefix"] = raw["prefix"]
    if raw.get("broker") is not None:
        data["broker"] = raw["broker"]
    data["robots"] = {robot: own}
    return data


def split_fleet(config: str | Path, out: str | Path, robots: list[str] | None = None) -> list[Path]:
    """Write ``<out>/<robot>.yaml`` for each robot (every robot of the fleet when ``robots`` is None); each is
    loaded back before it is kept, so a file the bridge would refuse is never written. Mode 0600: the robot's key."""
    fleet = load_fleet(config, need_hashes=True)
    raw = yaml.safe_load(Path(config).read_text(encoding="utf-8"))
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    for robot in robots or list(fleet.robots):
        text = HEADER.format(robot=robot, source=config) + yaml.safe_dump(
            robot_file_data(raw, fleet, robot), sort_keys=False, default_flow_style=None, width=118)
        path = out / f"{robot}.yaml"
        parse_fleet(text, str(path))  # the bridge must be able to run from it
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
        written.append(path)
    return written
