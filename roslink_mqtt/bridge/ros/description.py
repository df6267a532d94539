"""The robot description the bridge publishes (retained ``state/description``): config + ROS type introspection.

:func:`build_description` is ROS-free: it reads the robot's part of the fleet file and asks a
``fields_of(type_name) -> layout`` callable for the field layout of each ROS type an entry mentions, so it is
unit-tested with a table (tests/unit/test_description_unit.py). :func:`ros_fields_of` is that callable on a robot:
it loads the interface classes (:func:`~roslink_mqtt.bridge.core.ros_types.load_interface`) and walks their
``SLOT_TYPES``, nested messages expanded, spelling types as a ``.msg`` file does (what ``ros2 interface show``
prints). :func:`description_message` gives the bridge the topic and the body to publish.

Who may use an entry is the one authorization rule's answer for a viewer (:func:`roslink_mqtt.authorize.allowed`): state
is for everyone granted the robot, commands for operators, services and actions for viewers where the fleet
file opens them (``read_only``, ``viewers: true``); parameters are read by everyone and set by operators, or by
viewers where ``viewers_may_set``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from dataclasses import asdict
from functools import cache
from typing import Any

from ...authorize import allowed
from ...config import Direction, Robot, Role
from ...config.interfaces import VELOCITY_TYPES
from ...config.model import ENCODING_JSON
from ...protocol.description import (
    DESCRIPTION,
    OPERATORS,
    VIEWERS,
    ActionEntry,
    CommandEntry,
    Layout,
    ParameterEntry,
    RobotDescription,
    ServiceEntry,
    StateEntry,
    VideoEntry,
)
from ...protocol.enums import RobotType
from ...ros_names import interface_name
from ...topics import TopicTree, Verb, join_leaf, state_name

log = logging.getLogger("roslink_mqtt.bridge")

ACK_STATE = "ack"  # the bridge's own state stream (acknowledgements, failsafe notices): in every description

FieldsOf = Callable[[str], Layout]


def _who(verb: Verb, *, read_only: bool = False) -> str:
    return VIEWERS if allowed(Role.VIEWER, verb, read_only=read_only) else OPERATORS


def build_description(robot: Robot, fields_of: FieldsOf, warnings: Mapping[str, str] | None = None
                      ) -> RobotDescription:
    """What ``robot`` maps, from its fleet-file entry; ``fields_of`` gives each mentioned ROS type's layout.

    ``warnings``: entry (``state/global_motion``, ``cmd/land``, ``call/reset``) → why it may send nothing or fail
    (its ROS topic has no publisher, its ROS service no server: bridge/core/graph_check.py), shown in the entry.

    A type ``fields_of`` cannot describe (it raises) is left out of ``types``, with a warning: the description
    is still published, since the rest of it is right.
    """
    warned = warnings or {}
    state: list[StateEntry] = []
    commands: list[CommandEntry] = []
    for rule in robot.rules:
        if rule.direction is Direction.ROS_TO_MQTT:
            encoding = None if rule.encoding == ENCODING_JSON else rule.encoding  # JSON goes without saying
            state.append(StateEntry(state_name(rule.mqtt_topic), rule.preset, rule.ros_type, rule.retain,
                                    rule.max_rate, dict(rule.fields), VIEWERS, encoding,
                                    warned.get(rule.mqtt_topic)))
        else:
            velocity = rule.ros_type in VELOCITY_TYPES
            limits = asdict(rule.limits or robot.bridge.limits) if velocity else {}
            commands.append(CommandEntry(rule.mqtt_topic, rule.preset, rule.ros_type, rule.on_demand,
                                         dict(rule.fields), limits, _who(Verb.CMD), warned.get(rule.mqtt_topic)))
    if all(s.name != ACK_STATE for s in state):
        state.append(StateEntry(ACK_STATE, ACK_STATE))
    services = [ServiceEntry(s.name, s.ros_type, s.read_only, s.timeout, _who(Verb.CALL, read_only=s.read_only),
                             warned.get(join_leaf(Verb.CALL, s.name))) for s in robot.services]
    actions = [ActionEntry(a.name, a.ros_type, a.viewers, a.timeout, a.feedback_rate,
                           _who(Verb.GOAL, read_only=a.viewers)) for a in robot.actions]
    parameters = [ParameterEntry(p.name, p.node, _who(Verb.PARAM, read_only=p.viewers_may_set), p.timeout,
                                 _who(Verb.PARAM, read_only=True)) for p in robot.parameters]
    types: dict[str, Layout] = {}
    entries: list[StateEntry | CommandEntry | ServiceEntry | ActionEntry] = [*state, *commands, *services, *actions]
    for ros_type in [e.ros_type for e in entries]:
        if ros_type is None or ros_type in types:
            continue
        try:
            types[ros_type] = fields_of(ros_type)
        except Exception as err:  # noqa: BLE001 - a type we cannot describe must not stop the description
            log.warning("description of %s: no field layout for %s: %s", robot.name, ros_type, err)
    kind = RobotType(robot.type).name.lower()
    return RobotDescription(robot.name, robot.system_id, kind, limits=asdict(robot.bridge.limits),
                            state=tuple(state), commands=tuple(commands), services=tuple(services),
                            actions=tuple(actions), types=types, parameters=tuple(parameters),
                            video=tuple(VideoEntry(v.name, v.ros_type, v.codec, v.fps, v.max_kbit_s)
                                        for v in robot.video))


def description_message(robot: Robot, topics: TopicTree, fields_of: FieldsOf | None = None,
                        warnings: Mapping[str, str] | None = None) -> tuple[str, bytes]:
    """(topic, body) of ``robot``'s retained description; ``fields_of`` defaults to ROS introspection."""
    body = build_description(robot, fields_of or ros_fields_of, warnings).to_json()
    return topics.state(robot.name, DESCRIPTION), body


