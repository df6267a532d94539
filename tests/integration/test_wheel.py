"""The wheel is the product (issue 43, 5): `python -m build` gives a wheel whose install alone, in a fresh venv with
no repository on the path and no npm, runs `roslink-mqtt dashboard` with its JavaScript (MQTT.js, uPlot) inside the
package; Chromium loads the page from it and logs in to a real broker over WebSockets.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import urllib.request
import zipfile
from pathlib import Path

import pytest

from roslink_mqtt.dashboard.vendor import BUNDLES, VENDOR_DIR, VERSIONS
from roslink_mqtt.localproc import LocalProcess
from tests.support.browser import CHROMIUM, browser, logged_in, login, wait_until
from tests.support.embedded_broker import EmbeddedBrokerProcess
from tests.support.mqtt_client import TestClient
from tests.support.net import free_port, wait_for_port
from tests.support.procs import CONFIG, ROOT, run

pytestmark = [pytest.mark.timeout(300), CHROMIUM,
              pytest.mark.skipif(not VERSIONS.is_file(), reason="no vendored bundles (make install)")]


def _clean_env() -> dict[str, str]:
    """The environment of a user's shell: nothing of this repository or its venv on any path."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV", "PYTHONHOME")}
    env["PATH"] = os.pathsep.join(p for p in env.get("PATH", "").split(os.pathsep) if str(ROOT) not in p)
    return env


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """The wheel `python -m build` makes of this checkout."""
    work = tmp_path_factory.mktemp("wheel")
    built = subprocess.run([sys.executable, "-m", "build", "--wheel", "--outdir", str(work / "dist"), str(ROOT)],
                           capture_output=True, text=True, timeout=240, cwd=work)
    assert built.returncode == 0, built.stdout[-3000:] + built.stderr[-3000:]
    made = next((work / "dist").glob("roslink_mqtt-*.whl"))
    names = set(zipfile.ZipFile(made).namelist())
    for name in (*BUNDLES, "VERSIONS.json", "LICENSE-mqtt", "LICENSE-uplot"):
        assert f"roslink_mqtt/dashboard/vendor/{name}" in names, name
    assert not any(n.startswith(("tests/", "bench/", "node_modules/")) for n in names)
    return made


@pytest.fixture(scope="module")
def installed(wheel: Path, tmp_path_factory) -> Path:
    """A fresh venv with only the built wheel (and its dependencies from PyPI) installed; its bin directory."""
    work = tmp_path_factory.mktemp("laptop")
    venv = work / "venv"
    subprocess.run(["python3", "-m", "venv", str(venv)], check=True, timeout=120, env=_clean_env())
    pip = subprocess.run([str(venv / "bin" / "pip"), "install", "--quiet", str(wheel)], capture_output=True,
                         text=True, timeout=240, env=_clean_env(), cwd=work)
    assert pip.returncode == 0, pip.stdout[-3000:] + pip.stderr[-3000:]
    where = subprocess.run([str(venv / "bin" / "python"), "-c", "import roslink_mqtt; print(roslink_mqtt.__file__)"],
                           capture_output=True, text=True, timeout=60, env=_clean_env(), cwd=work)
    assert where.stdout.strip().startswith(str(venv)), where  # the installed copy, not the repository's
    return venv / "bin"


