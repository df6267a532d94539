"""The smallest live fleet for client-side tests: a broker, simulated turtle1, its bridge (support/stack.py)."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from roslink_mqtt.config.split import split_fleet

from .broker_setup import write_fleet
from .procs import CONFIG
from .stack import live_robot

BROKERS = ("embedded", "mosquitto")


@contextmanager
def turtle1_online(work: Path, broker: str = "embedded", *, fleet: Path | None = None) -> Iterator[int]:
    """Yield the broker's port once turtle1's bridge reports itself active (retained heartbeat, status 4).

    ``broker``: ``embedded`` (the demo fleet file as it is, or ``fleet``: a variant of it) or ``mosquitto``
    (Mosquitto running exactly what ``roslink-mqtt acl export`` writes for a copy of the demo fleet: the deployed
    configuration). With the demo fleet as it is, the bridge runs as a deployed robot's should: from turtle1's
    robot file (``roslink-mqtt fleet split``: no password hashes), written to ``work/robot-files/turtle1.yaml``.
    """
    bridge_config = None
    if broker == "mosquitto":
        fleet = write_fleet(work, read_only_service=False)
    elif broker == "embedded" and fleet is None:
        bridge_config = split_fleet(CONFIG, work / "robot-files", ["turtle1"])[0]
    with live_robot(work, broker, fleet=fleet, bridge_config=bridge_config) as stack:
        yield stack.port
