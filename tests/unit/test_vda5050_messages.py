"""A robot's ``vda5050:`` section in robots.yaml, and the messages built from it: each validates against the
standard's 2.1.0 schemas (bundled unchanged by vda5050-sdk)."""

from __future__ import annotations

import textwrap

import pytest
from vda5050.validation import SchemaValidator

from roslink_mqtt.config import ConfigError, parse_fleet
from roslink_mqtt.config.model import Vda5050Settings, VelocityLimits
from roslink_mqtt.config.passwords import hash_password
from roslink_mqtt.vda5050.messages import (
    CONNECTIONBROKEN,
    ONLINE,
    Telemetry,
    connection_body,
    factsheet_body,
    state_body,
    visualization_body,
)
from roslink_mqtt.vda5050.order import read_order
from roslink_mqtt.vda5050.vehicle import INSTANT_ACTIONS, Vehicle
from roslink_mqtt.vda5050.wire import Headers

pytestmark = pytest.mark.unit
SCHEMAS = SchemaValidator()
HASH = hash_password("pw", iterations=1)

FLEET = f"""\
robots:
  turtle1:
    system_id: 1
    key: k1
    password: "{HASH}"
    vda5050:
      manufacturer: RoslinkSim
      map_id: demo
      master: mc
      vehicle: {{width: 0.4, length: 0.5, height: 0.3}}
  turtle2:
    system_id: 2
    key: k2
    password: "{HASH}"
users:
  mc:
    password: "{HASH}"
    grants:
      - {{key: k1, role: operator}}
  bob:
    password: "{HASH}"
    grants:
      - {{key: k1, role: viewer}}
"""


def settings() -> Vda5050Settings:
    vda = parse_fleet(FLEET, "robots.yaml").robots["turtle1"].vda5050
    assert vda is not None
    return vda


def test_the_section_loads_with_its_defaults() -> None:
    vda = settings()
    assert (vda.manufacturer, vda.serial_number, vda.map_id, vda.master) == ("RoslinkSim", "turtle1", "demo", "mc")
    assert (vda.navigate, vda.odometry, vda.battery, vda.state_interval) == (
        "navigate_to_pose", "odom", "battery_state", 30.0)
    assert parse_fleet(FLEET, "robots.yaml").robots["turtle2"].vda5050 is None


@pytest.mark.parametrize(("old", "new", "expected"), [
    ("master: mc", "master: bob", "robots.turtle1.vda5050.master: the master control must be an operator of the "
                                  "robot: 'bob' is not an operator of turtle1"),
    ("master: mc", "master: nobody", "the master control must be an operator of the robot: no such user"),
    ("manufacturer: RoslinkSim", "manufacturer: Roslink/Sim", "robots.turtle1.vda5050.manufacturer: expected "
                                                              "letters, digits and _ . : - only"),
    ("map_id: demo", "map_id: demo\n      serial_number: 'a b'", "robots.turtle1.vda5050.serial_number"),
    ("      vehicle: {width: 0.4, length: 0.5, height: 0.3}\n", "", "missing required key 'vehicle'"),
    ("height: 0.3}", "height: 0}", "robots.turtle1.vda5050.vehicle.height: expected a finite number > 0"),
    ("map_id: demo", "map_id: demo\n      state_interval: 60", "robots.turtle1.vda5050.state_interval: expected a "
                                                               "finite number >= 1"),
    ("map_id: demo", "map_id: demo\n      navigte: nav", "unknown key 'navigte' (did you mean 'navigate'?)"),
    ("map_id: demo", "map_id: demo\n      actions: {cancelOrder: {service: stop}}",
     "robots.turtle1.vda5050.actions.cancelOrder: 'cancelOrder' is one of the standard's actions"),
    ("map_id: demo", "map_id: demo\n      actions: {startCharging: {service: dock, type: std_srvs/srv/SetBool}}",
     "robots.turtle1.vda5050.actions.startCharging.type: expected one of std_srvs/srv/Trigger, std_srvs/srv/Empty"),
    ("map_id: demo", "map_id: demo\n      actions: {start-charging: {service: dock}}",
     "expected an instant action type"),
])
def test_mistakes_in_the_section_are_named(old: str, new: str, expected: str) -> None:
    text = FLEET.replace(old, new, 1)
    assert text != FLEET
    with pytest.raises(ConfigError) as info:
        parse_fleet(text, "robots.yaml")
    assert expected in str(info.value), str(info.value)


def test_instant_actions_mapped_to_ros_services_join_the_factsheet() -> None:
    text = FLEET.replace("map_id: demo", "map_id: demo\n      estop: base/estop\n"
                                         "      actions: {startCharging: {service: dock}, "
                                         "stopCharging: {service: undock, type: std_srvs/srv/Empty}}", 1)
    vda = parse_fleet(text, "robots.yaml").robots["turtle1"].vda5050
    assert vda is not None and vda.estop == "base/estop"
    assert [(c.action_type, c.service, c.service_type) for c in vda.actions] == [
        ("startCharging", "dock", "std_srvs/srv/Trigger"), ("stopCharging", "undock", "std_srvs/srv/Empty")]
    factsheet = Headers("RoslinkSim", "turtle1").stamp("factsheet", factsheet_body(vda, VelocityLimits()))
    assert SCHEMAS.errors("factsheet", factsheet) == []
    assert [a["actionType"] for a in factsheet["protocolFeatures"]["agvActions"]][-2:] == [
        "startCharging", "stopCharging"]


