"""Remove Fast DDS shared-memory files left behind by processes that died.

With ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` the Jazzy RMW adds Fast DDS's
shared-memory transport to every participant, whatever the XML profile says.
Its segments live in /dev/shm as ``fastrtps_*`` files, each with a ``*_el``
companion that the owning process holds an exclusive flock on. A process that
is killed (the fault-injection tests do that on purpose; a stopped session does
it to everything) leaves both files behind; a later run on the same machine
would map that stale state again. A companion nobody holds a lock on marks a
zombie: the same rule as ``fastdds shm clean``.
"""

from __future__ import annotations

import fcntl
import os
import time
from pathlib import Path

SHM_DIR = Path("/dev/shm")
LOCK_SUFFIX = "_el"


def _unlocked(lock_file: Path) -> bool:
    """True when no living process holds the companion's lock (we can take it ourselves)."""
    try:
        fd = os.open(lock_file, os.O_RDWR)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        return False
    else:
        fcntl.flock(fd, fcntl.LOCK_UN)
        return True
    finally:
        os.close(fd)


# Between creating a segment's companion and locking it, a starting process's pair looks like a zombie; removing it
# then would leave that process on a file nobody else can open (its DDS data lost while discovery, over UDP, still
# works: what a test of two parallel workers once showed, a probe that got no /cmd_vel at all). Not proven from
# Fast DDS's source, but cheap to rule out: young pairs are never judged, a real zombie is removed a little later.
MIN_ZOMBIE_AGE = 5.0  # s since the companion was created


def remove_zombie_segments(shm_dir: Path = SHM_DIR, min_age: float = MIN_ZOMBIE_AGE) -> list[str]:
    """Delete every ``fastrtps_*`` segment whose owner is gone (and whose companion is at least ``min_age`` s
    old); return the names removed."""
    removed: list[str] = []
    if not shm_dir.is_dir():
        return removed
    now = time.time()
    for lock_file in sorted(shm_dir.glob(f"fastrtps_*{LOCK_SUFFIX}")):
        try:
            young = now - lock_file.stat().st_mtime < min_age
        except FileNotFoundError:
            continue
        if young or not _unlocked(lock_file):
            continue
        segment = lock_file.with_name(lock_file.name[: -len(LOCK_SUFFIX)])
        for path in (segment, lock_file):
            try:
                path.unlink()
                removed.append(path.name)
            except FileNotFoundError:
                pass
    return removed


PORT_PREFIX = "fastrtps_port"


def live_port_segments(shm_dir: Path = SHM_DIR) -> set[int]:
    """The shared-memory ports that a living Fast DDS process holds (its ``fastrtps_port<N>_el`` is locked).

    The port numbers follow the RTPS domain mapping, so they say which ROS domains are in use
    on this machine -- from any network namespace, unlike the UDP ports.
    """
    ports: set[int] = set()
    if not shm_dir.is_dir():
        return ports
    for lock_file in shm_dir.glob(f"{PORT_PREFIX}*{LOCK_SUFFIX}"):
        number = lock_file.name[len(PORT_PREFIX):-len(LOCK_SUFFIX)]
        if number.isdigit() and not _unlocked(lock_file):
            ports.add(int(number))
    return ports
