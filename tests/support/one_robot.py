"""A fleet of one robot, ``r1``, with the given rules: for tests of rule parsing and compiling."""

from __future__ import annotations

from roslink_mqtt.config import Fleet, parse_fleet
from roslink_mqtt.config.passwords import hash_password

HASH = hash_password("pw", iterations=1)  # cheap: these fleets are never logged into


def one_robot_fleet(*rules: str) -> Fleet:
    """``rules``: each a YAML flow mapping, as robots.yaml spells a rule."""
    body = "".join(f"\n      - {r}" for r in rules)
    return parse_fleet(f"""
robots:
  r1:
    system_id: 1
    key: k1
    password: "{HASH}"
    rules:{body}
""", "robots.yaml")
