"""A ROS 2 robot that speaks VDA 5050 (issue 46): a third-party master control (vda5050-sdk's MasterClient, over
aiomqtt) drives the simulated robot through whole orders, on the embedded broker and on the exported Mosquitto.

One stack per broker: broker, sim (its ``navigate_to_pose`` action), turtle1's bridge with a ``vda5050`` section,
the master control ``factory`` (an operator of turtle1 whose ACL holds exactly the robot's VDA topics), and an
admin watching ``uagv/#``, whose copy of every message the robot sends is checked against the standard's 2.1.0
schemas at the end. In order: ONLINE and the factsheet; a three-node order driven to its end; a horizon, the wait
at the decision point and the update that releases it; refusals (malformed, older update, a new order while one
runs) that change nothing; pause and resume; one driver (an operator's twists are refused while the order runs);
a viewer's emergency stop (eStop REMOTE), cancelOrder and noOrderToCancel; the bridge killed: CONNECTIONBROKEN.
"""

from __future__ import annotations

import asyncio
import json
import math
import threading
import time
from collections.abc import Callable, Coroutine, Iterator
from contextlib import ExitStack
from pathlib import Path
from typing import Any

import pytest

from roslink_mqtt.config.passwords import hash_password
from roslink_mqtt.protocol import encode_message
from tests.support.broker_setup import ExportedMosquitto, write_fleet
from tests.support.embedded_broker import EmbeddedBrokerProcess
from tests.support.measure import record_measurement
from tests.support.mqtt_client import TestClient
from tests.support.procs import bridge_args, bridge_env, run
from tests.support.waits import never, paced, stays, wait_until

pytestmark = pytest.mark.timeout(300)

T = "uagv/v2/RoslinkSim/turtle1/"
KEEPALIVE = 5  # s: the demo bridge's (robots.yaml bridge.keepalive default)
VDA_SECTION = """\
    vda5050:
      manufacturer: RoslinkSim
      map_id: demo-room
      master: factory
      navigate_type: roslink_sim_msgs/action/NavigateToPose
      frame: odom
      state_interval: 5
      visualization_interval: 0.5
      estop: hw_estop
      actions: {resetPose: {service: reset}}
      vehicle: {width: 0.4, length: 0.5, height: 0.3, series_name: ROSLink sim}
"""


def _with_vda(text: str) -> str:
    anchor = "    # password: turtle1-demo\n"
    assert anchor in text
    factory = (f'  factory:  # the master control — password factory-demo\n'
               f'    password: "{hash_password("factory-demo", iterations=1000)}"\n'
               f'    grants:\n      - {{key: demo-key-turtle1, role: operator}}\n')
    text = text.replace(anchor, VDA_SECTION + anchor, 1)
    return text.replace("users:\n", "users:\n" + factory, 1)


class Master:
    """vda5050-sdk's MasterClient on an event loop of its own, driven from the test's thread."""

    def __init__(self, port: int) -> None:
        from vda5050.client.master import MasterClient
        from vda5050.config import MasterConfig

        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()
        self.client = MasterClient(MasterConfig(broker_url=f"mqtt://127.0.0.1:{port}", username="factory",
                                                password="factory-demo", client_id="factory-master"))
        self.states: list[Any] = []  # as the SDK parsed them (pydantic models of the standard's messages)
        self.connections: list[str] = []
        self.client.on_state(lambda state, _key: self.states.append(state))
        self.client.on_connection(lambda c, _key: self.connections.append(str(c.connection_state.value)))
        self.call(self.client.connect())

    def call(self, coro: Coroutine[Any, Any, Any], timeout: float = 10.0) -> Any:
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(timeout)

    def order(self, order_id: str, update: int, nodes: list[tuple[str, int, float, float, bool]]) -> Any:
        from vda5050.model.common import NodePosition
        from vda5050.model.order import Edge, Node, Order

        vnodes = [Node(node_id=n, sequence_id=s, released=r, node_position=NodePosition(x=x, y=y, map_id="demo-room",
                                                                                        allowed_deviation_xy=0.15))
                  for n, s, x, y, r in nodes]
        edges = [Edge(edge_id=f"{a.node_id}-{b.node_id}", sequence_id=a.sequence_id + 1,
                      released=a.released and b.released, start_node_id=a.node_id, end_node_id=b.node_id)
                 for a, b in zip(vnodes, vnodes[1:], strict=False)]
        order = Order(header_id=0, version="2.1.0", manufacturer="RoslinkSim", serial_number="turtle1",
                      order_id=order_id, order_update_id=update, nodes=vnodes, edges=edges)
        return self.call(self.client.dispatch(order, "RoslinkSim/turtle1"))

    def close(self) -> None:
        try:
            self.call(self.client.disconnect(), timeout=5)
        finally:
            self.loop.call_soon_threadsafe(self.loop.stop)
            self.thread.join(5)


