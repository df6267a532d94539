"""Environment that keeps ROS 2 / DDS traffic on this machine.

Tests, the demo and benchmarks start real rclpy processes; without this they
would announce themselves on every network the machine is on and could talk
to a stranger's robot on the same domain. No rclpy import here: the parent
process only prepares the environment its children inherit.
"""

from __future__ import annotations

import os
import random
from collections.abc import Iterable
from importlib import resources
from pathlib import Path

from .fastdds_shm import SHM_DIR, live_port_segments, remove_zombie_segments

# The RTPS well-known port mapping every DDS vendor uses: domain d owns the ports PB + DG*d ... PB + DG*(d+1) - 1.
RTPS_PORT_BASE = 7400
RTPS_DOMAIN_GAIN = 250
SAFE_DOMAINS = range(1, 102)  # 1..101: valid on every platform (higher ids collide with ephemeral ports on Linux)
_PROC_UDP = (Path("/proc/net/udp"), Path("/proc/net/udp6"))


def fastdds_profile() -> str:
    """Path of the bundled Fast DDS profile that binds 127.0.0.1 only."""
    return str(resources.files("roslink_mqtt") / "data" / "fastdds_localhost.xml")


def bound_udp_ports(tables: Iterable[Path] = _PROC_UDP) -> set[int]:
    """The local UDP ports bound in this network namespace (from the kernel's /proc tables)."""
    ports: set[int] = set()
    for table in tables:
        try:
            lines = table.read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            fields = line.split()
            if len(fields) > 1 and ":" in fields[1]:
                ports.add(int(fields[1].rsplit(":", 1)[1], 16))
    return ports


def domain_of_port(port: int) -> int | None:
    """The ROS domain whose RTPS port range holds ``port``, or None below the first domain."""
    return (port - RTPS_PORT_BASE) // RTPS_DOMAIN_GAIN if port >= RTPS_PORT_BASE else None


def domains_in_use(shm_dir: Path = SHM_DIR, udp_tables: Iterable[Path] = _PROC_UDP) -> set[int]:
    """ROS domains some DDS participant on this machine uses right now.

    A participant binds UDP ports in its domain's range (seen here for this network namespace)
    and, with Fast DDS's shared-memory transport, holds a lock on a ``fastrtps_port<N>_el``
    file (seen from every namespace). Either marks the domain as taken: a second graph on it
    would see ours -- another demo's robot moving under our commands, or a crash.
    """
    ports = bound_udp_ports(udp_tables) | live_port_segments(shm_dir)
    return {d for p in ports if (d := domain_of_port(p)) is not None}


def unused_domain_ids(count: int, rng: random.Random | None = None, *, in_use: set[int] | None = None) -> list[int]:
    """``count`` different domain ids in 1..101 that no DDS participant on this machine uses, picked at once:
    processes that start together (a test run's parallel workers) each take one, and none can pick what another
    picked a moment before it bound a port."""
    taken = domains_in_use() if in_use is None else in_use
    free = [d for d in SAFE_DOMAINS if d not in taken]
    if not free:
        raise RuntimeError(f"every ROS domain id {SAFE_DOMAINS.start}..{SAFE_DOMAINS.stop - 1} is in use on this "
                           "machine: stop some ROS processes (ros2 daemon stop, leftover demos)")
    if len(free) < count:
        raise RuntimeError(f"{count} ROS domain ids are needed and only {len(free)} of {SAFE_DOMAINS.start}.."
                           f"{SAFE_DOMAINS.stop - 1} are unused on this machine: stop some ROS processes")
    return (rng or random).sample(free, count)


def unused_domain_id(rng: random.Random | None = None, *, in_use: set[int] | None = None) -> int:
    """A random ROS domain id in 1..101 that no DDS participant on this machine uses."""
    return unused_domain_ids(1, rng, in_use=in_use)[0]


def local_ros_env(domain_id: int | None = None, base: dict[str, str] | None = None) -> dict[str, str]:
    """A copy of ``base`` (default ``os.environ``) with loopback-only DDS and a fresh domain id.

    A random domain that no ROS process on this machine uses right now (see
    :func:`unused_domain_id`) keeps parallel runs and leftover processes from seeing each other.
    """
    env = dict(os.environ if base is None else base)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env.pop("ROS_LOCALHOST_ONLY", None)  # deprecated on Jazzy; RANGE above replaces it
    env["FASTRTPS_DEFAULT_PROFILES_FILE"] = fastdds_profile()
    env["RMW_IMPLEMENTATION"] = "rmw_fastrtps_cpp"
    env["ROS_DOMAIN_ID"] = str(domain_id if domain_id is not None else unused_domain_id())
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
