"""The bridge with ROS from a sourced installation, not the wheels (bridge/README.md, "ROS from apt").

A ROS 2 installation from apt is not in the venv: ``source /opt/ros/jazzy/setup.bash`` puts its Python packages
on ``PYTHONPATH``, its libraries on ``LD_LIBRARY_PATH`` and its prefix on ``AMENT_PREFIX_PATH``. Simulated here:
the ROS wheels' files (found by their distributions' records) are linked into a directory of their own, every other
package into another, and a fresh venv sees only the second one. Without the three variables the bridge says it
cannot import rclpy; with them it runs the robot.
"""

from __future__ import annotations

import importlib.metadata
import os
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

from tests.support.embedded_broker import EmbeddedBrokerProcess
from tests.support.mqtt_client import TestClient
from tests.support.procs import CONFIG, ROOT, run

pytestmark = pytest.mark.timeout(120)


def _split_site_packages(ros: Path, others: Path) -> None:
    """Link each entry of this venv's site-packages into ``ros`` (files of a ros-* distribution) or ``others``."""
    site = Path(sysconfig.get_paths()["purelib"])
    ros_entries: set[str] = set()
    for dist in importlib.metadata.distributions():
        if (dist.metadata["Name"] or "").lower().replace("_", "-").startswith("ros-"):
            ros_entries |= {str(f).split("/")[0] for f in dist.files or () if not str(f).startswith("..")}
    assert "rclpy" in ros_entries, "the ROS wheels are not installed in this venv"
    for directory in (ros, others):
        directory.mkdir(parents=True)
    for entry in site.iterdir():
        if entry.suffix == ".pth" or entry.name == "__pycache__":
            continue  # a .pth runs only in a site directory (the wheels' bootstrapper is one): a sourced ROS has none
        ((ros if entry.name in ros_entries else others) / entry.name).symlink_to(entry)


def test_the_bridge_runs_from_a_sourced_ros_installation(tmp_path: Path) -> None:
    ros, others, venv = tmp_path / "opt-ros", tmp_path / "deps", tmp_path / "venv"
    _split_site_packages(ros, others)
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=60)
    python = venv / "bin" / "python"
    purelib = subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                             capture_output=True, text=True, check=True, timeout=30).stdout.strip()
    Path(purelib, "deps.pth").write_text(f"{others}\n{ROOT}\n")  # the core's dependencies and roslink_mqtt
    plain = {k: v for k, v in os.environ.items()
             if k not in ("PYTHONPATH", "LD_LIBRARY_PATH", "AMENT_PREFIX_PATH", "_ROS_WHEELS_BOOTSTRAP_COMPLETE")}
    assert subprocess.run([str(python), "-c", "import rclpy"], env=plain, capture_output=True,
                          timeout=30).returncode != 0, "rclpy is importable without the sourced variables"
    with EmbeddedBrokerProcess(tmp_path, CONFIG) as broker:
        args = ["-m", "roslink_mqtt.bridge.main", "--config", str(CONFIG), "--robot", "turtle1", "--url",
                f"mqtt://127.0.0.1:{broker.port}"]
        env = {**plain, "ROSLINK_PASSWORD": "turtle1-demo"}
        refused = subprocess.run([str(python), *args], env=env, capture_output=True, text=True, timeout=60)
        assert refused.returncode == 2 and "rclpy is not importable in this Python" in refused.stderr, refused
        libraries = ":".join(str(p) for p in sorted(ros.glob("ros_*.libs")))
        sourced = {**env, "PYTHONPATH": str(ros), "AMENT_PREFIX_PATH": sys.prefix,  # what setup.bash sets
                   "LD_LIBRARY_PATH": f"{libraries}:{Path(sys.prefix) / 'lib'}"}
        with run(["-m", "roslink_mqtt.sim"], tmp_path / "sim.log"), \
                run(args, tmp_path / "bridge.log", sourced, python=str(python)) as bridge, \
                TestClient(broker.port, "bob", "bob-demo") as bob:
            assert bob.connect() == 0
            bob.subscribe("roslink/turtle1/state/global_motion")
            motion = bob.wait_for(lambda m: True, timeout=30)  # odometry from the sim, through the bridge
            assert "x" in motion.json()["payload"], motion.payload
            assert "Traceback" not in bridge.output()
