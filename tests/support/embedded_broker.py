"""Run the embedded broker (``python -m roslink_mqtt.broker``) as a child process on a free loopback port.

:class:`EmbeddedBrokerProcess` has the interface of :class:`tests.support.mosquitto.MosquittoProcess`
(``.port``, ``start()``, ``signal(sig)``, ``kill()``, ``stop()``; restartable on the same
port), so fault-injection tests can run against either broker::

    broker = EmbeddedBrokerProcess(tmp_path).start()
    ...
    broker.signal(signal.SIGSTOP)   # freeze it
    broker.stop()                   # SIGCONT + SIGTERM, then SIGKILL after 5 s
    broker.start()                  # same port again

The broker's output goes to ``workdir/embedded-broker.log`` (appended across restarts);
:meth:`output` reads it back for assertions and failure reports.
"""

from __future__ import annotations

import sys
from pathlib import Path

from tests.support.waits import wait_until

from .managed import ManagedProcess
from .net import free_port
from .procs import CONFIG, ROOT


class EmbeddedBrokerProcess(ManagedProcess):
    def __init__(self, workdir: Path, config: Path = CONFIG, *extra_args: str, ws: bool = False,
                 log_name: str = "embedded-broker.log") -> None:
        """``ws=True`` also opens a WebSocket listener on a free port (``.ws_port``); ``extra_args`` go to the CLI."""
        self.workdir, self.config = Path(workdir), Path(config)
        self.port = free_port()
        self.ws_port = free_port() if ws else 0
        self.extra_args = list(extra_args)
        super().__init__(self.args, self.workdir / log_name, cwd=ROOT, port=self.port, what="embedded broker",
                         append=True)
        self._log_offset = 0

    @property
    def args(self) -> list[str]:
        return [sys.executable, "-m", "roslink_mqtt.broker", "--config", str(self.config), "--host", "127.0.0.1",
                "--port", str(self.port), "--ws-port", str(self.ws_port), *self.extra_args]

    def start(self, timeout: float = 15.0) -> EmbeddedBrokerProcess:
        self.ready_timeout = timeout
        self._log_offset = self.log.stat().st_size if self.log.exists() else 0  # a restart appends
        return super().start()

    def wait_ready(self) -> None:
        """Ready = the 'listening on' line is logged (every listener is bound by then)."""
        proc = self.proc
        assert proc is not None
        marker = f"listening on mqtt://127.0.0.1:{self.port}".encode()

        def listening() -> bool:
            if marker in self.log.read_bytes()[self._log_offset:]:
                return True
            if proc.poll() is not None:
                raise RuntimeError(f"embedded broker exited with {proc.returncode}:\n{self.output()[-3000:]}")
            return False

        try:
            wait_until(f"the embedded broker listening on port {self.port}", listening, timeout=self.ready_timeout)
        except AssertionError:
            raise TimeoutError(f"embedded broker not ready on port {self.port} after {self.ready_timeout} s:\n"
                               f"{self.output()[-3000:]}") from None
