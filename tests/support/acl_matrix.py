"""The broker's access matrix: principals, topic classes, the documented outcome and an independent oracle.

Shared by the matrix run on the real brokers (tests/integration/test_broker_matrix.py), the exporters' unit
tests and the RabbitMQ cluster. The oracle reads topics by hand from broker/README.md ("What it enforces"): it
must not use the product's own topic parser, or a parser bug would agree with itself.
"""

from __future__ import annotations

import paho.mqtt.client as mqtt

from roslink_mqtt.topics import TopicTree, Verb
from tests.support.procs import DEMO_PASSWORDS

BACKENDS = ("embedded", "mosquitto", "mosquitto-dynsec")  # the last: its dynamic-security plugin
ROBOTS = ("turtle1", "turtle2")
PRINCIPALS = ("turtle1", "turtle2", "alice", "bob", "carol", "admin", "wrong-password", "anonymous")
LOGINS: dict[str, tuple[str | None, str | None]] = {
    **{p: (p, DEMO_PASSWORDS[p]) for p in DEMO_PASSWORDS},
    "wrong-password": ("alice", "not-alices-password"),
    "anonymous": (None, None),
}
SELF = {**{p: p for p in DEMO_PASSWORDS}, "wrong-password": "alice", "anonymous": "nobody"}

ROBOT_CLASSES = ("heartbeat", "state", "from/self/cmd", "from/other/cmd", "from/self/estop", "to/self", "to/other",
                 "call/read-only", "call/read-write", "grants", "watch")
CLASSES = tuple(f"{c}@{r}" for r in ROBOTS for c in ROBOT_CLASSES) + ("operators/self", "operators/other", "$SYS")
ACTIONS = ("publish", "subscribe", "receive", "retained")
WILDCARDS = ("#", "roslink/#", "roslink/+/heartbeat", "roslink/turtle1/#", "roslink/turtle2/#",
             "roslink/+/to/+/#", "roslink/operators/#", "$SYS/#")

# The documented outcome (broker/README.md "What it enforces", issue 3). r = may read (subscribe, receive, retained),
# w = may publish. Unlisted classes: nothing. "other" is bob (alice for bob himself).
EXPECTED: dict[str, dict[str, str]] = {
    # a robot reads its own grants (who may use it: written by admins only) and nobody else's
    "turtle1": {"heartbeat@turtle1": "rw", "state@turtle1": "w", "grants@turtle1": "r",
                "to/self@turtle1": "w", "to/other@turtle1": "w",
                "from/self/cmd@turtle1": "r", "from/other/cmd@turtle1": "r", "from/self/estop@turtle1": "r",
                "call/read-only@turtle1": "r", "call/read-write@turtle1": "r", "watch@turtle1": "r",
                "operators/other": "r"},  # bob is granted turtle1
    "turtle2": {"heartbeat@turtle2": "rw", "state@turtle2": "w", "grants@turtle2": "r",
                "to/self@turtle2": "w", "to/other@turtle2": "w",
                "from/self/cmd@turtle2": "r", "from/other/cmd@turtle2": "r", "from/self/estop@turtle2": "r",
                "call/read-only@turtle2": "r", "watch@turtle2": "r",
                "call/read-write@turtle2": "r"},  # bob is not granted turtle2: his presence is not for turtle2
    "alice": {"heartbeat@turtle1": "r", "state@turtle1": "r", "to/self@turtle1": "r", "from/self/cmd@turtle1": "w",
              "from/self/estop@turtle1": "w", "call/read-only@turtle1": "w", "call/read-write@turtle1": "w",
              "watch@turtle1": "w", "operators/self": "w"},
    "bob": {"heartbeat@turtle1": "r", "state@turtle1": "r", "to/self@turtle1": "r", "call/read-only@turtle1": "w",
            "from/self/estop@turtle1": "w", "watch@turtle1": "w",  # turtle1's front_camera (the demo fleet's video:)
            "operators/self": "w"},  # viewer: no commands but the emergency stop, only read-only service calls
    "carol": {"heartbeat@turtle2": "r", "state@turtle2": "r", "to/self@turtle2": "r", "from/self/cmd@turtle2": "w",
              "from/self/estop@turtle2": "w", "call/read-only@turtle2": "w", "call/read-write@turtle2": "w",
              "watch@turtle2": "w", "operators/self": "w"},
    "admin": {**{c: "rw" for c in CLASSES}, "$SYS": "r"},  # nobody publishes into $SYS
    "wrong-password": {},
    "anonymous": {},
}
MOSQUITTO_GRANTS_EVERY_FILTER = True  # Mosquitto 2.0.11 (acl_file, or dynsec's subscribePattern #): SUBACK ok,
# read checked per delivery
# The embedded broker drops retained commands and calls (a retained copy would run again on every
# bridge reconnect), whoever sends them -- admin included. Mosquitto cannot: docs/safety.md says so.
NEVER_RETAINED_EMBEDDED = ("from/self/cmd", "from/other/cmd", "from/self/estop", "call/read-only", "call/read-write",
                           "watch")

