"""The ROS ↔ JSON converter round-trips every installed message and service type (property tests)."""

from __future__ import annotations

import importlib
import math
import pkgutil
import sys
from pathlib import Path

import orjson
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

pytest.importorskip("rclpy")

from rosidl_parser import definition as d  # noqa: E402

from roslink_mqtt.bridge.core.ros_types import load_interface  # noqa: E402
from roslink_mqtt.bridge.ros.convert import ConversionError, converter_for  # noqa: E402


def installed_types() -> list[str]:
    """Every msg/srv interface importable from site-packages (rosidl-generated packages)."""
    names: set[str] = set()
    for site in map(Path, sys.path):
        if not site.is_dir():
            continue
        for init in site.glob("*/msg/__init__.py"):
            names.update(_names(init.parent.parent.name, "msg", init))
        for init in site.glob("*/srv/__init__.py"):
            names.update(_names(init.parent.parent.name, "srv", init))
    return sorted(names)


def _names(package: str, kind: str, init: Path) -> set[str]:
    out = set()
    for line in init.read_text().splitlines():  # lines like: from pkg.msg._foo import Foo
        parts = line.split()
        if len(parts) >= 4 and parts[0] == "from" and parts[1].startswith(f"{package}.{kind}._") \
                and parts[2] == "import":
            out.add(f"{package}/{kind}/{parts[3]}")
    return out


TYPES = installed_types()
MESSAGE_TYPES = [t for t in TYPES if "/msg/" in t]
SERVICE_TYPES = [t for t in TYPES if "/srv/" in t and not t.endswith(("_Request", "_Response", "_Event"))]

_INTS = {"int8": 8, "uint8": 8, "int16": 16, "uint16": 16, "int32": 32, "uint32": 32, "int64": 64, "uint64": 64,
         "char": 8, "wchar": 16}


def _scalar(typename: str) -> st.SearchStrategy:
    if typename == "float":
        return st.floats(width=32, allow_nan=False) | st.sampled_from([math.inf, -math.inf])
    if typename in ("double", "long double"):
        return st.floats(allow_nan=False)
    if typename == "boolean":
        return st.booleans()
    if typename == "octet":
        return st.integers(0, 255)
    bits = _INTS[typename]
    if typename.startswith("u") or typename in ("char", "wchar"):
        return st.integers(0, 2**bits - 1)
    return st.integers(-(2 ** (bits - 1)), 2 ** (bits - 1) - 1)


def _text(limit):
    return st.text(alphabet=st.characters(codec="utf-8", exclude_categories=("Cs",), exclude_characters="\0"),
                   max_size=min(limit or 8, 8))


def strategy(cls: type, depth: int = 0) -> st.SearchStrategy:
    fields = {}
    for name, slot in zip(cls.get_fields_and_field_types(), cls.SLOT_TYPES, strict=True):
        fields[name] = _member(slot, depth)
    return st.fixed_dictionaries({}, optional=fields)


def _member(slot, depth: int) -> st.SearchStrategy:
    if isinstance(slot, d.BasicType):
        return _scalar(slot.typename)
    if isinstance(slot, d.AbstractGenericString):
        return _text(getattr(slot, "maximum_size", None))
    if isinstance(slot, d.NamespacedType):
        return strategy(load_interface("/".join(slot.namespaces) + "/" + slot.name), depth + 1)
    inner = slot.value_type
    if isinstance(inner, d.BasicType) and inner.typename in ("uint8", "octet"):
        size = slot.size if isinstance(slot, d.Array) else None
        bound = getattr(slot, "maximum_size", None) if isinstance(slot, d.BoundedSequence) else None
        return st.binary(min_size=size or 0, max_size=size or min(bound or 6, 6)).map(
            lambda b: __import__("base64").b64encode(b).decode())
    item = _member(inner, depth + 1)
    if isinstance(slot, d.Array):
        return st.lists(item, min_size=slot.size, max_size=slot.size)
    limit = getattr(slot, "maximum_size", None) if isinstance(slot, d.BoundedSequence) else None
    return st.lists(item, max_size=min(limit or 3, 3 if depth < 2 else 1))


def test_found_the_common_interfaces() -> None:
    for expected in ("std_msgs/msg/String", "geometry_msgs/msg/Twist", "sensor_msgs/msg/LaserScan",
                     "nav_msgs/msg/Odometry", "diagnostic_msgs/msg/DiagnosticArray", "std_srvs/srv/Trigger"):
        assert expected in TYPES
    assert len(MESSAGE_TYPES) > 100


def _round_trip_check(conv):
    @settings(max_examples=12, deadline=None, suppress_health_check=list(HealthCheck), database=None)
    @given(strategy(conv.ros_type))
    def check(data):
        msg = conv.from_dict(data)
        as_dict = conv.to_dict(msg)
        wire = conv.to_json(msg)
        # Both encodings carry the same values (to_json writes float32 in its shortest form).
        via_dict = conv.from_dict(orjson.loads(orjson.dumps(as_dict)))
        via_json = conv.from_dict(orjson.loads(wire))
        assert via_dict == msg and via_json == msg
    return check


