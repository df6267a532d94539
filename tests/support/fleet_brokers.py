"""Brokers loaded with the demo fleet's logins, for bridge and client tests."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from roslink_mqtt.config import load_fleet

from .mosquitto import run_mosquitto
from .procs import CONFIG


def fleet_password_file(workdir: Path, config: Path = CONFIG) -> Path:
    """A Mosquitto password file with the fleet's robots and users (hashes straight from robots.yaml)."""
    fleet = load_fleet(config)
    pwfile = workdir / "passwd"
    pwfile.write_text("".join(f"{name}:{fleet.password_hash(name)}\n" for name in [*fleet.robots, *fleet.users]))
    return pwfile


@contextmanager
def mosquitto_with_logins(workdir: Path, config: Path = CONFIG) -> Iterator[int]:
    """Mosquitto that authenticates the fleet's robots and users."""
    pwfile = fleet_password_file(workdir, config)
    with run_mosquitto(workdir, f"allow_anonymous false\npassword_file {pwfile}\n") as port:
        yield port