# -- ROS introspection (needs the interface packages, not rclpy) ------------------------------------------------

_MSG_NAMES = {"double": "float64", "float": "float32", "boolean": "bool", "octet": "byte", "long double": "float128"}
_PARTS = {"Request": "request", "Response": "response"}
_ACTION_PARTS = {"Goal": "goal", "Result": "result", "Feedback": "feedback"}


@cache
def ros_fields_of(type_name: str) -> Layout:
    """The field layout of a ROS message, service or action type (UnknownTypeError if it is not installed)."""
    from ..core.ros_types import load_interface

    cls = load_interface(type_name)
    if hasattr(cls, "Goal") and hasattr(cls, "Feedback"):
        return {key: message_layout(getattr(cls, attr)) for attr, key in _ACTION_PARTS.items()}
    if hasattr(cls, "Request") and hasattr(cls, "Response"):
        return {key: message_layout(getattr(cls, attr)) for attr, key in _PARTS.items()}
    return message_layout(cls)


def message_layout(cls: type[Any]) -> Layout:
    """Field name → type of a message class, nested messages expanded (``{"type": …, "fields": …}``)."""
    names = list(cls.get_fields_and_field_types())
    return {name: _slot(slot) for name, slot in zip(names, cls.SLOT_TYPES, strict=True)}


def _slot(slot: Any) -> Any:
    """One field's type as a .msg file spells it; an object with the element's fields for nested messages."""
    from rosidl_parser import definition as d

    suffix, inner = "", slot
    if isinstance(slot, d.Array):
        suffix, inner = f"[{slot.size}]", slot.value_type
    elif isinstance(slot, d.BoundedSequence):
        suffix, inner = f"[<={slot.maximum_size}]", slot.value_type
    elif isinstance(slot, d.UnboundedSequence):
        suffix, inner = "[]", slot.value_type
    if isinstance(inner, d.NamespacedType):
        name = interface_name(inner.namespaces, inner.name)
        from ..core.ros_types import load_interface

        return {"type": name + suffix, "fields": message_layout(load_interface(name))}
    if isinstance(inner, d.BasicType):
        base = _MSG_NAMES.get(inner.typename, inner.typename)
    elif isinstance(inner, (d.BoundedString, d.BoundedWString)):
        base = f"{'w' if isinstance(inner, d.BoundedWString) else ''}string<={inner.maximum_size}"
    elif isinstance(inner, d.UnboundedWString):
        base = "wstring"
    elif isinstance(inner, d.UnboundedString):
        base = "string"
    else:
        base = type(inner).__name__
    return base + suffix
