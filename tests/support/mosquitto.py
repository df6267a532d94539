"""Start a real Mosquitto broker (the OS package) on a free loopback port."""

from __future__ import annotations

import getpass
import shutil
import subprocess
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from .managed import ManagedProcess
from .net import free_port, wait_for_port

MOSQUITTO = shutil.which("mosquitto") or "/usr/sbin/mosquitto"


@contextmanager
def run_mosquitto(workdir: Path, extra_conf: str = "", port: int | None = None) -> Iterator[int]:
    """Run mosquitto with ``extra_conf`` appended; yield its port; stop it afterwards."""
    port = port or free_port()
    conf = workdir / "mosquitto.conf"
    # Started as root, mosquitto drops to user "mosquitto", who cannot read pytest's private tmp dirs.
    user = getpass.getuser()
    # set_tcp_nodelay: without it Mosquitto's small replies wait behind Nagle (~40 ms per service call).
    conf.write_text(f"user {user}\nlistener {port} 127.0.0.1\npersistence false\nlog_dest stderr\n"
                    f"set_tcp_nodelay true\n{extra_conf}\n")
    log = open(workdir / "mosquitto.log", "wb")  # noqa: SIM115 - closed below
    proc = subprocess.Popen([MOSQUITTO, "-c", str(conf)], stdout=log, stderr=subprocess.STDOUT)
    try:
        wait_for_port(port)
        yield port
    finally:
        proc.terminate()
        try:
            proc.wait(5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        log.close()


class MosquittoProcess(ManagedProcess):
    """A Mosquitto that tests can kill, freeze and restart on the same port."""

    def __init__(self, workdir: Path, extra_conf: str = "") -> None:
        self.workdir, self.port = workdir, free_port()
        self.conf = workdir / "mosquitto.conf"
        self.log = workdir / "mosquitto.log"
        self.conf.write_text(f"user {getpass.getuser()}\nlistener {self.port} 127.0.0.1\npersistence false\n"
                             f"log_dest stderr\nset_tcp_nodelay true\n{extra_conf}\n")

    def start(self) -> MosquittoProcess:
        with open(self.log, "ab") as log:
            self.proc = subprocess.Popen([MOSQUITTO, "-c", str(self.conf)], stdout=log, stderr=subprocess.STDOUT)
        wait_for_port(self.port)
        return self
