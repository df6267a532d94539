"""The core (SDK, CLI, config, protocol) installs and runs on Python 3.10..3.13 (requires-python); the bridge's ROS
wheels are for 3.11 only, marked so that pip on another Python skips them (the bridge then uses a sourced ROS's rclpy).

The suite itself runs on 3.11: here the core is installed with pip into a venv of the oldest other CPython on this
machine (the lower bound, 3.10, where one exists) and used, and the metadata pip built for it is read.
"""

from __future__ import annotations

import re
import shutil
import subprocess
from email.parser import Parser
from pathlib import Path

import pytest

from tests.support.procs import CONFIG, ROOT

pytestmark = pytest.mark.timeout(180)

OTHER_PYTHONS = ("3.10", "3.12", "3.13")


def _interpreter(version: str) -> str | None:
    found = shutil.which(f"python{version}")
    if found and subprocess.run([found, "-c", "1"], capture_output=True).returncode == 0:
        return found
    pyenv = sorted(Path("/root/.pyenv/versions").glob(f"{version}.*/bin/python{version}"))
    return str(pyenv[-1]) if pyenv else None


def test_the_core_installs_and_runs_on_the_oldest_other_python(tmp_path) -> None:
    python = next((p for v in OTHER_PYTHONS if (p := _interpreter(v))), None)
    if python is None:
        pytest.skip(f"no other CPython ({', '.join(OTHER_PYTHONS)}) on this machine")
    venv = tmp_path / "venv"
    subprocess.run([python, "-m", "venv", str(venv)], check=True, timeout=60)
    pip = subprocess.run([str(venv / "bin" / "pip"), "install", "--quiet", "--disable-pip-version-check", str(ROOT)],
                         capture_output=True, text=True, timeout=150)
    assert pip.returncode == 0, pip.stdout + pip.stderr
    code = ("import sys; from roslink_mqtt.client import RobotClient; from roslink_mqtt.config import Role, load_fleet;"
            "fleet = load_fleet(sys.argv[1]); role = fleet.roles_of('alice')['turtle1'];"
            "print(sys.version_info[:2], f'{role}', str(Role.VIEWER), RobotClient.__name__)")
    used = subprocess.run([str(venv / "bin" / "python"), "-c", code, str(CONFIG)], capture_output=True, text=True,
                          cwd=tmp_path, timeout=60)  # not from the source tree: the installed package
    assert used.returncode == 0, used.stderr
    assert used.stdout.split(")")[1].split() == ["operator", "viewer", "RobotClient"], used.stdout
    cli = subprocess.run([str(venv / "bin" / "roslink-mqtt"), "fleet", "--config", str(CONFIG)], capture_output=True,
                         text=True, cwd=tmp_path, timeout=60)
    assert cli.returncode == 0 and "operator alice" in cli.stdout, cli.stdout + cli.stderr
    # the metadata pip built (what any pip on 3.10..3.13 reads before it installs anything)
    meta = Parser().parsestr(next(venv.glob("lib/python*/site-packages/roslink_mqtt-*.dist-info/METADATA")).read_text())
    assert meta["Requires-Python"] == "<3.14,>=3.10"
    requires = meta.get_all("Requires-Dist")
    ros = [r for r in requires if r.startswith("ros-jazzy-")]
    assert ros and all('python_version == "3.11"' in r and 'extra == "bridge"' in r for r in ros), ros
    core = [r for r in requires if "extra ==" not in r]
    assert sorted(re.split(r"[<>=]", r)[0] for r in core) == ["orjson", "paho-mqtt", "pyyaml"], core
    assert {f"Programming Language :: Python :: {v}" for v in ("3.10", "3.11", "3.12", "3.13")} <= \
        set(meta.get_all("Classifier"))
    print(f"\n{Path(python).name}: installed with pip and used: {used.stdout.strip()}")
