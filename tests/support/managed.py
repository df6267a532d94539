"""A child process (a broker) that tests can freeze, kill, stop and restart.

Subclasses say how to start it; stopping, signalling and reading the log are
the same for Mosquitto and the embedded broker.
"""

from __future__ import annotations

import signal
import subprocess
from pathlib import Path


class ManagedProcess:
    proc: subprocess.Popen | None = None
    log: Path

    def start(self):  # pragma: no cover - subclasses implement
        raise NotImplementedError

    def output(self) -> str:
        return self.log.read_text(errors="replace") if self.log.exists() else ""

    def signal(self, sig: int) -> None:
        assert self.proc is not None
        self.proc.send_signal(sig)

    def kill(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()

    def stop(self, timeout: float = 5.0) -> int | None:
        """SIGCONT (in case it is frozen), SIGTERM; SIGKILL if it does not exit in time. Returns the exit code."""
        if self.proc is None:
            return None
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGCONT)
            self.proc.terminate()
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.kill()
        return self.proc.returncode

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()
