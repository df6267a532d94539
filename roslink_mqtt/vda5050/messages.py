"""The bodies of what the vehicle publishes: ``state``, ``visualization``, ``connection`` and ``factsheet``
(VDA 5050 2.1.0 §6.10, §6.13–6.15), from the vehicle's order state, what the robot measures and robots.yaml.

Headers are :class:`~roslink_mqtt.vda5050.wire.Headers`'; the ROS adapter fills :class:`Telemetry`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from ..config.model import Vda5050Settings, VelocityLimits
from .vehicle import INSTANT_ACTIONS, Vehicle

ONLINE, OFFLINE, CONNECTIONBROKEN = "ONLINE", "OFFLINE", "CONNECTIONBROKEN"
MOVING = 0.01  # m/s or rad/s: below this the robot stands (odometry noise is not driving)


@dataclass(slots=True)
class Telemetry:
    """What the robot measured last (None: nothing yet)."""

    pose: tuple[float, float, float] | None = None  # x, y (m), theta (rad) in the map's frame
    velocity: tuple[float, float, float] | None = None  # vx, vy (m/s), omega (rad/s) in the vehicle's frame
    battery: tuple[float, bool, float | None] | None = None  # charge (%), charging, voltage (V)
    emergency_stop: bool = False  # a ROSLink emergency stop holds the robot (any granted user may press it)
    hardware_estop: bool = False  # the robot's own e-stop (robots.yaml vda5050.estop) is pressed

    @property
    def moving(self) -> bool:
        return self.velocity is not None and any(abs(v) >= MOVING for v in self.velocity)


def _position(t: Telemetry, settings: Vda5050Settings) -> dict[str, Any] | None:
    if t.pose is None:
        return None
    x, y, theta = t.pose
    theta = math.atan2(math.sin(theta), math.cos(theta))  # [-π, π], as the schema asks
    return {"x": x, "y": y, "theta": theta, "mapId": settings.map_id, "positionInitialized": True}


def _velocity(t: Telemetry) -> dict[str, Any] | None:
    if t.velocity is None:
        return None
    vx, vy, omega = t.velocity
    return {"vx": vx, "vy": vy, "omega": omega}


def state_body(vehicle: Vehicle, t: Telemetry, settings: Vda5050Settings) -> dict[str, Any]:
    """``state`` without its header: the order's part from ``vehicle``, the rest measured."""
    body = vehicle.state()
    if t.battery is None:
        battery: dict[str, Any] = {"batteryCharge": 0.0, "charging": False}
        body["information"] = [{"infoType": "batteryUnknown", "infoLevel": "INFO",
                                "infoDescription": f"nothing received on {settings.battery} yet"}]
    else:
        charge, charging, voltage = t.battery
        battery = {"batteryCharge": charge, "charging": charging}
        if voltage is not None:
            battery["batteryVoltage"] = voltage
    body.update(batteryState=battery, operatingMode="AUTOMATIC",
                safetyState={"eStop": "MANUAL" if t.hardware_estop else "REMOTE" if t.emergency_stop else "NONE",
                             "fieldViolation": False})
    if (position := _position(t, settings)) is not None:
        body["agvPosition"] = position
    if (velocity := _velocity(t)) is not None:
        body["velocity"] = velocity
    return body


def visualization_body(t: Telemetry, settings: Vda5050Settings) -> dict[str, Any]:
    body: dict[str, Any] = {}
    if (position := _position(t, settings)) is not None:
        body["agvPosition"] = position
    if (velocity := _velocity(t)) is not None:
        body["velocity"] = velocity
    return body


def connection_body(state: str) -> dict[str, Any]:
    return {"connectionState": state}


def factsheet_body(settings: Vda5050Settings, limits: VelocityLimits) -> dict[str, Any]:
    """What the vehicle is and supports: exactly the instant actions :class:`Vehicle` carries out, no node or edge
    actions, no optional order fields it would ignore (docs/vda5050.md)."""
    return {
        "typeSpecification": {"seriesName": settings.series_name, "agvKinematic": settings.kinematic,
                              "agvClass": settings.vehicle_class, "maxLoadMass": 0.0,
                              "localizationTypes": ["NATURAL"], "navigationTypes": ["AUTONOMOUS"]},
        "physicalParameters": {"speedMin": 0.0, "speedMax": limits.linear, "angularSpeedMin": 0.0,
                               "angularSpeedMax": limits.angular, "accelerationMax": settings.acceleration,
                               "decelerationMax": settings.acceleration, "heightMin": settings.height,
                               "heightMax": settings.height, "width": settings.width, "length": settings.length},
        "protocolLimits": {"maxStringLens": {}, "maxArrayLens": {},
                           "timing": {"minOrderInterval": 0.0, "minStateInterval": 0.0,
                                      "defaultStateInterval": settings.state_interval,
                                      **({"visualizationInterval": settings.visualization_interval}
                                         if settings.visualization_interval else {})}},
        "protocolFeatures": {
            # a position for every node (the robot drives to positions); the rest it honours when given
            "optionalParameters": [
                {"parameter": "order.nodes.nodePosition", "support": "REQUIRED"},
                {"parameter": "order.nodes.nodePosition.allowedDeviationXY", "support": "SUPPORTED"},
                {"parameter": "order.nodes.nodePosition.theta", "support": "SUPPORTED"},
                {"parameter": "order.zoneSetId", "support": "SUPPORTED"},
            ],
            "agvActions": [{"actionType": name, "actionScopes": ["INSTANT"]} for name in INSTANT_ACTIONS] + [
                {"actionType": c.action_type, "actionScopes": ["INSTANT"],
                 "actionDescription": f"calls the robot's ROS service {c.service}"} for c in settings.actions],
        },
        "agvGeometry": {},
        "loadSpecification": {},
    }