class Watch:
    """An admin's copy of everything on the robot's VDA topics, newest state at hand."""

    def __init__(self, port: int) -> None:
        self.client = TestClient(port, "admin", "admin-demo")
        assert self.client.connect() == 0
        self.all: list[tuple[str, dict[str, Any]]] = []
        self.arrived: list[float] = []  # when each of them came (wall clock, as the messages' timestamps)
        self.lock = threading.Lock()
        self.client.client.on_message = self._on_message
        self.client.subscribe("uagv/#")

    def _on_message(self, _c: Any, _u: Any, m: Any) -> None:
        if m.payload:
            with self.lock:
                self.all.append((m.topic, json.loads(m.payload)))
                self.arrived.append(time.time())

    def of(self, leaf: str) -> list[dict[str, Any]]:
        with self.lock:
            return [body for topic, body in self.all if topic == T + leaf]

    def state(self, predicate: Callable[[dict[str, Any]], bool], what: str, timeout: float = 30.0,
              after: int = 0) -> dict[str, Any]:
        """The first state from index ``after`` on that ``predicate`` accepts (waiting for it)."""
        try:
            return wait_until(f"a state where {what}", lambda: next(
                (s for s in self.of("state")[after:] if predicate(s)), None), timeout=timeout)
        except AssertionError:
            last = self.of("state")[-1:] or [None]
            raise AssertionError(f"no state where {what} within {timeout} s; the last: "
                                 f"{json.dumps(last[0])[:1500]}") from None

    def mark(self) -> int:
        return len(self.of("state"))

    def publish_as(self, port: int, user: str, leaf: str, body: Any) -> None:
        with TestClient(port, user, f"{user}-demo") as c:
            assert c.connect() == 0
            c.publish(T + leaf, body if isinstance(body, (bytes, str)) else json.dumps(body), qos=1)


def _near(state: dict[str, Any], x: float, y: float, within: float = 0.2) -> bool:
    p = state.get("agvPosition")
    return p is not None and math.hypot(p["x"] - x, p["y"] - y) <= within


def _raw_order(order_id: str, update: int, nodes: list[tuple[str, int, float, float, bool]]) -> dict[str, Any]:
    body: dict[str, Any] = {"headerId": 900 + update, "timestamp": "2026-11-29T08:00:00.00Z", "version": "2.1.0",
                            "manufacturer": "RoslinkSim", "serialNumber": "turtle1", "orderId": order_id,
                            "orderUpdateId": update, "nodes": [], "edges": []}
    for n, s, x, y, r in nodes:
        body["nodes"].append({"nodeId": n, "sequenceId": s, "released": r, "actions": [],
                              "nodePosition": {"x": x, "y": y, "mapId": "demo-room", "allowedDeviationXY": 0.15}})
    for a, b in zip(body["nodes"], body["nodes"][1:], strict=False):
        body["edges"].append({"edgeId": f"{a['nodeId']}-{b['nodeId']}", "sequenceId": a["sequenceId"] + 1,
                              "released": a["released"] and b["released"], "startNodeId": a["nodeId"],
                              "endNodeId": b["nodeId"], "actions": []})
    return body


def _errors(state: dict[str, Any], kind: str) -> list[dict[str, Any]]:
    return [e for e in state["errors"] if e["errorType"] == kind]


