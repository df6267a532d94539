"""Environment that keeps ROS 2 / DDS traffic on this machine.

Tests, the demo and benchmarks start real rclpy processes; without this they
would announce themselves on every network the machine is on and could talk
to a stranger's robot on the same domain. No rclpy import here: the parent
process only prepares the environment its children inherit.
"""

from __future__ import annotations

import os
import random
from importlib import resources

from .fastdds_shm import remove_zombie_segments


def fastdds_profile() -> str:
    """Path of the bundled Fast DDS profile that binds 127.0.0.1 only."""
    return str(resources.files("roslink_mqtt") / "data" / "fastdds_localhost.xml")


def local_ros_env(domain_id: int | None = None, base: dict[str, str] | None = None) -> dict[str, str]:
    """A copy of ``base`` (default ``os.environ``) with loopback-only DDS and a fresh domain id.

    A random domain (1..101, the range that is safe on every platform) per run
    keeps parallel runs and leftover processes from seeing each other.
    """
    env = dict(os.environ if base is None else base)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env.pop("ROS_LOCALHOST_ONLY", None)  # deprecated on Jazzy; RANGE above replaces it
    env["FASTRTPS_DEFAULT_PROFILES_FILE"] = fastdds_profile()
    env["RMW_IMPLEMENTATION"] = "rmw_fastrtps_cpp"
    env["ROS_DOMAIN_ID"] = str(domain_id if domain_id is not None else random.randint(1, 101))
    env.pop("ROS_STATIC_PEERS", None)
    return env


def apply_local_ros_env(domain_id: int | None = None) -> dict[str, str]:
    """Set the loopback-only ROS variables in this process (before importing rclpy).

    Also clears shared-memory files that killed DDS processes left behind, so
    this run cannot pick up their stale state (see :mod:`roslink_mqtt.fastdds_shm`).
    """
    remove_zombie_segments()
    env = local_ros_env(domain_id)
    for key in ("ROS_AUTOMATIC_DISCOVERY_RANGE", "FASTRTPS_DEFAULT_PROFILES_FILE",
                "RMW_IMPLEMENTATION", "ROS_DOMAIN_ID"):
        os.environ[key] = env[key]
    return env
