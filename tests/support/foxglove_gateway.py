"""``roslink-mqtt foxglove`` as a test starts it: a real gateway process, the URL it prints, the SDK's own port."""

from __future__ import annotations

import os
import re
import sys
from collections.abc import Sequence
from pathlib import Path

from roslink_mqtt.localproc import LocalProcess, free_port

from .browser import wait_until
from .procs import ROOT


def start_gateway(work: Path, broker_port: int, user: str, *options: str, robots: Sequence[str] = ("turtle1",),
                  token: str | None = None) -> LocalProcess:
    """``user``'s gateway on a free port, started; ``token``: set as ROSLINK_FOXGLOVE_TOKEN (default: none, the
    gateway makes one and prints its URL: :func:`printed_url`)."""
    port = free_port()
    env = {**os.environ, "ROSLINK_PASSWORD": f"{user}-demo", "PYTHONUNBUFFERED": "1"}
    env.pop("ROSLINK_FOXGLOVE_TOKEN", None)
    if token is not None:
        env["ROSLINK_FOXGLOVE_TOKEN"] = token
    proc = LocalProcess([sys.executable, "-m", "roslink_mqtt.cli.main", "foxglove", *robots, "--port", str(port),
                         "--url", f"mqtt://127.0.0.1:{broker_port}", "-u", user, *options],
                        work / f"gateway-{user}.log", env=env, cwd=ROOT, port=port, what=f"{user}'s gateway",
                        stop_signal=2)
    proc.start()
    return proc


def printed_url(gateway: LocalProcess) -> str:
    """The URL the gateway printed (``serving … on ws://127.0.0.1:PORT/?token=… (Ctrl-C ends it)``)."""
    def printed() -> str | None:
        found = re.search(r"to Foxglove on (ws://\S+) \(Ctrl-C", gateway.log.read_text(errors="replace"))
        return found.group(1) if found else None
    return wait_until("the gateway's URL in its output", printed)


def upstream_port(gateway: LocalProcess) -> int:
    """The SDK's own port, as a scan would find it: the gateway's other listening TCP port (checked to be on
    loopback only)."""
    import psutil

    assert gateway.proc is not None
    listening = {c.laddr for c in psutil.Process(gateway.proc.pid).net_connections("tcp")
                 if c.status == psutil.CONN_LISTEN}
    others = [addr for addr in listening if addr.port != gateway.port]
    assert len(others) == 1, listening
    assert others[0].ip == "127.0.0.1", f"the SDK's server listens on {others[0].ip}"
    return int(others[0].port)
