"""Compile robots.yaml rules into ready-to-run handlers, once, at bridge start.

Everything that can be decided before the first message is decided here —
type classes loaded, preset checked against the type, converter built, topic
strings formatted — so the per-message path is a few calls. Any problem is a
:class:`RuleError` naming the rule, raised before the bridge connects.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import orjson
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from ... import ros_names
from ...config import Robot, RosQos, Rule
from ...config.model import ENCODING_CBOR, ENCODING_JSON, ENCODING_RAW, RAW_TYPES, Direction
from ...protocol import SPECS_BY_NAME, Envelope, encode
from ...protocol.validate import show_key
from ...topics import TopicTree, state_name
from ..core.presets import COMMAND_PRESETS, STATE_PRESETS
from ..core.ros_types import UnknownTypeError, load_interface
from ..core.routes import Inbound
from ..core.safety import VELOCITY_TYPES
from .convert import ConversionError, converter_for, raw_bytes


def ros_qos(q: RosQos, *, latched: bool = False) -> QoSProfile:
    """The rclpy QoS profile for a rule's ``ros_qos`` (``latched``: transient local, for e-stop)."""
    return QoSProfile(
        depth=q.depth,
        reliability=ReliabilityPolicy.BEST_EFFORT if q.reliability == "best_effort" else ReliabilityPolicy.RELIABLE,
        durability=(DurabilityPolicy.TRANSIENT_LOCAL if latched or q.durability == "transient_local"
                    else DurabilityPolicy.VOLATILE))


class RuleError(ValueError):
    """A rule that cannot run (unknown type, preset/type mismatch, …); names the rule."""

    def __init__(self, message: str, rule: Rule | None = None) -> None:
        super().__init__(message)
        self.rule = rule


@dataclass
class Outbound:
    """ros_to_mqtt: a ROS message becomes MQTT bytes on one topic."""

    rule: Rule
    ros_cls: type
    topic: str
    serialize: Callable[[Any], bytes]
    period: float  # 0 = no throttle


def _load(rule: Rule) -> type:
    try:
        return load_interface(rule.ros_type)
    except UnknownTypeError as err:
        raise RuleError(f"{rule.label}: {err}", rule) from None


def _preset(rule: Rule, presets: dict[str, Any], kind: str) -> Any:
    """The rule's preset, checked to exist in ``presets`` and to accept the rule's ROS type."""
    preset = presets.get(rule.preset) if rule.preset is not None else None
    if preset is None:
        raise RuleError(f"{rule.label}: preset '{rule.preset}' is not a {kind} preset "
                        f"({kind} presets: {', '.join(presets)})", rule)
    if rule.ros_type not in preset.ros_types:
        raise RuleError(f"{rule.label}: preset '{rule.preset}' needs ros_type "
                        f"{' or '.join(preset.ros_types)}, not {rule.ros_type}", rule)
    return preset


def _get_path(data: dict[str, Any], path: str) -> Any:
    for part in path.split("."):
        data = data[part]
    return data


def _set_path(data: dict[str, Any], path: str, value: Any) -> None:
    parts = path.split(".")
    for part in parts[:-1]:
        data = data.setdefault(part, {})
    data[parts[-1]] = value


def _is_nested_message(field_type: str) -> bool:
    """``pkg/Type`` is one nested message; ``sequence<pkg/Type>``, ``pkg/Type[3]`` and primitives are not."""
    return ros_names.nested_message(field_type) is not None


def _check_field_paths(rule: Rule, ros_cls: type) -> None:
    """Every ``fields`` target must exist in the ROS type, or the rule fails at start.

    A path may end at a sequence or array (it is carried as a list) but not go through one: there is no single
    element to follow. Every problem is a :class:`RuleError` naming the rule, never an ``UnknownTypeError`` from
    loading a field type, which ``main`` would not catch.
    """
    for mqtt_field, ros_path in rule.fields.items():
        cls: Any = ros_cls
        parts = ros_path.split(".")
        for i, part in enumerate(parts):
            fields = cls.get_fields_and_field_types() if hasattr(cls, "get_fields_and_field_types") else {}
            if part not in fields:
                raise RuleError(f"{rule.label}: fields.{mqtt_field}: '{ros_path}' is not a field of {rule.ros_type}",
                                rule)
            if i == len(parts) - 1:
                break
            sub = fields[part]
            if not _is_nested_message(sub):
                if sub.startswith("sequence<") or sub.endswith("]"):
                    raise RuleError(f"{rule.label}: fields.{mqtt_field}: '{ros_path}' goes through '{part}', a {sub} "
                                    f"of {rule.ros_type} (a fields path ends at a sequence or array; it cannot reach "
                                    "inside one)", rule)
                raise RuleError(f"{rule.label}: fields.{mqtt_field}: '{ros_path}' is not a field of {rule.ros_type}",
                                rule)
            try:
                cls = load_interface(ros_names.nested_message(sub) or sub)
            except UnknownTypeError as err:
                raise RuleError(f"{rule.label}: fields.{mqtt_field}: {err}", rule) from None


def _check_encoding(rule: Rule) -> None:
    """What the loader checks, again (a Rule may be built in code): where each encoding makes sense."""
    if rule.encoding == ENCODING_JSON:
        return
    if rule.encoding not in (ENCODING_CBOR, ENCODING_RAW):
        raise RuleError(f"{rule.label}: unknown encoding '{rule.encoding}' (json, cbor or raw)", rule)
    if rule.preset is not None:
        raise RuleError(f"{rule.label}: encoding '{rule.encoding}' is for generic rules; preset '{rule.preset}' "
                        "publishes a ROSLink message, which is always JSON", rule)
    if rule.encoding == ENCODING_RAW and (rule.ros_type not in RAW_TYPES or rule.fields):
        raise RuleError(f"{rule.label}: encoding 'raw' needs ros_type {' or '.join(RAW_TYPES)} and no fields, "
                        f"not {rule.ros_type}", rule)
    if rule.encoding == ENCODING_CBOR:
        try:
            import cbor2  # noqa: F401 - only checked for here
        except ImportError:
            raise RuleError(f"{rule.label}: encoding 'cbor' needs the cbor2 package "
                            "(pip install 'roslink-mqtt[bridge]')", rule) from None


