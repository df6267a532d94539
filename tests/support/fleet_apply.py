"""``roslink-mqtt fleet apply`` run by a test, its output read as it comes (tests/integration/test_fleet_apply.py,
test_rabbitmq_cluster.py)."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

from .procs import ROOT


class Apply:
    """``fleet apply`` as a process whose lines are read as they come: ``planned`` is when the plan was printed
    (the change is applied right after), ``done`` when it exited."""

    def __init__(self, fleet: Path, port: int | str, *extra: str, env: dict[str, str] | None = None) -> None:
        """``port``: the broker's on 127.0.0.1, or a URL list (a cluster's nodes)."""
        url = port if isinstance(port, str) else f"mqtt://127.0.0.1:{port}"
        self.started = time.monotonic()
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "roslink_mqtt.cli.main", "fleet", "apply", "--config", str(fleet), "--url", url,
             "-u", "admin", *extra], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=ROOT,
            env={**(env or os.environ), "ROSLINK_PASSWORD": "admin-demo"}, stdin=subprocess.DEVNULL)
        self.lines: list[str] = []
        self.planned: float | None = None
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append(line.rstrip())
            if self.planned is None and line.startswith(("embedded broker", "mosquitto", "rabbitmq")):
                self.planned = time.monotonic()
        self.rc = self.proc.wait(timeout=30)
        self.done = time.monotonic()
        assert self.rc == 0, self.output

    @property
    def output(self) -> str:
        return "\n".join(self.lines)
