"""Run the project's real programs as child processes, with logs kept for failure reports."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "config" / "robots.yaml"
DEMO_PASSWORDS = {"turtle1": "turtle1-demo", "turtle2": "turtle2-demo", "alice": "alice-demo",
                  "bob": "bob-demo", "carol": "carol-demo", "admin": "admin-demo"}


class Proc:
    def __init__(self, popen: subprocess.Popen, log: Path) -> None:
        self.popen, self.log = popen, log

    @property
    def pid(self) -> int:
        return self.popen.pid

    def signal(self, sig: int) -> None:
        self.popen.send_signal(sig)

    def output(self) -> str:
        return self.log.read_text(errors="replace") if self.log.exists() else ""

    def stop(self, timeout: float = 5.0) -> int | None:
        if self.popen.poll() is None:
            try:
                self.popen.send_signal(signal.SIGCONT)  # a frozen process cannot handle SIGINT
                self.popen.send_signal(signal.SIGINT)
                self.popen.wait(timeout)
            except subprocess.TimeoutExpired:
                self.popen.kill()
                self.popen.wait()
        return self.popen.returncode


@contextmanager
def run(args: list[str], log: Path, env: dict[str, str] | None = None) -> Iterator[Proc]:
    """Start ``python args…`` (a module or script) and stop it afterwards."""
    full_env = dict(os.environ if env is None else env)
    full_env.setdefault("PYTHONUNBUFFERED", "1")
    with open(log, "wb") as out:
        popen = subprocess.Popen([sys.executable, *args], stdout=out, stderr=subprocess.STDOUT, env=full_env,
                                 cwd=ROOT)
        proc = Proc(popen, log)
        try:
            yield proc
        finally:
            proc.stop()


def bridge_args(robot: str, port: int, *extra: str, config: Path = CONFIG) -> list[str]:
    return ["-m", "roslink_mqtt.bridge.main", "--config", str(config), "--robot", robot,
            "--broker", f"mqtt://127.0.0.1:{port}", *extra]


def bridge_env(robot: str) -> dict[str, str]:
    return {**os.environ, "ROSLINK_MQTT_PASSWORD": DEMO_PASSWORDS[robot]}
