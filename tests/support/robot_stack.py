"""The smallest live fleet for client-side tests: embedded broker, simulated turtle1 and its bridge."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from .embedded_broker import EmbeddedBrokerProcess
from .mqtt_client import TestClient
from .procs import bridge_args, bridge_env, run


@contextmanager
def turtle1_online(work: Path) -> Iterator[int]:
    """Yield the broker's port once turtle1's bridge reports itself active (retained heartbeat, status 4)."""
    with EmbeddedBrokerProcess(work) as broker, \
            run(["-m", "roslink_mqtt.sim"], work / "sim.log"), \
            run(bridge_args("turtle1", broker.port), work / "bridge.log", bridge_env("turtle1")):
        with TestClient(broker.port, "bob", "bob-demo") as bob:
            assert bob.connect() == 0
            bob.subscribe("roslink/turtle1/heartbeat")
            bob.wait_for(lambda m: m.json()["payload"]["system_status"] == 4, timeout=20)
        yield broker.port
