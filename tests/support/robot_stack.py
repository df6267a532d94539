"""The smallest live fleet for client-side tests: a broker, simulated turtle1 and its bridge."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from roslink_mqtt.config.split import split_fleet

from .broker_setup import ExportedMosquitto, write_fleet
from .embedded_broker import EmbeddedBrokerProcess
from .mqtt_client import TestClient
from .procs import CONFIG, bridge_args, bridge_env, run

BROKERS = ("embedded", "mosquitto")


@contextmanager
def turtle1_online(work: Path, broker: str = "embedded", *, fleet: Path | None = None) -> Iterator[int]:
    """Yield the broker's port once turtle1's bridge reports itself active (retained heartbeat, status 4).

    ``broker``: ``embedded`` (the demo fleet file as it is, or ``fleet``: a variant of it) or ``mosquitto``
    (Mosquitto running exactly what ``roslink-mqtt acl export`` writes for a copy of the demo fleet: the deployed
    configuration). With the demo fleet as it is, the bridge runs as a deployed robot's should: from turtle1's
    robot file (``roslink-mqtt fleet split``: no password hashes), written to ``work/robot-files/turtle1.yaml``.
    """
    if broker == "mosquitto":
        fleet = write_fleet(work, read_only_service=False)
        server = ExportedMosquitto(work, fleet)
        extra = {"config": fleet}
    elif broker == "embedded" and fleet is not None:
        server, extra = EmbeddedBrokerProcess(work, fleet), {"config": fleet}
    elif broker == "embedded":
        robot_file = split_fleet(CONFIG, work / "robot-files", ["turtle1"])[0]
        server, extra = EmbeddedBrokerProcess(work), {"config": robot_file}
    else:
        raise ValueError(f"broker: {broker!r} is not one of {BROKERS}")
    with server, run(["-m", "roslink_mqtt.sim"], work / "sim.log"), \
            run(bridge_args("turtle1", server.port, **extra), work / "bridge.log", bridge_env("turtle1")):
        with TestClient(server.port, "bob", "bob-demo") as bob:
            assert bob.connect() == 0
            bob.subscribe("roslink/turtle1/heartbeat")
            bob.wait_for(lambda m: m.json()["payload"]["system_status"] == 4, timeout=20)
        yield server.port
