"""Child processes for the benchmarks: free loopback ports, start with guaranteed stop, wait for a port.

Shared by the benchmark scripts (run as ``python bench/<name>.py``, so this directory is on sys.path);
the leading underscore keeps ``run_all.py`` from running it as a benchmark.
"""

from __future__ import annotations

import signal
import socket
import subprocess
import time
from contextlib import ExitStack
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def free_port() -> int:
    """A free TCP port on loopback, so a bench never collides with a broker already running."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def tail(path: Path | None, lines: int = 15) -> str:
    """The end of a child's log, for an error message (the logs live in a temporary directory)."""
    if path is None:
        return "(no log)"
    try:
        return "\n".join(path.read_text(errors="replace").splitlines()[-lines:])
    except OSError:
        return "(no log)"


def start_process(stack: ExitStack, args: list[str], log: Path, env: dict[str, str]) -> subprocess.Popen:
    """Start a child whose stop (SIGINT, then kill) is registered on ``stack``: no child outlives the bench."""
    out = stack.enter_context(open(log, "wb"))
    proc = subprocess.Popen(args, stdout=out, stderr=subprocess.STDOUT, env=env, cwd=ROOT)

    def stop() -> None:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(5)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()

    stack.callback(stop)
    return proc


def wait_port(port: int, proc: subprocess.Popen, what: str, log: Path | None = None, timeout: float = 15.0) -> None:
    """Block until ``proc`` listens on ``port``; fail fast (with its log) if it exits first."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise SystemExit(f"bench: {what} exited (code {proc.returncode}):\n{tail(log)}")
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=0.2):
                return
        except OSError:
            time.sleep(0.05)
    raise SystemExit(f"bench: {what} did not open port {port}:\n{tail(log)}")
