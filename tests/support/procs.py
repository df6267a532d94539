"""Run the project's real programs as child processes, with logs kept for failure reports.

The process handling (own process group; SIGINT, then SIGKILL) is :mod:`roslink_mqtt.localproc`,
shared with the demo and the benchmarks.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from roslink_mqtt.localproc import LocalProcess

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "config" / "robots.yaml"
DEMO_PASSWORDS = {"turtle1": "turtle1-demo", "turtle2": "turtle2-demo", "alice": "alice-demo",
                  "bob": "bob-demo", "carol": "carol-demo", "admin": "admin-demo"}

Proc = LocalProcess  # the old name: ``.popen``, ``.pid``, ``.signal()``, ``.output()``, ``.stop()``


@contextmanager
def run(args: list[str], log: Path, env: dict[str, str] | None = None, *,
        python: str = sys.executable) -> Iterator[LocalProcess]:
    """Start ``python args…`` (a module or script; ``python``: another interpreter) and stop it afterwards."""
    full_env = dict(os.environ if env is None else env)
    full_env.setdefault("PYTHONUNBUFFERED", "1")
    proc = LocalProcess([python, *args], log, env=full_env, cwd=ROOT)
    proc.spawn()
    try:
        yield proc
    finally:
        proc.stop()


def bridge_args(robot: str, port: int, *extra: str, config: Path = CONFIG) -> list[str]:
    return ["-m", "roslink_mqtt.bridge.main", "--config", str(config), "--robot", robot,
            "--url", f"mqtt://127.0.0.1:{port}", *extra]


def bridge_env(robot: str) -> dict[str, str]:
    return {**os.environ, "ROSLINK_PASSWORD": DEMO_PASSWORDS[robot]}
