"""Benchmark: ROS message ↔ JSON bytes, per-type converters vs a naive recursive walk.

    .venv/bin/python bench/convert.py [--iterations 10000]

Goals (issue 4): ≤ 15 µs nav_msgs/Odometry → JSON, ≤ 40 µs 720-beam LaserScan → JSON.
The baseline is what a bridge without per-type converters does: walk
get_fields_and_field_types() on every message.
"""

from __future__ import annotations

import argparse
import array
import base64
import math
import statistics
import time

import orjson
from geometry_msgs.msg import Twist
from nav_msgs.msg import Odometry
from sensor_msgs.msg import LaserScan

from roslink_mqtt.bridge.ros.convert import converter_for


def naive_to_dict(msg):
    """Baseline: generic recursive walk, introspecting the type on every call."""
    out = {}
    for name in msg.get_fields_and_field_types():
        value = getattr(msg, name)
        if hasattr(value, "get_fields_and_field_types"):
            out[name] = naive_to_dict(value)
        elif isinstance(value, (bytes, bytearray)):
            out[name] = base64.b64encode(value).decode()
        elif isinstance(value, (list, tuple, array.array)) or hasattr(value, "tolist"):
            value = value.tolist() if hasattr(value, "tolist") else value
            out[name] = [naive_to_dict(v) if hasattr(v, "get_fields_and_field_types")
                         else (v if not isinstance(v, float) or math.isfinite(v) else str(v)) for v in value]
        elif isinstance(value, float) and not math.isfinite(value):
            out[name] = str(value)
        else:
            out[name] = value
    return out


def naive_from_dict(cls, data):
    msg = cls()
    fields = cls.get_fields_and_field_types()
    for name, value in data.items():
        if name not in fields:
            raise ValueError(name)
        current = getattr(msg, name)
        if hasattr(current, "get_fields_and_field_types"):
            setattr(msg, name, naive_from_dict(type(current), value))
        else:
            setattr(msg, name, value)
    return msg


def sample_odometry() -> Odometry:
    m = Odometry()
    m.header.frame_id, m.child_frame_id = "odom", "base_link"
    m.header.stamp.sec, m.header.stamp.nanosec = 1_700_000_000, 123_456_789
    m.pose.pose.position.x, m.pose.pose.position.y = 1.234, -5.678
    m.pose.pose.orientation.z, m.pose.pose.orientation.w = 0.3826834, 0.9238795
    m.twist.twist.linear.x, m.twist.twist.angular.z = 0.4, 0.2
    m.pose.covariance = [0.01 * i for i in range(36)]
    return m


def sample_scan(beams: int = 720) -> LaserScan:
    m = LaserScan()
    m.header.frame_id = "base_link"
    m.angle_min, m.angle_max, m.angle_increment = -math.pi, math.pi, 2 * math.pi / beams
    m.range_min, m.range_max = 0.1, 12.0
    m.ranges = [1.0 + 4.0 * abs(math.sin(i / 50)) for i in range(beams)]
    m.intensities = [100.0 + (i % 7) for i in range(beams)]
    return m


def measure(fn, iterations: int, repeats: int = 5) -> float:
    """Best mean over ``repeats`` runs, in µs per call (best = least disturbed by the machine)."""
    fn()
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter_ns()
        for _ in range(iterations):
            fn()
        best = min(best, (time.perf_counter_ns() - t0) / iterations / 1000)
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--iterations", type=int, default=10000)
    args = parser.parse_args()
    n = args.iterations
    odom, scan, twist = sample_odometry(), sample_scan(), Twist()
    twist.linear.x, twist.angular.z = 0.2, 0.5
    c_odom, c_scan, c_twist = converter_for(Odometry), converter_for(LaserScan), converter_for(Twist)
    odom_json, twist_json = c_odom.to_json(odom), c_twist.to_json(twist)
    rows = [
        ("nav_msgs/Odometry → JSON bytes", lambda: orjson.dumps(naive_to_dict(odom)),
         lambda: c_odom.to_json(odom), 15.0),
        ("sensor_msgs/LaserScan 720 beams → JSON bytes", lambda: orjson.dumps(naive_to_dict(scan)),
         lambda: c_scan.to_json(scan), 40.0),
        ("JSON bytes → geometry_msgs/Twist", lambda: naive_from_dict(Twist, orjson.loads(twist_json)),
         lambda: c_twist.from_dict(orjson.loads(twist_json)), None),
        ("JSON bytes → nav_msgs/Odometry (checked)", lambda: naive_from_dict(Odometry, orjson.loads(odom_json)),
         lambda: c_odom.from_dict(orjson.loads(odom_json)), None),
    ]
    print(f"{'conversion':<46} {'naive µs':>9} {'roslink µs':>11} {'speed-up':>9} {'goal':>8}")
    print("-" * 87)
    results = []
    for label, naive, fast, goal in rows:
        base, ours = measure(naive, n), measure(fast, n)
        results.append(ours)
        verdict = "" if goal is None else (f"≤{goal:g} ✓" if ours <= goal else f"≤{goal:g} ✗")
        print(f"{label:<46} {base:>9.2f} {ours:>11.2f} {base / ours:>8.1f}× {verdict:>8}")
    print(f"\nJSON sizes: Odometry {len(odom_json)} B, LaserScan {len(c_scan.to_json(scan))} B; "
          f"median of our times {statistics.median(results):.2f} µs")


if __name__ == "__main__":
    main()
