"""``make vda5050``: a factory's master control drives the simulated robot through a VDA 5050 order.

The master control here is a plain MQTT client (what any master control is on the wire, docs/vda5050.md): it
waits for the robot's ONLINE, reads its factsheet, sends an order of three released nodes and one in the horizon,
watches the state as the robot reaches each node and waits at the decision point, releases the last node with an
order update, and finally asks to cancel with no order left (the standard's ``noOrderToCancel``). The demo
(roslink_mqtt/demo.py ``--vda5050``) starts the broker, the simulated robot and its bridge around it.
"""

from __future__ import annotations

import math
import queue
import time
from typing import Any

import orjson

from .config import Fleet
from .mqtt import make_client
from .vda5050 import wire

WAIT = 30.0  # s for each step at most (the robot drives about 1 m in 3 s)
MASTER_PASSWORD = "factory-demo"  # examples/vda5050/robots.yaml: public, demo only


class Master:
    """The master control: a plain MQTT client on the robot's VDA 5050 topics."""

    def __init__(self, port: int, user: str, manufacturer: str, serial_number: str) -> None:
        self.user = user
        self.headers = wire.Headers(manufacturer, serial_number)  # the master's own header counters
        self.inbox: queue.Queue[tuple[str, dict[str, Any]]] = queue.Queue()
        leaves = {self.headers.topic(leaf): leaf for leaf in (wire.CONNECTION, wire.FACTSHEET, wire.STATE)}
        self.client = make_client(f"{user}-demo-master", username=user, password=MASTER_PASSWORD)
        self.client.on_message = lambda _c, _u, m: self.inbox.put((leaves[m.topic], orjson.loads(m.payload)))
        self.client.connect("127.0.0.1", port, keepalive=15)
        self.client.loop_start()
        for topic in leaves:
            self.client.subscribe(topic, qos=1)
        self.state: dict[str, Any] = {}

    def send(self, leaf: str, body: dict[str, Any]) -> None:
        self.client.publish(self.headers.topic(leaf), orjson.dumps(self.headers.stamp(leaf, body)), qos=0)

    def wait(self, leaf: str, predicate: Any = lambda _body: True, timeout: float = WAIT) -> dict[str, Any] | None:
        deadline = time.monotonic() + timeout
        while (left := deadline - time.monotonic()) > 0:
            try:
                got, body = self.inbox.get(timeout=left)
            except queue.Empty:
                break
            if got == wire.STATE:
                self.state = body
            if got == leaf and predicate(body):
                return body
        return None

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


def _order(order_id: str, update: int, nodes: list[tuple[str, int, float, float, bool]],
           map_id: str) -> dict[str, Any]:
    body: dict[str, Any] = {"orderId": order_id, "orderUpdateId": update, "nodes": [], "edges": []}
    for name, seq, x, y, released in nodes:
        body["nodes"].append({"nodeId": name, "sequenceId": seq, "released": released, "actions": [],
                              "nodePosition": {"x": round(x, 3), "y": round(y, 3), "mapId": map_id,
                                               "allowedDeviationXY": 0.15}})
    for a, b in zip(body["nodes"], body["nodes"][1:], strict=False):
        body["edges"].append({"edgeId": f"{a['nodeId']}-{b['nodeId']}", "sequenceId": a["sequenceId"] + 1,
                              "released": a["released"] and b["released"], "startNodeId": a["nodeId"],
                              "endNodeId": b["nodeId"], "actions": []})
    return body


def _where(state: dict[str, Any]) -> str:
    p = state.get("agvPosition")
    return f"({p['x']:.2f}, {p['y']:.2f})" if p else "(position unknown)"


def run_scene(port: int, fleet: Fleet, robot: str = "turtle1") -> int:
    """Play the scene against the robot's bridge on ``port``; 0 when every step was seen."""
    vda = fleet.robots[robot].vda5050
    if vda is None:
        print(f"demo: {robot} has no vda5050 section in {fleet.file}")
        return 1
    master = Master(port, vda.master, vda.manufacturer, vda.serial_number)
    try:
        return _play(master, vda.map_id)
    finally:
        master.close()


def _play(master: Master, map_id: str) -> int:
    print(f"3. the master control ({master.user}) subscribes to the robot's state, connection and factsheet "
          f"({master.headers.topic(wire.STATE)}, …):")
    online = master.wait(wire.CONNECTION, lambda b: b["connectionState"] == "ONLINE")
    factsheet = master.wait(wire.FACTSHEET)
    if online is None or factsheet is None:
        print("  the robot did not come online; see the logs")
        return 1
    kind = factsheet["typeSpecification"]
    actions = ", ".join(a["actionType"] for a in factsheet["protocolFeatures"]["agvActions"])
    print(f"  connection: ONLINE; factsheet: {kind['seriesName']} ({kind['agvKinematic']}, {kind['agvClass']}), "
          f"instant actions: {actions}")
    here = master.wait(wire.STATE, lambda b: "agvPosition" in b)
    if here is None:
        print("  no position in the robot's state; see the logs")
        return 1
    x, y = here["agvPosition"]["x"], here["agvPosition"]["y"]
    nodes = [("a", 0, x, y, True), ("b", 2, x + 1.0, y, True), ("c", 4, x + 1.0, y + 1.0, True),
             ("d", 6, x, y + 1.0, False)]
    print("4. order o1: a (where the robot stands) → b → c released, d in the horizon")
    master.send(wire.ORDER, _order("o1", 0, nodes, map_id))
    reached = ""
    while True:
        state = master.wait(wire.STATE, lambda b, last=reached: b["lastNodeId"] != last or b["newBaseRequest"]
                            or b["errors"])
        if state is None:
            print("  (no progress seen)")
            return 1
        if state["errors"]:
            print(f"  refused: {state['errors'][-1]['errorType']}: {state['errors'][-1].get('errorDescription')}")
            return 1
        if state["lastNodeId"] != reached:
            reached = state["lastNodeId"]
            print(f"  reached {reached} at {_where(state)}; still to go: "
                  f"{', '.join(n['nodeId'] + ('' if n['released'] else ' (horizon)') for n in state['nodeStates'])}")
        if reached == "c" and state["newBaseRequest"] and not state["driving"]:
            print("  waits at c, the decision point, and asks for more (newBaseRequest)")
            break
    print("5. order update 1 releases d (stitched at c)")
    master.send(wire.ORDER, _order("o1", 1, [nodes[2], (*nodes[3][:4], True)], map_id))
    done = master.wait(wire.STATE, lambda b: b["lastNodeId"] == "d" and not b["nodeStates"] and not b["driving"])
    if done is None:
        print("  (the update was not driven to its end)")
        return 1
    back = math.hypot(done["agvPosition"]["x"] - x, done["agvPosition"]["y"] - y)
    print(f"  reached d at {_where(done)}: order o1 done, {back:.2f} m from where it started")
    print("6. cancelOrder with no order under way:")
    master.send(wire.INSTANT_ACTIONS, {"actions": [{"actionType": "cancelOrder", "actionId": "demo-cancel",
                                                    "blockingType": "HARD"}]})
    failed = master.wait(wire.STATE, lambda b: any(e["errorType"] == "noOrderToCancel" for e in b["errors"]))
    if failed is None:
        print("  (no answer seen)")
        return 1
    status = next(a["actionStatus"] for a in failed["actionStates"] if a["actionId"] == "demo-cancel")
    print(f"  demo-cancel: {status}, warning noOrderToCancel")
    return 0