@pytest.mark.parametrize("name", MESSAGE_TYPES + SERVICE_TYPES)
def test_round_trip(name: str) -> None:
    cls = load_interface(name)
    classes = [cls.Request, cls.Response] if "/srv/" in name else [cls]
    for c in classes:
        _round_trip_check(converter_for(c))()


@pytest.mark.parametrize(("data", "fragment"), [
    ({"linear": {"x": "fast"}}, 'linear.x: expected number, got "fast"'),
    ({"linear": {"q": 1}}, "linear.q: unknown field for Vector3"),
    ({"angular": 5}, "angular: expected an object, got 5"),
    ({"linear": {"x": True}}, "linear.x: expected number, got true"),
])
def test_twist_errors(data, fragment) -> None:
    from geometry_msgs.msg import Twist
    with pytest.raises(ConversionError, match=fragment.replace("(", r"\(").replace(")", r"\)")):
        converter_for(Twist).from_dict(data)


def test_other_errors() -> None:
    from sensor_msgs.msg import CompressedImage, Image
    from std_msgs.msg import UInt8
    with pytest.raises(ConversionError, match=r"data: expected integer 0..255, got 256"):
        converter_for(UInt8).from_dict({"data": 256})
    with pytest.raises(ConversionError, match=r"data: invalid base64"):
        converter_for(CompressedImage).from_dict({"data": "%%%"})
    with pytest.raises(ConversionError, match=r"header.stamp.nanosec: expected integer 0..4294967295, got -1"):
        converter_for(Image).from_dict({"header": {"stamp": {"nanosec": -1}}})
    from nav_msgs.msg import Odometry
    with pytest.raises(ConversionError, match=r"pose.covariance: expected exactly 36 items, got 2"):
        converter_for(Odometry).from_dict({"pose": {"covariance": [0.0, 1.0]}})


def test_float32_overflow_and_nul_refused() -> None:
    from sensor_msgs.msg import LaserScan
    from std_msgs.msg import String
    with pytest.raises(ConversionError, match="out of range for float32"):
        converter_for(LaserScan).from_dict({"range_max": 1e39})
    with pytest.raises(ConversionError, match="NUL"):
        converter_for(String).from_dict({"data": "a\x00b"})


def test_time_and_non_finite_conventions() -> None:
    from sensor_msgs.msg import LaserScan
    scan = LaserScan()
    scan.header.stamp.sec, scan.header.stamp.nanosec = 12, 34
    scan.ranges = [1.5, math.inf, math.nan, -math.inf]
    out = orjson.loads(converter_for(LaserScan).to_json(scan))
    assert out["header"]["stamp"] == {"sec": 12, "nanosec": 34}
    assert out["ranges"] == [1.5, "Infinity", "NaN", "-Infinity"]
    back = converter_for(LaserScan).from_dict(out)
    assert back.ranges[1] == math.inf and math.isnan(back.ranges[2])


def test_every_generated_module_imports() -> None:
    for name in ("std_msgs", "geometry_msgs"):
        mod = importlib.import_module(f"{name}.msg")
        assert list(pkgutil.iter_modules(mod.__path__))


@pytest.mark.parametrize(("type_name", "data", "fragment"), [
    ("nav_msgs/msg/Odometry", {"pose": {"covariance": [0.0] * 35 + ["x"]}}, 'pose.covariance[35]: expected number'),
    ("sensor_msgs/msg/LaserScan", {"ranges": [1.0, 1e39]}, "ranges[1]: 1e+39 is out of range for float32"),
    ("std_msgs/msg/Int8MultiArray", {"data": [1, 128]}, "data[1]: expected integer -128..127, got 128"),
    ("std_msgs/msg/Int8MultiArray", {"data": [1, True]}, "data[1]: expected integer, got true"),
    ("sensor_msgs/msg/JointState", {"name": ["a", 3]}, "name[1]: expected string, got 3"),
    ("nav_msgs/msg/Path", {"poses": [{}, {"pose": {"position": {"x": "far"}}}]},
     'poses[1].pose.position.x: expected number, got "far"'),
    ("std_msgs/msg/Bool", [True], "message: expected an object"),
])
def test_error_paths_through_arrays_and_nesting(type_name: str, data, fragment: str) -> None:
    with pytest.raises(ConversionError) as err:
        converter_for(load_interface(type_name)).from_dict(data)
    assert fragment in str(err.value)


def test_plain_arrays_take_the_fast_path_and_keep_their_values() -> None:
    from sensor_msgs.msg import LaserScan
    scan = converter_for(LaserScan).from_dict({"ranges": [0.5, 3.4e38], "intensities": [1, 2.5, "NaN"]})
    assert list(scan.ranges) == pytest.approx([0.5, 3.4e38], rel=1e-6)  # at the float32 edge: accepted
    assert list(scan.intensities)[:2] == [1.0, 2.5] and math.isnan(scan.intensities[2])  # mixed: the slow path
