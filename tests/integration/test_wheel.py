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
from tests.support.browser import CHROMIUM, browser, logged_in, login, wait_until
from tests.support.embedded_broker import EmbeddedBrokerProcess
from tests.support.net import free_port, wait_for_port
from tests.support.procs import ROOT

pytestmark = [pytest.mark.timeout(300), CHROMIUM,
              pytest.mark.skipif(not VERSIONS.is_file(), reason="no vendored bundles (make install)")]


def _clean_env() -> dict[str, str]:
    """The environment of a user's shell: nothing of this repository or its venv on any path."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV", "PYTHONHOME")}
    env["PATH"] = os.pathsep.join(p for p in env.get("PATH", "").split(os.pathsep) if str(ROOT) not in p)
    return env


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Path:
    """A fresh venv with only the built wheel (and its dependencies from PyPI) installed; its bin directory."""
    work = tmp_path_factory.mktemp("wheel")
    built = subprocess.run([sys.executable, "-m", "build", "--wheel", "--outdir", str(work / "dist"), str(ROOT)],
                           capture_output=True, text=True, timeout=240, cwd=work)
    assert built.returncode == 0, built.stdout[-3000:] + built.stderr[-3000:]
    wheel = next((work / "dist").glob("roslink_mqtt-*.whl"))
    names = set(zipfile.ZipFile(wheel).namelist())
    for name in (*BUNDLES, "VERSIONS.json", "LICENSE-mqtt", "LICENSE-uplot"):
        assert f"roslink_mqtt/dashboard/vendor/{name}" in names, name
    assert not any(n.startswith(("tests/", "bench/", "node_modules/")) for n in names)
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
