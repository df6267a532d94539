"""The suite's one way to start a live robot: a broker × the robot's processes (the sim, its bridge), ready.

Every integration module used to build this by hand — choose a broker, start the sim and the bridge, connect a
viewer, wait for the retained heartbeat to say ACTIVE — each a little differently. Here it is once:

* ``broker``: ``embedded`` (the project's broker with the fleet's ACL), ``mosquitto`` (Mosquitto running exactly
  what ``roslink-mqtt acl export`` writes: the deployed configuration) or ``logins`` (Mosquitto that only checks
  passwords, no ACL: the bridge's own role checks are what the test sees).
* ``fleet``: the fleet file the broker and the bridge read; by default the demo fleet for ``embedded`` and
  ``logins``, and a written copy of it (``write_fleet``) for ``mosquitto``, which needs its exported files.
* ``bridge_config``: the file the bridge reads, when not the broker's fleet (a robot file from ``fleet split``).
* ``sim``: the simulated robot (turtlesim-like), or ``False`` for a bridge with no ROS peer but the test's own.
* ``bridge_env_extra``: extra environment for the bridge (``ROSLINK_EXECUTOR``…).
* ``ws``: the embedded broker's WebSocket listener open too (``ws_port``: browsers, MQTT.js).

The stack is ready when the robot's heartbeat says ACTIVE (status 4). Clients made with :meth:`LiveStack.client`
are closed with the stack.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, field
from pathlib import Path

from roslink_mqtt.localproc import LocalProcess

from .broker_setup import ExportedMosquitto, write_fleet
from .embedded_broker import EmbeddedBrokerProcess
from .fleet_brokers import mosquitto_with_logins
from .mqtt_client import TestClient
from .procs import CONFIG, bridge_args, bridge_env, run

BROKERS = ("embedded", "mosquitto", "logins")
ACTIVE = 4  # the heartbeat's system_status once the bridge runs


@dataclass
class LiveStack:
    """A running broker and robot; ``port``/``url`` is where clients connect."""

    work: Path
    broker: str
    port: int
    fleet: Path
    robot: str
    bridge: LocalProcess
    sim: LocalProcess | None
    exits: ExitStack = field(repr=False)
    server: EmbeddedBrokerProcess | ExportedMosquitto | None = None  # the broker's process (not for ``logins``)
    ws_port: int = 0

    @property
    def url(self) -> str:
        return f"mqtt://127.0.0.1:{self.port}"

    def client(self, user: str, password: str | None = None, *, operator: bool = False,
               subscribe: tuple[str, ...] = ()) -> TestClient:
        """A connected test client (``password``: the demo's ``<user>-demo``) subscribed to ``subscribe``."""
        client = self.exits.enter_context(TestClient(self.port, user, password or f"{user}-demo", operator=operator))
        assert client.connect() == 0, f"{user} could not log in to the {self.broker} broker"
        for topic in subscribe:
            client.subscribe(topic)
        return client

    def wait_active(self, viewer: str = "bob", timeout: float = 30.0) -> None:
        """Until the robot's retained heartbeat says ACTIVE, as ``viewer`` (granted in the fleet) sees it."""
        with TestClient(self.port, viewer, f"{viewer}-demo") as client:
            assert client.connect() == 0, f"{viewer} could not log in to the {self.broker} broker"
            client.subscribe(f"roslink/{self.robot}/heartbeat")
            client.wait_for(lambda m: m.json()["payload"]["system_status"] == ACTIVE, timeout=timeout)


@contextmanager
def live_robot(work: Path, broker: str = "embedded", *, fleet: Path | None = None, robot: str = "turtle1",
               bridge_config: Path | None = None, sim: bool = True, bridge_env_extra: Mapping[str, str] | None = None,
               bridge_extra: tuple[str, ...] = (), viewer: str = "bob", ws: bool = False,
               ready_timeout: float = 30.0) -> Iterator[LiveStack]:
    """Start ``broker``, the sim and ``robot``'s bridge in ``work``; yield once the robot is ACTIVE."""
    if broker not in BROKERS:
        raise ValueError(f"broker: {broker!r} is not one of {BROKERS}")
    if ws and broker != "embedded":
        raise ValueError("ws: only the embedded broker is started with a WebSocket listener here")
    server: EmbeddedBrokerProcess | ExportedMosquitto | None = None
    with ExitStack() as exits:
        if broker == "mosquitto":
            fleet = fleet or write_fleet(work)
            server = exits.enter_context(ExportedMosquitto(work, fleet))
            port = server.port
        elif broker == "embedded":
            fleet = fleet or CONFIG
            server = exits.enter_context(EmbeddedBrokerProcess(work, fleet, ws=ws))
            port = server.port
        else:
            fleet = fleet or CONFIG
            port = exits.enter_context(mosquitto_with_logins(work, fleet))
        sim_proc = exits.enter_context(run(["-m", "roslink_mqtt.sim"], work / "sim.log")) if sim else None
        args = bridge_args(robot, port, *bridge_extra, config=bridge_config or fleet)
        bridge = exits.enter_context(run(args, work / "bridge.log", {**bridge_env(robot), **(bridge_env_extra or {})}))
        stack = LiveStack(work, broker, port, fleet, robot, bridge, sim_proc, exits, server,
                          server.ws_port if isinstance(server, EmbeddedBrokerProcess) else 0)
        stack.wait_active(viewer, ready_timeout)
        yield stack