TREE = TopicTree("roslink")
GRANTED = {"turtle1": {"alice", "bob", "admin"}, "turtle2": {"carol", "admin"}}
OPERATORS = {"alice": {"turtle1"}, "carol": {"turtle2"}, "admin": {"turtle1", "turtle2"}}
VIEWERS = {"bob": {"turtle1"}}
READ_ONLY_SERVICES = {"status"}
VIDEO_STREAMS = {"turtle1": {"front_camera"}}  # the demo fleet's video: every granted user may watch


def other_of(me: str) -> str:
    return "alice" if me == "bob" else "bob"


def topic_of(cls: str, me: str, *, publish: bool = False) -> str:
    if cls == "$SYS":
        return "$SYS/broker/matrix" if publish else "$SYS/broker/version"
    if cls == "operators/self":
        return f"roslink/operators/{me}/matrix"
    if cls == "operators/other":
        return f"roslink/operators/{other_of(me)}/matrix"
    kind, robot = cls.split("@")
    return {
        "heartbeat": TREE.heartbeat(robot), "state": TREE.state(robot, "matrix"),
        "from/self/cmd": TREE.command(robot, me, "twist"), "from/other/cmd": TREE.command(robot, other_of(me), "twist"),
        "from/self/estop": TREE.command(robot, me, "emergency_stop"),
        "to/self": TREE.reply(robot, me, "reset"), "to/other": TREE.reply(robot, other_of(me), "reset"),
        "call/read-only": TREE.call(robot, me, "status"), "call/read-write": TREE.call(robot, me, "reset"),
        "grants": TREE.grants(robot), "watch": TREE.user_topic(robot, me, Verb.WATCH, "front_camera"),
    }[kind]


# -- an independent oracle, written from broker/README.md (not from roslink_mqtt.broker.acl, nor from the product's
# topic parser: the levels are read here by hand) --


def _read(topic: str) -> dict[str, str] | None:
    """The parts of a topic of the tree, as broker/README.md names them; None outside the tree."""
    parts = topic.split("/")
    if len(parts) < 3 or parts[0] != "roslink":
        return None
    if parts[1] == "operators":
        return {"kind": "operators", "user": parts[2]} if len(parts) == 4 else None
    robot, kind, rest = parts[1], parts[2], parts[3:]
    if kind in ("heartbeat", "grants") and not rest:
        return {"kind": kind, "robot": robot}
    if kind == "state" and rest:
        return {"kind": kind, "robot": robot, "name": "/".join(rest)}
    if kind in ("from", "to") and len(rest) >= 2:
        verb = rest[1]
        return {"kind": kind, "robot": robot, "user": rest[0], "verb": verb, "name": "/".join(rest[2:])}
    return None


def dynsec_presence(login: str, topic: str) -> bool:
    """The one documented difference of the dynamic-security export (roslink_mqtt/broker/export_dynsec.py): a
    robot's role reads every user's presence, not only its granted users' (a grant change would otherwise drop the
    robot's bridge)."""
    t = _read(topic)
    return login in ROBOTS and t is not None and t["kind"] == "operators"


def may_read(login: str, topic: str) -> bool:
    if login == "admin":
        return True
    if login not in DEMO_PASSWORDS or topic.startswith("$"):
        return False
    t = _read(topic)
    if t is None:
        return False
    if login in ROBOTS:
        # its users' inputs and presence; its own heartbeat and state/bridge (where another bridge of the robot
        # shows itself: one per robot)
        return (t["kind"] == "from" and t["robot"] == login) \
            or (t["kind"] == "operators" and t["user"] in GRANTED[login]) \
            or (t.get("robot") == login and (t["kind"] in ("heartbeat", "grants") or (t["kind"] == "state"
                                                                                       and t["name"] == "bridge")))
    robots = OPERATORS.get(login, set()) | VIEWERS.get(login, set())
    return t.get("robot") in robots and (t["kind"] in ("heartbeat", "state")
                                         or (t["kind"] == "to" and t["user"] == login))


def may_write(login: str, topic: str) -> bool:
    if topic.startswith("$") or login not in DEMO_PASSWORDS:
        return False
    if login == "admin":
        return True
    t = _read(topic)
    if t is None:
        return False
    if login in ROBOTS:
        return t.get("robot") == login and t["kind"] in ("heartbeat", "state", "to")
    if t["kind"] == "operators":
        return t["user"] == login
    if t["kind"] != "from" or t["user"] != login:
        return False
    if t["robot"] in OPERATORS.get(login, set()):
        return True
    # a viewer: read-only services, and the robot's emergency stop (the demo fleet's robots allow viewers that)
    if t["robot"] not in VIEWERS.get(login, set()):
        return False
    return (t["verb"] == "call" and t["name"] in READ_ONLY_SERVICES) \
        or (t["verb"] == "cmd" and t["name"] == "emergency_stop") \
        or (t["verb"] == "watch" and t["name"] in VIDEO_STREAMS.get(t["robot"], set()))


def matches(flt: str, topic: str) -> bool:
    if topic.startswith("$") and flt[:1] in ("+", "#"):
        return False
    return mqtt.topic_matches_sub(flt, topic)


