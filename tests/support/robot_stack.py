"""The smallest live fleet for client-side tests: a broker, simulated turtle1 and its bridge."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from .broker_setup import ExportedMosquitto, write_fleet
from .embedded_broker import EmbeddedBrokerProcess
from .mqtt_client import TestClient
from .procs import bridge_args, bridge_env, run

BROKERS = ("embedded", "mosquitto")


@contextmanager
def turtle1_online(work: Path, broker: str = "embedded", *, fleet: Path | None = None) -> Iterator[int]:
    """Yield the broker's port once turtle1's bridge reports itself active (retained heartbeat, status 4).

    ``broker``: ``embedded`` (the demo fleet file as it is, or ``fleet``: a variant of it) or ``mosquitto``
    (Mosquitto running exactly what ``roslink-mqtt acl export`` writes for a copy of the demo fleet: the deployed
    configuration).
    """
    if broker == "mosquitto":
        fleet = write_fleet(work, read_only_service=False)
        server = ExportedMosquitto(work, fleet)
        extra = {"config": fleet}
    elif broker == "embedded" and fleet is not None:
        server, extra = EmbeddedBrokerProcess(work, fleet), {"config": fleet}
    elif broker == "embedded":
        server, extra = EmbeddedBrokerProcess(work), {}
    else:
        raise ValueError(f"broker: {broker!r} is not one of {BROKERS}")
    with server, run(["-m", "roslink_mqtt.sim"], work / "sim.log"), \
            run(bridge_args("turtle1", server.port, **extra), work / "bridge.log", bridge_env("turtle1")):
        with TestClient(server.port, "bob", "bob-demo") as bob:
            assert bob.connect() == 0
            bob.subscribe("roslink/turtle1/heartbeat")
            bob.wait_for(lambda m: m.json()["payload"]["system_status"] == 4, timeout=20)
        yield server.port