def test_the_wheel_alone_serves_the_dashboard_and_it_logs_in(installed: Path, tmp_path: Path) -> None:
    port = free_port()
    with EmbeddedBrokerProcess(tmp_path, ws=True) as broker:
        dashboard = subprocess.Popen([str(installed / "roslink-mqtt"), "dashboard", "--port", str(port),
                                      "--ws-port", str(broker.ws_port)], cwd=tmp_path, env=_clean_env(),
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        try:
            wait_for_port(port, 30)
            versions = json.loads((VENDOR_DIR / "VERSIONS.json").read_text())
            for name in BUNDLES:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/vendor/{name}", timeout=10) as resp:
                    body = resp.read()
                package = next(p for p, entry in versions.items() if name in entry["files"])
                assert body == (VENDOR_DIR / name).read_bytes(), f"{name} ({package}) differs from the pinned copy"
            with browser(tmp_path, "wheel") as driver:
                login(driver, f"http://127.0.0.1:{port}/", "bob", "bob-demo")
                logged_in(driver, "bob")  # MQTT.js from the package talked to the broker
                wait_until("uPlot from the package", lambda: driver.execute_async_script(
                    "const done = arguments[0]; import('/vendor/uPlot.esm.js')"
                    ".then(m => done(typeof m.default === 'function'), () => done(false))"))
        finally:
            dashboard.terminate()
            out, _ = dashboard.communicate(timeout=10)
    assert "Traceback" not in out, out


# -- the robot recipe of docs/deploy.md: ROS from apt, the system's Python, the wheel with [robot] -------------------

RECIPE_MARK = "tests/integration/test_wheel.py runs these lines with a stand-in ROS"


def _recipe() -> list[str]:
    """The lines of docs/deploy.md's robot recipe, as a user would paste them."""
    text = (ROOT / "docs" / "deploy.md").read_text()
    head = text.index(RECIPE_MARK)
    body = text[text.index("\n", head) + 1:text.index("```", head)]
    return [line.split("  #")[0].rstrip() for line in body.splitlines() if line.strip()]


def _ros_python_dependencies() -> set[str]:
    """The Python packages ROS's own need (numpy, pyyaml, lark, empy): apt installs them as python3-numpy & co."""
    import importlib.metadata
    import re

    names = set()
    for dist in importlib.metadata.distributions():
        if (dist.metadata["Name"] or "").lower().replace("_", "-").startswith("ros-"):
            for requirement in dist.requires or ():
                name = re.split(r"[ ;<>=!~\[(]", requirement, maxsplit=1)[0].lower().replace("_", "-")
                if not name.startswith("ros-") and "extra ==" not in requirement and name != "setuptools":
                    names.add(name)
    return names


def _stand_in_ros(root: Path) -> Path:
    """/opt/ros/jazzy as apt installs it, made from the ROS wheels of this venv: their files linked into a
    site-packages of its own, and a setup.bash that sets PYTHONPATH, LD_LIBRARY_PATH and AMENT_PREFIX_PATH only.

    apt installs what ROS's Python needs (python3-numpy, python3-yaml, …) into /usr/lib/python3/dist-packages,
    which the recipe's venv sees through ``--system-site-packages``; this Python's system site has none of them,
    so a stand-in dist-packages with exactly those goes on PYTHONPATH after ROS's (and nothing else does)."""
    import importlib.metadata

    from tests.integration.test_sourced_ros import _split_site_packages

    site, others = root / "lib" / "python3" / "site-packages", root / "unused"
    site.parent.mkdir(parents=True)
    _split_site_packages(site, others)
    dist_packages = root / "dist-packages"
    dist_packages.mkdir()
    for name in _ros_python_dependencies():
        dist = importlib.metadata.distribution(name)
        for top in {str(f).split("/")[0] for f in dist.files or () if not str(f).startswith("..")}:
            if (others / top).exists() and not (dist_packages / top).exists():
                (dist_packages / top).symlink_to((others / top).resolve())
    libraries = ":".join(str(p) for p in sorted(site.glob("ros_*.libs")))
    setup = root / "setup.bash"
    lib = f"{libraries}:{Path(sys.prefix) / 'lib'}"
    setup.write_text(f"export PYTHONPATH={site}:{dist_packages}${{PYTHONPATH:+:$PYTHONPATH}}\n"
                     f"export LD_LIBRARY_PATH={lib}${{LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}}\n"
                     f"export AMENT_PREFIX_PATH={sys.prefix}\n")
    return setup


def test_the_deploy_guides_robot_recipe_runs_the_bridge_with_a_sourced_ros(wheel: Path, tmp_path: Path) -> None:
    home = tmp_path / "home"
    home.mkdir()
    lines = _recipe()
    assert lines[0] == "sudo apt install python3-venv"  # here python3's venv is there already: not run
    install = next(line for line in lines if "pip install" in line)
    assert f"./{wheel.name}[robot]" in install, f"the guide names {install!r}; `make wheel` makes {wheel.name}"
    setup = _stand_in_ros(tmp_path / "opt-ros-jazzy")
    script = "\n".join(["set -e", f"cd {wheel.parent}"] + [
        line.replace("/opt/ros/jazzy/setup.bash", str(setup)) for line in lines[1:]])
    env = {**_clean_env(), "HOME": str(home)}
    for name in ("LD_LIBRARY_PATH", "AMENT_PREFIX_PATH", "_ROS_WHEELS_BOOTSTRAP_COMPLETE"):
        env.pop(name, None)
    done = subprocess.run(["bash", "-c", script], capture_output=True, text=True, timeout=300, env=env)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert f"rclpy from {setup.parent}" in done.stdout, done.stdout  # the stand-in's rclpy, not a wheel's
    venv = home / "roslink-venv"
    assert not list(venv.glob("lib/python3*/site-packages/rclpy")), "the recipe installed rclpy into the venv"

    # the bridge from that venv, with the variables setup.bash sets, serves the simulated robot
    sourced = subprocess.run(["bash", "-c", f"source {setup} && env"], capture_output=True, text=True, check=True,
                             env=env, timeout=30).stdout
    ros_env = dict(line.split("=", 1) for line in sourced.splitlines()
                   if line.split("=", 1)[0] in ("PYTHONPATH", "LD_LIBRARY_PATH", "AMENT_PREFIX_PATH"))
    with EmbeddedBrokerProcess(tmp_path, ws=False) as broker, \
            run(["-m", "roslink_mqtt.sim"], tmp_path / "sim.log"), \
            LocalProcess([str(venv / "bin" / "roslink-mqtt-bridge"), "--config", str(CONFIG), "--robot", "turtle1",
                          "--url", f"mqtt://127.0.0.1:{broker.port}"], tmp_path / "bridge.log", cwd=home,
                         env={**env, **ros_env, "ROSLINK_PASSWORD": "turtle1-demo", "PYTHONUNBUFFERED": "1"}) \
            as bridge, \
            TestClient(broker.port, "bob", "bob-demo") as bob:
        assert bob.connect() == 0
        bob.subscribe("roslink/turtle1/state/global_motion")
        motion = bob.wait_for(lambda m: True, timeout=30)  # odometry from the sim, through the venv's bridge
        assert "x" in motion.json()["payload"], motion.payload
        assert "Traceback" not in bridge.output()
