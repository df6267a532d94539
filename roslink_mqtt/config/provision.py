"""A new robot's provisioning bundle (``roslink-mqtt fleet robot add``): everything its computer needs, nothing more.

* ``<robot>.yaml`` -- its robot file (config/split.py): rules and settings, no login's hash, no other robot's key, no
  users (grants come from the broker);
* ``<robot>.password`` -- its generated password (mode 600; robots.yaml holds only the hash), to install as
  ``/etc/roslink-mqtt/<robot>.password`` readable by the bridge's group: the bridge reads it at start and again on
  SIGHUP, which is how a rotated password reaches it without a restart (docs/operations.md);
* ``<robot>.env`` -- the bridge unit's environment file (robot name, broker URL, the ROS graph's settings), to
  install as ``/etc/roslink-mqtt/<robot>.env``;
* ``roslink-mqtt-bridge.service.d/<robot>.conf`` -- a systemd drop-in that points the unit at the files above
  (``EnvironmentFile=`` and ``ExecStart=`` are reset first, as systemd needs for a replacement).

The robot's password is random (144 bits), so its hash needs no slow PBKDF2: ``ROBOT_ITERATIONS`` (docs/config.md,
"Password hashes").
"""

from __future__ import annotations

import os
import secrets
from dataclasses import dataclass
from pathlib import Path

from .split import split_fleet

ROBOT_ITERATIONS = 1000  # a random 144-bit password: no guessing to slow down
ETC = "/etc/roslink-mqtt"
DEFAULT_PREFIX = "/opt/roslink-mqtt"  # deploy/install.sh's


@dataclass(frozen=True, slots=True)
class Bundle:
    robot_file: Path
    password: Path
    env: Path
    drop_in: Path


def new_password() -> str:
    return secrets.token_urlsafe(18)


def new_key() -> str:
    return secrets.token_urlsafe(18)


def _private(path: Path, text: str) -> None:
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(text)


def env_text(robot: str, url: str | None) -> str:
    return (f"# {ETC}/{robot}.env: the bridge of {robot} (roslink-mqtt fleet robot add). Its password is in\n"
            f"# {ETC}/{robot}.password (the drop-in passes --password-file).\n"
            f"ROSLINK_ROBOT={robot}\n"
            + (f"ROSLINK_BRIDGE_ARGS=--url {url}\n" if url else "ROSLINK_BRIDGE_ARGS=\n")
            + "ROS_DOMAIN_ID=0\nRMW_IMPLEMENTATION=rmw_fastrtps_cpp\nROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST\n")


def drop_in_text(robot: str, prefix: str = DEFAULT_PREFIX) -> str:
    return (f"# /etc/systemd/system/roslink-mqtt-bridge.service.d/{robot}.conf (roslink-mqtt fleet robot add):\n"
            f"# the bridge of {robot}, from its robot file and environment file.\n"
            "[Service]\n"
            "EnvironmentFile=\n"
            f"EnvironmentFile={ETC}/{robot}.env\n"
            "ExecStart=\n"
            f"ExecStart={prefix}/.venv/bin/roslink-mqtt-bridge --config {ETC}/{robot}.yaml --robot ${{ROSLINK_ROBOT}} "
            f"--password-file {ETC}/{robot}.password $ROSLINK_BRIDGE_ARGS\n")


def write_bundle(config: str | Path, robot: str, password: str, out: str | Path, *, url: str | None,
                 prefix: str = DEFAULT_PREFIX) -> Bundle:
    """Write ``robot``'s bundle into ``out`` (created, mode 700) from the fleet file ``config``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True, mode=0o700)
    robot_file = split_fleet(config, out, [robot])[0]
    bundle = Bundle(robot_file, out / f"{robot}.password", out / f"{robot}.env",
                    out / "roslink-mqtt-bridge.service.d" / f"{robot}.conf")
    _private(bundle.password, password + "\n")
    _private(bundle.env, env_text(robot, url))
    bundle.drop_in.parent.mkdir(exist_ok=True)
    bundle.drop_in.write_text(drop_in_text(robot, prefix))
    return bundle
