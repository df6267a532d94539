"""Test fleets for broker tests, and a real Mosquitto started from ``roslink-mqtt acl export``.

* :func:`write_fleet` copies the demo robots.yaml into a test directory with the broker on
  free loopback ports and (by default) an extra read-only service ``status`` on both
  robots, so the viewer rules can be tested (the demo's ``reset`` is not read-only).
* :class:`ExportedMosquitto` exports that fleet and runs Mosquitto with the exported
  ``mosquitto.conf`` -- same interface as :class:`~tests.support.mosquitto.MosquittoProcess`.
"""

from __future__ import annotations

import getpass
import subprocess
from collections.abc import Callable
from pathlib import Path

from roslink_mqtt.broker.export import export_mosquitto
from roslink_mqtt.config import load_fleet

from .managed import ManagedProcess
from .mosquitto import MOSQUITTO
from .net import free_port, wait_for_port
from .procs import CONFIG

READ_ONLY_SERVICE = """      - name: status
        ros_service: status
        ros_type: std_srvs/srv/Trigger
        read_only: true
"""


def write_fleet(workdir: Path, *, port: int | None = None, ws_port: int = 0, read_only_service: bool = True,
                edit: Callable[[str], str] | None = None, name: str = "robots.yaml") -> Path:
    """A copy of config/robots.yaml for one test; ``edit`` may rewrite the YAML text further."""
    text = CONFIG.read_text()
    text = text.replace("  port: 1883\n  ws_port: 8083\n", f"  port: {port or free_port()}\n  ws_port: {ws_port}\n")
    if read_only_service:
        anchor = "        timeout: 5.0\n"
        assert text.count(anchor) == 1, "demo robots.yaml changed: update write_fleet"
        text = text.replace(anchor, anchor + READ_ONLY_SERVICE)
    if edit is not None:
        text = edit(text)
    path = Path(workdir) / name
    path.write_text(text)
    load_fleet(path)  # fail here, not in the broker, if the edit broke it
    return path


class ExportedMosquitto(ManagedProcess):
    """Mosquitto running the exact files ``roslink-mqtt acl export`` writes for ``config``.

    ``extra_conf`` is appended to a copy of the exported mosquitto.conf. The copy always gets a
    ``user`` line for the current account: Mosquitto started as root otherwise drops to the user
    ``mosquitto``, which cannot read pytest's private temporary directories.
    """

    def __init__(self, workdir: Path, config: Path, extra_conf: str = "") -> None:
        self.workdir = Path(workdir)
        self.fleet = load_fleet(config)
        self.port = self.fleet.broker.port
        self.files = export_mosquitto(self.fleet, self.workdir / "mosquitto-export")
        self.conf = self.workdir / "mosquitto-run.conf"
        self.conf.write_text(self.files.conf.read_text() + f"user {getpass.getuser()}\n{extra_conf}\n")
        self.log = self.workdir / "mosquitto.log"

    def start(self) -> ExportedMosquitto:
        with open(self.log, "ab") as log:
            self.proc = subprocess.Popen([MOSQUITTO, "-c", str(self.conf)], stdout=log, stderr=subprocess.STDOUT)
        try:
            wait_for_port(self.port)
        except TimeoutError:
            self.kill()
            raise RuntimeError(f"mosquitto did not start:\n{self.output()[-2000:]}") from None
        return self