@pytest.fixture(params=["embedded", "mosquitto"])
def stack(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[dict[str, Any]]:
    with ExitStack() as s:
        fleet = write_fleet(tmp_path, edit=_with_vda)
        if request.param == "mosquitto":
            server: Any = s.enter_context(ExportedMosquitto(tmp_path, fleet))
        else:
            server = s.enter_context(EmbeddedBrokerProcess(tmp_path, fleet))
        port = server.port
        s.enter_context(run(["-m", "roslink_mqtt.sim"], tmp_path / "sim.log"))
        watch = Watch(port)
        s.callback(watch.client.close)
        bridge = s.enter_context(run(bridge_args("turtle1", port, config=fleet), tmp_path / "bridge.log",
                                     bridge_env("turtle1")))
        yield {"port": port, "watch": watch, "bridge": bridge, "broker": request.param, "tmp": tmp_path,
               "fleet": fleet}


def test_a_master_control_drives_the_robot_through_orders(stack: dict[str, Any]) -> None:
    from vda5050.validation import SchemaValidator

    port, watch, broker = stack["port"], stack["watch"], stack["broker"]
    watch.state(lambda s: _near(s, 0.0, 0.0, 0.05), "the robot stands at the room's centre", timeout=60)
    master = Master(port)
    try:
        _drive_orders(port, watch, master, broker)
    finally:
        master.close()

    # -- a clean stop says OFFLINE (retained); a new bridge says ONLINE; killed, the broker publishes the robot's
    #    last will, CONNECTIONBROKEN (retained)
    def connection_becomes(state: str, since: int, within: float) -> None:
        try:
            wait_until(f"connection {state}", lambda: any(c["connectionState"] == state
                                                          for c in watch.of("connection")[since:]), timeout=within)
        except AssertionError:
            raise AssertionError((state, [c["connectionState"] for c in watch.of("connection")])) from None

    since = len(watch.of("connection"))
    stack["bridge"].stop()  # SIGINT, as systemd stops it
    connection_becomes("OFFLINE", since, 15)
    since = len(watch.of("connection"))
    with run(bridge_args("turtle1", port, config=stack["fleet"]), stack["tmp"] / "bridge2.log",
             bridge_env("turtle1")) as again:
        connection_becomes("ONLINE", since, 30)
        since = len(watch.of("connection"))
        killed = time.monotonic()
        again.popen.kill()
        connection_becomes("CONNECTIONBROKEN", since, 1.5 * KEEPALIVE + 10)
    record_measurement(f"[{broker}] VDA 5050 bridge killed → CONNECTIONBROKEN", time.monotonic() - killed,
                       1.5 * KEEPALIVE + 10)

    assert not [s for s in watch.of("state") if s["orderId"] == "evil"]

    # -- everything the robot sent is what the standard's 2.1.0 schemas accept
    schemas = SchemaValidator()
    counts: dict[str, int] = {}
    for topic, body in watch.all:
        leaf = topic.rsplit("/", 1)[-1]
        if leaf in ("state", "visualization", "connection", "factsheet"):
            counts[leaf] = counts.get(leaf, 0) + 1
            assert schemas.errors(leaf, body) == [], (leaf, schemas.errors(leaf, body), body)
    assert counts["state"] > 20 and counts["visualization"] > 10 and counts["factsheet"] >= 1, counts
    assert len(master.states) > 10  # and the master's SDK read them


def _drive_orders(port: int, watch: Watch, master: Master, broker: str) -> None:
    # -- ONLINE, retained, and the factsheet listing exactly the instant actions the robot carries out
    try:
        wait_until("ONLINE at the master control", lambda: "ONLINE" in master.connections, timeout=15)
    except AssertionError:
        raise AssertionError(master.connections) from None
    factsheet = watch.of("factsheet")[-1]
    assert [a["actionType"] for a in factsheet["protocolFeatures"]["agvActions"]] == [
        "startPause", "stopPause", "cancelOrder", "stateRequest", "factsheetRequest", "resetPose"]

    # -- a three-node order, driven to its end
    mark = watch.mark()
    result = master.order("o1", 0, [("n0", 0, 0.0, 0.0, True), ("n1", 2, 1.0, 0.0, True), ("n2", 4, 1.0, 1.0, True)])
    assert result.accepted, result
    taken = watch.state(lambda s: s["orderId"] == "o1", "o1 is taken", after=mark)
    assert taken["lastNodeId"] == "n0" and [n["nodeId"] for n in taken["nodeStates"]] == ["n1", "n2"]
    watch.state(lambda s: s["lastNodeId"] == "n1" and [n["nodeId"] for n in s["nodeStates"]] == ["n2"],
                "n1 is reached", after=mark)
    done = watch.state(lambda s: s["lastNodeId"] == "n2" and not s["nodeStates"] and not s["edgeStates"]
                       and not s["driving"], "o1 is driven to its end", after=mark)
    assert _near(done, 1.0, 1.0), done["agvPosition"]

    # -- refusals change nothing: malformed, the same order again (ignored), a lower update
    mark = watch.mark()
    watch.publish_as(port, "factory", "order", {"headerId": 1, "orderId": "bad"})
    refused = watch.state(lambda s: _errors(s, "validationError"), "a validationError", after=mark)
    assert refused["orderId"] == "o1" and refused["lastNodeId"] == "n2"
    # a viewer cannot send an order, on either broker: the ACL drops it (the robot never sees it)
    watch.publish_as(port, "bob", "order", _raw_order("evil", 0, [("e0", 0, 1.0, 1.0, True)]))

    # -- a horizon: the robot waits at the decision point, asks for more, and the update releases it
    mark = watch.mark()
    assert master.order("o2", 0, [("m0", 0, 1.0, 1.0, True), ("m1", 2, 0.0, 1.0, True),
                                  ("m2", 4, 0.0, 0.0, False)]).accepted
    waits = watch.state(lambda s: s["orderId"] == "o2" and s["lastNodeId"] == "m1" and not s["driving"],
                        "the robot waits at m1", after=mark)
    assert waits["newBaseRequest"] and [(n["nodeId"], n["released"]) for n in waits["nodeStates"]] == [("m2", False)]
    assert not _errors(waits, "validationError")  # the accepted order cleared the warning
    mark = watch.mark()
    watch.publish_as(port, "factory", "order", _raw_order("o2", 1, [("m1", 2, 0.0, 1.0, True),
                                                                    ("m2", 4, 0.0, 0.0, True)]))
    watch.state(lambda s: s["orderUpdateId"] == 1 and s["lastNodeId"] == "m2" and not s["nodeStates"]
                and not s["driving"], "the update is driven to m2", after=mark)
    mark = watch.mark()
    watch.publish_as(port, "factory", "order", _raw_order("o2", 0, [("m0", 0, 1.0, 1.0, True),
                                                                    ("m1", 2, 0.0, 1.0, True)]))
    old = watch.state(lambda s: _errors(s, "orderUpdateError"), "an orderUpdateError", after=mark)
    assert old["orderUpdateId"] == 1 and _near(old, 0.0, 0.0)

    # -- pause and resume; one driver: while the order runs, an operator's twists are refused, naming the master
    mark = watch.mark()
    assert master.order("o3", 0, [("p0", 0, 0.0, 0.0, True), ("p1", 2, 1.5, 0.0, True)]).accepted
    watch.state(lambda s: s["orderId"] == "o3" and s["driving"], "driving o3", after=mark)
    with TestClient(port, "alice", "alice-demo", operator=True) as alice:
        assert alice.connect() == 0
        alice.subscribe("roslink/turtle1/to/alice/#")
        alice.publish("roslink/turtle1/from/alice/cmd/twist", encode_message(100, {"lx": 0.3}), qos=0)
        said = alice.wait_for(lambda m: m.topic.endswith("/error"), timeout=10).json()["error"]
        assert "driven by factory" in said, said
    mark = watch.mark()
    watch.publish_as(port, "factory", "order", _raw_order("o4", 0, [("q0", 0, 0.5, 0.0, True)]))
    busy = watch.state(lambda s: _errors(s, "orderError"), "an orderError (o3 runs)", after=mark)
    assert busy["orderId"] == "o3"
    paused_at = time.monotonic()
    master.call(master.client.pause("RoslinkSim/turtle1", action_id="pause-1"))
    paused = watch.state(lambda s: s["paused"] and not s["driving"] and any(
        a["actionId"] == "pause-1" and a["actionStatus"] == "FINISHED" for a in s["actionStates"]),
        "paused and standing", after=mark)
    record_measurement(f"[{broker}] VDA 5050 startPause → standing (state)", time.monotonic() - paused_at, 5.0)
    assert paused["nodeStates"] and not _near(paused, 1.5, 0.0)  # stopped on the way

    def moved(s: dict[str, Any]) -> float:
        return math.hypot(s["agvPosition"]["x"] - paused["agvPosition"]["x"],
                          s["agvPosition"]["y"] - paused["agvPosition"]["y"])

    # a paused robot stays where it stopped
    never("the paused robot moving", lambda: (last := watch.of("state")[-1:]) and "agvPosition" in last[0]
          and moved(last[0]) >= 0.05, seconds=1.0)
    still = watch.state(lambda s: True, "a state", after=watch.mark() - 1)
    assert moved(still) < 0.05
    mark = watch.mark()
    master.call(master.client.resume("RoslinkSim/turtle1", action_id="resume-1"))
    resumed = watch.state(lambda s: s["lastNodeId"] == "p1" and not s["nodeStates"] and not s["driving"],
                          "o3 is driven to its end after the resume", after=mark)
    assert not resumed["paused"] and _near(resumed, 1.5, 0.0)

    # -- anyone's emergency stop stops an order (eStop REMOTE); cancelOrder ends it; a second cancel: nothing to cancel
    mark = watch.mark()
    assert master.order("o5", 0, [("r0", 0, 1.5, 0.0, True), ("r1", 2, -1.5, 0.0, True)]).accepted
    watch.state(lambda s: s["orderId"] == "o5" and s["driving"], "driving o5", after=mark)
    stopped_at = time.monotonic()
    with TestClient(port, "bob", "bob-demo") as bob:  # a viewer
        assert bob.connect() == 0
        bob.publish("roslink/turtle1/from/bob/cmd/emergency_stop", encode_message(108, {"reason": "vda test"}))
    estop = watch.state(lambda s: s["safetyState"]["eStop"] == "REMOTE" and not s["driving"],
                        "eStop REMOTE and standing", after=mark)
    record_measurement(f"[{broker}] VDA 5050 order + emergency stop → standing (state)",
                       time.monotonic() - stopped_at, 5.0)
    assert estop["nodeStates"] and not _near(estop, -1.5, 0.0)
    mark = watch.mark()
    master.call(master.client.cancel_order("RoslinkSim/turtle1", action_id="cancel-1"))
    cancelled = watch.state(lambda s: any(a["actionId"] == "cancel-1" and a["actionStatus"] == "FINISHED"
                                          for a in s["actionStates"]), "cancel-1 FINISHED", after=mark)
    assert cancelled["nodeStates"] == [] and cancelled["edgeStates"] == [] and cancelled["orderId"] == "o5"
    mark = watch.mark()
    master.call(master.client.cancel_order("RoslinkSim/turtle1", action_id="cancel-2"))
    nothing = watch.state(lambda s: _errors(s, "noOrderToCancel"), "noOrderToCancel", after=mark)
    assert {"actionId": "cancel-2", "actionType": "cancelOrder", "actionStatus": "FAILED"} in nothing["actionStates"]

    # -- an instant action robots.yaml maps to a ROS service: RUNNING, then FINISHED with what the service said
    from vda5050.model.common import Action, BlockingType

    mark = watch.mark()
    master.call(master.client.send_instant_action("RoslinkSim/turtle1", [
        Action(action_type="resetPose", action_id="reset-1", blocking_type=BlockingType.NONE)]))
    reset = watch.state(lambda s: any(a["actionId"] == "reset-1" and a["actionStatus"] == "FINISHED"
                                      for a in s["actionStates"]), "reset-1 FINISHED", after=mark)
    assert {"actionId": "reset-1", "actionType": "resetPose", "actionStatus": "FINISHED",
            "resultDescription": "pose reset to the room centre"} in reset["actionStates"]
    watch.state(lambda s: _near(s, 0.0, 0.0, 0.05), "the pose at the centre", after=mark)

    # -- the robot's own e-stop (a ROS topic): eStop MANUAL while it is pressed
    from std_msgs.msg import Bool

    from tests.support.ros import RosProbe

    probe = RosProbe()
    try:
        pressed = probe.publisher(Bool, "/hw_estop")
        mark = watch.mark()

        def manual() -> list[dict[str, Any]]:
            return [s for s in watch.of("state")[mark:] if s["safetyState"]["eStop"] == "MANUAL"]

        for _ in paced(0.2, within=15, stop=manual):
            probe.on_spin(lambda: pressed.publish(Bool(data=True)))  # until the bridge's subscription matched
        assert manual(), "no eStop MANUAL"
        mark = watch.mark()
        probe.on_spin(lambda: pressed.publish(Bool(data=False)))
        watch.state(lambda s: s["safetyState"]["eStop"] == "REMOTE", "eStop back to REMOTE (bob's stop holds)",
                    after=mark)
    finally:
        probe.close()


def test_visualization_stays_fresh_on_a_thin_uplink(tmp_path: Path) -> None:
    """Behind a 96 kbit/s uplink that the robot's ROSLink telemetry fills, the VDA 5050 ``visualization`` leaves as
    motion with latest wins: what the master sees is fresh, not a queue of old poses; ``state`` still arrives."""
    from datetime import datetime

    from roslink_mqtt.protocol.link import LinkReport
    from tests.support.net import free_port, wait_for_port

    fleet = write_fleet(tmp_path, edit=lambda t: _with_vda(t).replace("visualization_interval: 0.5",
                                                                      "visualization_interval: 0.1"))
    with ExitStack() as s:
        broker = s.enter_context(EmbeddedBrokerProcess(tmp_path, fleet))
        link_port = free_port()
        s.enter_context(run(["-m", "roslink_mqtt.shaped_link", "--listen", f"127.0.0.1:{link_port}", "--to",
                             f"127.0.0.1:{broker.port}", "--delay-ms", "20", "--jitter-ms", "0", "--up-kbit", "96",
                             "--down-kbit", "1024"], tmp_path / "link.log"))
        wait_for_port(link_port, 10)
        s.enter_context(run(["-m", "roslink_mqtt.sim"], tmp_path / "sim.log"))
        watch = Watch(broker.port)
        s.callback(watch.client.close)
        links: list[LinkReport] = []
        with TestClient(broker.port, "admin", "admin-demo") as admin:
            assert admin.connect() == 0
            admin.client.on_message = lambda _c, _u, m: links.append(LinkReport.from_json(m.payload)) \
                if m.payload else None
            admin.subscribe("roslink/turtle1/state/link")
            bridge = s.enter_context(run(["-m", "roslink_mqtt.bridge.main", "--config", str(fleet), "--robot",
                                          "turtle1", "--url", f"mqtt://127.0.0.1:{link_port}"],
                                         tmp_path / "bridge.log", bridge_env("turtle1")))
            watch.state(lambda st: "agvPosition" in st, "a first state through the thin link", timeout=60)
            began = len(watch.all)
            # the measured window: the uplink is full all along (the link reports say so below)
            stays("the bridge running", lambda: bridge.poll() is None, seconds=8.0)
            with watch.lock:
                got = list(zip(watch.all[began:], watch.arrived[began:], strict=True))
            seen = [body for (topic, body), _ in got if topic == T + "visualization"]
            ages = sorted(at - datetime.fromisoformat(body["timestamp"].replace("Z", "+00:00")).timestamp()
                          for (topic, body), at in got if topic == T + "visualization")
            full = [r for r in links if r.streams.get("vda5050_visualization") is not None]
        assert len(seen) >= 8, f"only {len(seen)} visualization messages in 8 s"
        p90 = ages[int(0.9 * (len(ages) - 1))]
        record_measurement("VDA 5050 visualization on a 96 kbit/s uplink: age p90", p90, 2.0)
        assert p90 < 2.0, ages[-5:]
        report = full[-1]
        vis = report.streams["vda5050_visualization"]
        assert vis.priority == "motion" and vis.latest_only and report.streams["vda5050_state"].priority == "control"
        assert any(st.superseded > 0 for st in report.streams.values()), report.streams  # the link was full
