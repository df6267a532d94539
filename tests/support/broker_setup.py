"""Test fleets for broker tests, and a real Mosquitto started from ``roslink-mqtt acl export``.

* :func:`write_fleet` copies the demo robots.yaml into a test directory with the broker on
  free loopback ports and (by default) an extra read-only service ``status`` on both
  robots, so the viewer rules can be tested (the demo's ``reset`` is not read-only).
* :class:`ExportedMosquitto` exports that fleet and runs Mosquitto with the exported
  ``mosquitto.conf`` -- same interface as :class:`~tests.support.mosquitto.MosquittoProcess`
  (it is :meth:`roslink_mqtt.localproc.Mosquitto.exported`, which the benchmarks use too).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from roslink_mqtt.config import load_fleet
from roslink_mqtt.localproc import Mosquitto, free_port, replace_once

from .procs import CONFIG

READ_ONLY_SERVICE = """      - name: status
        ros_service: status
        ros_type: std_srvs/srv/Trigger
        read_only: true
"""


def write_fleet(workdir: Path, *, port: int | None = None, ws_port: int = 0, read_only_service: bool = True,
                edit: Callable[[str], str] | None = None, name: str = "robots.yaml") -> Path:
    """A copy of config/robots.yaml for one test; ``edit`` may rewrite the YAML text further.

    Every edit must change the text: one that finds nothing to replace (the demo file changed
    under it) fails here instead of silently testing the unedited fleet.
    """
    text = CONFIG.read_text()
    text = replace_once(text, "  port: 1883\n  ws_port: 8083\n",
                        f"  port: {port or free_port()}\n  ws_port: {ws_port}\n")
    if read_only_service:
        anchor = "        timeout: 5.0\n"
        text = replace_once(text, anchor, anchor + READ_ONLY_SERVICE)
    if edit is not None:
        edited = edit(text)
        if edited == text:
            raise ValueError("write_fleet: the edit changed nothing (did the demo robots.yaml change?)")
        text = edited
    path = Path(workdir) / name
    path.write_text(text)
    load_fleet(path)  # fail here, not in the broker, if the edit broke it
    return path


class ExportedMosquitto(Mosquitto):
    """Mosquitto running the exact files ``roslink-mqtt acl export`` writes for ``config``.

    ``extra_conf`` is appended to a copy of the exported mosquitto.conf. The copy always gets a
    ``user`` line for the current account: Mosquitto started as root otherwise drops to the user
    ``mosquitto``, which cannot read pytest's private temporary directories.
    """

    def __init__(self, workdir: Path, config: Path, extra_conf: str = "") -> None:
        exported = Mosquitto.exported(workdir, config, extra_conf)
        super().__init__(workdir, exported.conf.read_text(), exported.port, conf_name=exported.conf.name)
        self.fleet, self.files = exported.fleet, exported.files
