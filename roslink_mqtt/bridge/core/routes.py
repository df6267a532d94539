"""A compiled mqtt_to_ros rule: what the command endpoint needs to know about one input, ROS-free.

:mod:`.rules` builds these from the fleet file (loading ROS types, choosing converters);
:mod:`.endpoint` reads them without importing ROS, so its unit tests build routes by hand.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from ...config import Rule, VelocityLimits
from ...protocol import MessageSpec
from .presets.command import COMMAND_PRESETS, ORDINARY, CommandBehaviour


@dataclass(frozen=True)
class Inbound:
    """mqtt_to_ros: a payload from a user becomes a ROS message on one topic (or a call of a ROS service)."""

    rule: Rule
    ros_cls: type
    spec: MessageSpec | None  # the ROSLink message for preset rules; None for generic JSON
    build: Callable[[Any], Any]  # validated payload (preset) or parsed JSON (generic) -> ROS message
    is_velocity: bool
    limits: VelocityLimits
    is_service: bool = False  # the preset calls a ROS service (ros_cls is the srv type) instead of publishing
    behaviour: CommandBehaviour = field(init=False)

    def __post_init__(self) -> None:
        preset = COMMAND_PRESETS.get(self.spec.name) if self.spec is not None else None
        object.__setattr__(self, "behaviour", preset.behaviour if preset is not None else ORDINARY)

    @property
    def name(self) -> str:
        """The leaf under ``from/<user>/`` this rule reads (``cmd/twist``, ``lights``)."""
        return self.rule.mqtt_topic

    @property
    def moves_robot(self) -> bool:
        """Velocity (by ROS type) or an autonomous goal (by preset)."""
        return self.is_velocity or self.behaviour.moves_robot