def test_two_robots_cannot_share_a_vda_identity() -> None:
    second = textwrap.indent(textwrap.dedent("""\
        vda5050:
          manufacturer: RoslinkSim
          serial_number: turtle1
          map_id: demo
          master: mc
          vehicle: {width: 0.4, length: 0.5, height: 0.3}
        """), "    ")
    text = FLEET.replace('    password: "' + HASH + '"\nusers:', '    password: "' + HASH + '"\n' + second + "users:")
    text = text.replace("      - {key: k1, role: operator}", "      - {key: k1, role: operator}\n"
                                                                "      - {key: k2, role: operator}")
    with pytest.raises(ConfigError, match="RoslinkSim/turtle1 is already robot 'turtle1'"):
        parse_fleet(text, "robots.yaml")


def test_every_message_the_robot_sends_validates_against_the_standards_schemas() -> None:
    vda, headers = settings(), Headers("RoslinkSim", "turtle1")
    t = Telemetry()
    vehicle = Vehicle(map_id=vda.map_id)
    bare = headers.stamp("state", state_body(vehicle, t, vda))  # nothing measured yet
    assert SCHEMAS.errors("state", bare) == [] and bare["information"][0]["infoType"] == "batteryUnknown"
    assert "agvPosition" not in bare
    t = Telemetry(pose=(1.0, 2.0, 7.0), velocity=(0.3, 0.0, 0.1), battery=(76.0, False, 24.1), emergency_stop=True)
    vehicle.set_pose(1.0, 2.0, 7.0)
    vehicle.receive_order(read_order({
        "headerId": 1, "timestamp": "2026-11-29T08:00:00.00Z", "version": "2.1.0", "manufacturer": "RoslinkSim",
        "serialNumber": "turtle1", "orderId": "o1", "orderUpdateId": 0, "edges": [
            {"edgeId": "e1", "sequenceId": 1, "released": True, "startNodeId": "n0", "endNodeId": "n1",
             "actions": []}], "nodes": [
            {"nodeId": "n0", "sequenceId": 0, "released": True, "actions": [],
             "nodePosition": {"x": 1.0, "y": 2.0, "mapId": "demo"}},
            {"nodeId": "n1", "sequenceId": 2, "released": True, "actions": [],
             "nodePosition": {"x": 3.0, "y": 2.0, "theta": 1.5, "mapId": "demo", "allowedDeviationXY": 0.2}}]}))
    state = headers.stamp("state", state_body(vehicle, t, vda))
    assert SCHEMAS.errors("state", state) == [], SCHEMAS.errors("state", state)
    assert state["safetyState"]["eStop"] == "REMOTE" and state["batteryState"] == {
        "batteryCharge": 76.0, "charging": False, "batteryVoltage": 24.1}
    assert abs(state["agvPosition"]["theta"] - (7.0 - 2 * 3.141592653589793)) < 1e-9  # within [-π, π]
    assert state["nodeStates"][0]["nodePosition"]["theta"] == 1.5 and state["headerId"] == 1
    visualization = headers.stamp("visualization", visualization_body(t, vda))
    assert SCHEMAS.errors("visualization", visualization) == [] and visualization["velocity"]["vx"] == 0.3
    for kind in (ONLINE, CONNECTIONBROKEN):
        assert SCHEMAS.errors("connection", headers.stamp("connection", connection_body(kind))) == []
    factsheet = headers.stamp("factsheet", factsheet_body(vda, VelocityLimits(0.8, 2.0)))
    assert SCHEMAS.errors("factsheet", factsheet) == [], SCHEMAS.errors("factsheet", factsheet)
    assert factsheet["physicalParameters"]["speedMax"] == 0.8
    # the factsheet lists exactly what the vehicle carries out
    assert [a["actionType"] for a in factsheet["protocolFeatures"]["agvActions"]] == list(INSTANT_ACTIONS)


def test_the_robots_own_estop_reads_manual_before_a_remote_one() -> None:
    vda, vehicle = settings(), Vehicle(map_id="demo")
    assert state_body(vehicle, Telemetry(emergency_stop=True), vda)["safetyState"]["eStop"] == "REMOTE"
    both = Telemetry(emergency_stop=True, hardware_estop=True)
    assert state_body(vehicle, both, vda)["safetyState"] == {"eStop": "MANUAL", "fieldViolation": False}


def test_moving_is_measured_not_commanded() -> None:
    assert not Telemetry().moving and not Telemetry(velocity=(0.005, 0.0, -0.002)).moving
    assert Telemetry(velocity=(0.0, 0.0, 0.2)).moving
