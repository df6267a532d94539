"""A fleet's grants for one robot as the broker sends them (protocol/grants.py), and back into a :class:`Fleet`.

The broker side (the embedded broker, ``roslink-mqtt fleet apply``) writes :func:`grants_of` for each robot; the
bridge reads the message and runs on :func:`with_grants`: its robot file with the users the message names, each
holding one grant on the robot. Only the role matters to a bridge, so an administrator arrives as an operator.
"""

from __future__ import annotations

import dataclasses

from ..protocol.grants import RobotGrants
from .model import Fleet, Grant, Role, User


def grants_of(fleet: Fleet, robot: str, *, issued: float, by: str) -> RobotGrants:
    """What the fleet file says about ``robot``'s users (admins included, as operators)."""
    return RobotGrants(robot, {user: role.value for user, role in sorted(fleet.users_of(robot).items())}, issued, by)


def with_grants(fleet: Fleet, grants: RobotGrants) -> Fleet:
    """``fleet`` (the bridge's robot file, or its fleet file) with the users of ``grants`` instead of its own."""
    robot = fleet.robots[grants.robot]
    users = {name: User(name, "", (Grant(robot.key, Role(role)),)) for name, role in sorted(grants.users.items())}
    return dataclasses.replace(fleet, users=users, grants_pending=False)