def compile_outbound(rule: Rule, robot: Robot, topics: TopicTree) -> Outbound:
    ros_cls = _load(rule)
    topic = topics.state(robot.name, state_name(rule.mqtt_topic))
    period = 1.0 / rule.max_rate if rule.max_rate else 0.0
    _check_encoding(rule)
    if rule.preset is not None:
        preset = _preset(rule, STATE_PRESETS, "state")
        message_id, system_id, convert = SPECS_BY_NAME[rule.preset].message_id, robot.system_id, preset.convert
        sequence = 0

        def serialize_preset(msg: Any) -> bytes:
            nonlocal sequence
            sequence = (sequence + 1) & 0xFFFFFFFF
            return encode(Envelope(message_id, convert(msg), system_id, sequence))

        return Outbound(rule, ros_cls, topic, serialize_preset, period)
    if rule.encoding == ENCODING_RAW:  # the image file itself (JPEG, PNG): docs/protocol.md, "State encodings"
        return Outbound(rule, ros_cls, topic, lambda msg: raw_bytes(msg.data), period)
    converter = converter_for(ros_cls)
    cbor = rule.encoding == ENCODING_CBOR
    if rule.fields:
        _check_field_paths(rule, ros_cls)
        selected = tuple(rule.fields.items())
        if cbor:
            from .convert import cbor_dumps

            to_obj = converter.to_cbor_obj

            def serialize_fields_cbor(msg: Any) -> bytes:
                d = to_obj(msg)
                return cbor_dumps({k: _get_path(d, path) for k, path in selected})

            return Outbound(rule, ros_cls, topic, serialize_fields_cbor, period)
        to_dict = converter.to_dict

        def serialize_fields(msg: Any) -> bytes:
            d = to_dict(msg)
            return orjson.dumps({k: _get_path(d, path) for k, path in selected})

        return Outbound(rule, ros_cls, topic, serialize_fields, period)
    return Outbound(rule, ros_cls, topic, converter.to_cbor if cbor else converter.to_json, period)


SERVICE_TARGETS = ("std_srvs/srv/Trigger", "std_srvs/srv/SetBool", "std_srvs/srv/Empty")


def _service_target(rule: Rule, ros_cls: type[Any], robot: Robot) -> Inbound:
    """A command preset that calls a std_srvs service; SetBool carries False for disarm, True otherwise."""
    if rule.ros_type not in SERVICE_TARGETS:
        raise RuleError(f"{rule.label}: preset '{rule.preset}' can call {' or '.join(SERVICE_TARGETS)}, "
                        f"not {rule.ros_type}", rule)
    assert rule.preset is not None  # the fleet file takes a srv ros_type only with a service preset (config.loader)
    value = rule.preset != "disarm"

    def build(_payload: Any) -> Any:
        request = ros_cls.Request()
        if hasattr(request, "data"):
            request.data = value
        return request

    return Inbound(rule, ros_cls, SPECS_BY_NAME[rule.preset], build, False, robot.bridge.limits, is_service=True)


def compile_inbound(rule: Rule, robot: Robot) -> Inbound:
    ros_cls = _load(rule)
    if ros_names.is_interface(rule.ros_type, "srv"):
        return _service_target(rule, ros_cls, robot)
    limits = rule.limits or robot.bridge.limits
    is_velocity = rule.ros_type in VELOCITY_TYPES
    if rule.on_demand and is_velocity:
        raise RuleError(f"{rule.label}: on_demand is not for velocity commands (the failsafe must always be able "
                        f"to publish zero velocity on {rule.ros_topic})", rule)
    if rule.preset is not None:
        preset = _preset(rule, COMMAND_PRESETS, "command")
        build = preset.build
        return Inbound(rule, ros_cls, SPECS_BY_NAME[rule.preset], lambda p: build(p, ros_cls), is_velocity, limits)
    from_dict = converter_for(ros_cls).from_dict
    if rule.fields:
        _check_field_paths(rule, ros_cls)
        mapping = tuple(rule.fields.items())

        def build_fields(data: Any) -> Any:
            if not isinstance(data, dict):
                raise ConversionError("expected a JSON object")
            unknown = sorted(set(data) - set(rule.fields))
            if unknown:
                raise ConversionError(f"unknown field '{show_key(unknown[0])}' (fields: {', '.join(rule.fields)})")
            nested: dict[str, Any] = {}
            for mqtt_field, path in mapping:
                if mqtt_field in data:
                    _set_path(nested, path, data[mqtt_field])
            return from_dict(nested)

        return Inbound(rule, ros_cls, None, build_fields, is_velocity, limits)
    return Inbound(rule, ros_cls, None, from_dict, is_velocity, limits)


def compile_rules(robot: Robot, topics: TopicTree) -> tuple[list[Outbound], dict[str, Inbound]]:
    """All of a robot's rules; inbound keyed by the leaf under ``from/<user>/`` (e.g. ``cmd/twist``)."""
    outbound: list[Outbound] = []
    inbound: dict[str, Inbound] = {}
    for rule in robot.rules:
        if rule.direction is Direction.ROS_TO_MQTT:
            outbound.append(compile_outbound(rule, robot, topics))
        else:
            inbound[rule.mqtt_topic] = compile_inbound(rule, robot)
    return outbound, inbound
