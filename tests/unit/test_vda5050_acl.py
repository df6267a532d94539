"""Who may use a VDA 5050 robot's topics: its master control and the robot itself, each one way, nobody else
(roslink_mqtt/broker/acl.py); the Mosquitto and RabbitMQ exports carry the same entries."""

from __future__ import annotations

import re

import pytest

from roslink_mqtt.broker.acl import Access, Action, FleetAcl
from roslink_mqtt.broker.export import acl_text
from roslink_mqtt.broker.export_dynsec import role_acls
from roslink_mqtt.broker.export_rabbitmq import topic_permission_regex
from roslink_mqtt.config import parse_fleet
from tests.unit.test_vda5050_messages import FLEET

pytestmark = pytest.mark.unit
ADMIN = '  admin:\n    password: "{h}"\n    admin: true\n'
T = "uagv/v2/RoslinkSim/turtle1/"
TO_VEHICLE, FROM_VEHICLE = ("order", "instantActions"), ("state", "visualization", "connection", "factsheet")


def acl() -> FleetAcl:
    h = FLEET.split('password: "', 1)[1].split('"', 1)[0]
    return FleetAcl(parse_fleet(FLEET + ADMIN.format(h=h), "robots.yaml"))


def test_the_master_commands_and_the_robot_reports_each_one_way() -> None:
    a = acl()
    for leaf in TO_VEHICLE:
        assert a.allows("mc", T + leaf, Action.PUBLISH) and not a.allows("mc", T + leaf, Action.RECEIVE)
        assert a.allows("turtle1", T + leaf, Action.RECEIVE) and not a.allows("turtle1", T + leaf, Action.PUBLISH)
    for leaf in FROM_VEHICLE:
        assert a.allows("turtle1", T + leaf, Action.PUBLISH) and not a.allows("turtle1", T + leaf, Action.RECEIVE)
        assert a.allows("mc", T + leaf, Action.RECEIVE) and not a.allows("mc", T + leaf, Action.PUBLISH)
    assert a.allows("mc", "uagv/v2/RoslinkSim/+/state", Action.SUBSCRIBE)
    assert a.allows("admin", T + "order", Action.PUBLISH)


def test_nobody_else_reaches_them() -> None:
    a = acl()
    for login in ("bob", "turtle2", "nobody"):  # a viewer of the robot, another robot, an unknown login
        for leaf in TO_VEHICLE + FROM_VEHICLE:
            for action in (Action.PUBLISH, Action.RECEIVE):
                assert not a.allows(login, T + leaf, action), (login, leaf, action)
        assert not a.allows(login, "uagv/#", Action.SUBSCRIBE)
    # the master has nothing of another serial number, nor of the ROSLink robot it does not drive
    assert not a.allows("mc", "uagv/v2/RoslinkSim/turtle2/order", Action.PUBLISH)
    assert not a.allows("mc", "roslink/turtle2/state/x", Action.RECEIVE)


def test_the_exports_carry_the_same_entries() -> None:
    a = acl()
    text = acl_text(a.fleet, a)
    assert f"topic write {T}order" in text and f"topic read {T}state" in text
    assert f"topic write {T}state" in text  # the robot's own section
    write = re.compile(topic_permission_regex(a.entries("mc"), Access.WRITE))
    read = re.compile(topic_permission_regex(a.entries("mc"), Access.READ))
    assert write.search("uagv.v2.RoslinkSim.turtle1.order") and not write.search("uagv.v2.RoslinkSim.turtle1.state")
    assert read.search("uagv.v2.RoslinkSim.turtle1.state")
    dynsec = {(e["acltype"], e["topic"]) for e in role_acls(a.fleet, "mc", a)}
    assert ("publishClientSend", T + "order") in dynsec and ("publishClientReceive", T + "state") in dynsec
    assert ("publishClientSend", T + "state") not in dynsec
