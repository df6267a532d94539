"""Start a real Mosquitto broker (the OS package) on a free loopback port.

The runner is :class:`roslink_mqtt.localproc.Mosquitto`, shared with the demo and the benchmarks.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from roslink_mqtt.localproc import Mosquitto, free_port, mosquitto_conf, mosquitto_exe

MOSQUITTO = mosquitto_exe() or "/usr/sbin/mosquitto"


@contextmanager
def run_mosquitto(workdir: Path, extra_conf: str = "", port: int | None = None) -> Iterator[int]:
    """Run mosquitto with ``extra_conf`` appended; yield its port; stop it afterwards."""
    with Mosquitto.plain(workdir, extra_conf, port) as broker:
        yield broker.port


class MosquittoProcess(Mosquitto):
    """A Mosquitto that tests can kill, freeze and restart on the same port."""

    def __init__(self, workdir: Path, extra_conf: str = "") -> None:
        port = free_port()
        super().__init__(workdir, mosquitto_conf(port, extra_conf), port)
