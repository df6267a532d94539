"""Zombie Fast DDS shared-memory files are removed; files of living processes are kept."""

from __future__ import annotations

import fcntl
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from roslink_mqtt.fastdds_shm import SHM_DIR, live_port_segments, remove_zombie_segments
from roslink_mqtt.ros_env import domain_of_port, domains_in_use, unused_domain_id
from tests.support.waits import wait_until


def _segment(dir_: Path, name: str) -> tuple[Path, Path]:
    seg, lock = dir_ / name, dir_ / f"{name}_el"
    seg.write_bytes(b"\0" * 64)
    lock.write_bytes(b"")
    return seg, lock


def test_only_unlocked_segments_go(tmp_path: Path) -> None:
    live_seg, live_lock = _segment(tmp_path, "fastrtps_port7000")
    dead_seg, dead_lock = _segment(tmp_path, "fastrtps_port7001")
    lonely = tmp_path / "fastrtps_0123456789abcdef"  # no companion: not ours to judge
    lonely.write_bytes(b"x")
    other = tmp_path / "someone_else_el"
    other.write_bytes(b"")
    holder = os.open(live_lock, os.O_RDWR)  # a separate open file: flock conflicts as with another process
    try:
        fcntl.flock(holder, fcntl.LOCK_EX)
        removed = remove_zombie_segments(tmp_path, min_age=0)
    finally:
        os.close(holder)
    assert sorted(removed) == ["fastrtps_port7001", "fastrtps_port7001_el"]
    assert live_seg.exists() and live_lock.exists() and lonely.exists() and other.exists()
    assert not dead_seg.exists() and not dead_lock.exists()


def test_a_pair_just_created_is_not_yet_judged(tmp_path: Path) -> None:
    """A starting process locks its companion a moment after creating it: another process cleaning up at that
    moment (two test workers, the sim's start) must not take its segment away."""
    seg, lock = _segment(tmp_path, "fastrtps_port7002")
    assert remove_zombie_segments(tmp_path) == [] and seg.exists() and lock.exists()
    old = time.time() - 60
    os.utime(lock, (old, old))
    assert sorted(remove_zombie_segments(tmp_path)) == ["fastrtps_port7002", "fastrtps_port7002_el"]


def test_missing_directory_is_nothing_to_do(tmp_path: Path) -> None:
    assert remove_zombie_segments(tmp_path / "absent") == []


ROS_SLEEPER = ("import rclpy, time; rclpy.init(); node = rclpy.create_node('shm_probe'); "
               "print('up', flush=True); time.sleep(60)")


def _mapped_fastdds_files(pid: int) -> set[str]:
    maps = Path(f"/proc/{pid}/maps").read_text()
    return {Path(line.split()[-1]).name for line in maps.splitlines() if f"{SHM_DIR}/fastrtps_" in line}


def _start_ros_sleeper(domain_id: int) -> subprocess.Popen:
    env = {**os.environ, "ROS_DOMAIN_ID": str(domain_id)}
    proc = subprocess.Popen([sys.executable, "-c", ROS_SLEEPER], stdout=subprocess.PIPE, text=True, env=env)
    assert proc.stdout is not None and proc.stdout.readline().strip() == "up"
    return proc


def test_a_killed_ros_process_leaves_zombies_that_are_removed() -> None:
    """Real rclpy processes (LOCALHOST range, so Jazzy's RMW adds the SHM transport).

    Different domains: a living peer of the same domain may clean the dead one's
    files itself, and then this test could not tell whether ours did. The killed one's domain is
    nobody's: not in use now and not another test worker's. It used to be the next domain up, which
    can be the other worker's: once, two of the killed process's segments stayed locked (the most
    likely reading: that worker's ROS processes, of the same domain, had them open).
    """
    domain = int(os.environ["ROS_DOMAIN_ID"])
    workers = {int(d) for d in os.environ.get("ROSLINK_TEST_DOMAINS", "").split(",") if d}
    killed_domain = unused_domain_id(in_use=domains_in_use() | workers | {domain})
    living, killed = _start_ros_sleeper(domain), _start_ros_sleeper(killed_domain)
    try:
        wait_until("Fast DDS shared-memory segments mapped by both processes",
                   lambda: _mapped_fastdds_files(living.pid) and _mapped_fastdds_files(killed.pid),
                   timeout=10, period=0.1)
        living_files, killed_files = _mapped_fastdds_files(living.pid), _mapped_fastdds_files(killed.pid)
        killed.send_signal(signal.SIGKILL)
        killed.wait(5)
        assert all((SHM_DIR / name).exists() for name in killed_files)  # SIGKILL leaves them behind
        removed = set(remove_zombie_segments(min_age=0))
        # every zombie is gone: removed here, or just before by the same cleanup in another process (a sim that
        # starts in the other test worker clears zombies older than MIN_ZOMBIE_AGE)
        assert not [name for name in killed_files if (SHM_DIR / name).exists()], killed_files - removed
        assert removed & killed_files
        assert not living_files & removed
        assert all((SHM_DIR / name).exists() for name in living_files)
    finally:
        for proc in (living, killed):
            proc.kill()
            proc.wait()


def test_a_domain_a_ros_process_uses_is_never_handed_out() -> None:
    """The demo and the suite pick their ROS_DOMAIN_ID among the unused ones: a real rclpy process's domain is seen
    as taken (its UDP ports and its locked shared-memory port file), and every later pick avoids it."""
    domain = unused_domain_id()
    sleeper = _start_ros_sleeper(domain)
    try:
        wait_until(f"domain {domain} of a living rclpy process seen as in use", lambda: domain in domains_in_use(),
                   timeout=10, period=0.1)
        assert domain in {domain_of_port(p) for p in live_port_segments()}  # seen from any network namespace too
        assert domain not in {unused_domain_id() for _ in range(500)}
    finally:
        sleeper.kill()
        sleeper.wait()
