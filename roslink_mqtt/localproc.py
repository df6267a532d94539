"""Local processes on this machine: loopback ports, child processes that always stop, a Mosquitto runner.

One module for everything that starts real programs next to each other -- ``make demo``
(:mod:`roslink_mqtt.demo`), the benchmarks in ``bench/`` and the tests (``tests/support``):

* :func:`free_port`, :func:`port_free`, :func:`wait_for_port` -- 127.0.0.1 only; :func:`listener_of`
  says who holds a port;
* :class:`LocalProcess` -- a child with its output in a log file, restartable, whose
  :meth:`~LocalProcess.stop` always ends it: SIGCONT (a frozen child cannot handle anything
  else), the stop signal (SIGINT, or SIGTERM for brokers) to its whole process group, SIGKILL
  to the group if it has not exited in time. Every child gets a session (so a process group) of its own, so
  whatever it starts stops with it; :func:`start_child` registers the stop on an ``ExitStack``;
* :class:`Mosquitto` -- the OS package's broker, either with a small loopback config
  (:meth:`Mosquitto.plain`) or with exactly the files ``roslink-mqtt acl export`` writes for a
  fleet (:meth:`Mosquitto.exported`, the deployed configuration);
* :func:`fleet_copy` -- a copy of a robots.yaml with the broker on other ports, edited as
  YAML data (an edit that no longer applies fails instead of silently doing nothing), and
  :func:`replace_once` for the text edits that must keep the file's layout.

Imports neither rclpy nor amqtt: the demo ships in the core install, which has neither.
:meth:`Mosquitto.exported` imports the exporter, which is amqtt-free.
"""

from __future__ import annotations

import getpass
import os
import random
import shutil
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from contextlib import ExitStack
from pathlib import Path
from typing import Any

LOOPBACK = "127.0.0.1"


class ChildExited(RuntimeError):
    """A child process exited while we waited for it to become ready."""


# -- ports ------------------------------------------------------------------------------------------
def _ephemeral_low() -> int:
    """The lowest port the kernel hands to outgoing connections (Linux: 32768 unless configured)."""
    try:
        return int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return 32768


_PORTS = random.Random()  # seeded from the OS per process: parallel test workers draw different ports
# Ports this process has handed out: never handed out again. A port chosen for a server that starts later (a fleet
# file written at once, its broker started by a session fixture minutes after) is free until then, and another
# draw in between took it once in CI ("address already in use", and every test on that broker lost).
_HANDED: set[int] = set()


def _share(start: int, stop: int) -> tuple[int, int]:
    """The part of ``range(start, stop)`` this process draws from: all of it, except in a test worker of
    pytest-xdist (``PYTEST_XDIST_WORKER=gwN`` of ``PYTEST_XDIST_WORKER_COUNT``, inherited by what it starts), which
    gets a slice of its own: two workers never draw the same port between a pick and the server's bind."""
    worker, count = os.environ.get("PYTEST_XDIST_WORKER", ""), os.environ.get("PYTEST_XDIST_WORKER_COUNT", "")
    if not (worker.startswith("gw") and worker[2:].isdigit() and count.isdigit() and int(count) > 1):
        return start, stop
    index, parts = int(worker[2:]), int(count)
    size = (stop - start) // parts
    return start + (index % parts) * size, start + (index % parts + 1) * size


def free_port(host: str = LOOPBACK) -> int:
    """A TCP port on ``host`` (loopback) that is free right now, for a server started next.

    Drawn below the kernel's ephemeral range: a port the kernel picks for ``bind(0)`` is one it also gives to
    outgoing connections, so between our pick and the server's bind any client connection on the machine (another
    test worker's, a bridge reconnecting) could take it, and the server would fail with "address already in use"."""
    low = min(_ephemeral_low(), 32768)
    if low > 11000:
        start, stop = _share(10000, low - 1000)
        if len(_HANDED) > (stop - start) // 2:
            _HANDED.clear()
        for _ in range(200):
            port = _PORTS.randrange(start, stop)
            if port not in _HANDED and port_free(port, host):
                _HANDED.add(port)
                return port
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        bound: int = s.getsockname()[1]  # (host, port) of an AF_INET socket
        return bound


def can_listen(port: int, host: str = LOOPBACK) -> bool:
    """Whether a server could listen on ``host``:``port`` now, binding the way servers do: with ``SO_REUSEADDR``
    (asyncio, amqtt, Mosquitto, Python's HTTP servers), so a port whose last connections are in TIME_WAIT counts
    as free, as it is for them. The one check used before starting a server (the demo, the broker's error)."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
        except OSError:
            return False
    return True


def port_free(port: int, host: str = LOOPBACK) -> bool:
    """Whether ``port`` can be bound on ``host`` right now without ``SO_REUSEADDR`` (stricter than
    :func:`can_listen`: free of TIME_WAIT too, so any server, whatever its options, can take it)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        try:
            s.bind((host, port))
            return True
        except OSError:
            return False


def listening_sockets() -> dict[str, int]:
    """Every listening TCP socket on this machine (this network namespace): ``socket:[inode]`` → its port, as a
    process's /proc/<pid>/fd links name them."""
    out: dict[str, int] = {}
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        try:
            rows = Path(table).read_text().splitlines()[1:]
        except OSError:
            continue
        for row in rows:
            fields = row.split()
            if len(fields) > 9 and fields[3] == "0A":  # 0A: LISTEN
                out[f"socket:[{fields[9]}]"] = int(fields[1].rsplit(":", 1)[1], 16)
    return out


def listener_of(port: int) -> str | None:
    """Who listens on TCP ``port`` on this machine: "pid N: command line", or None when nobody (or unknown).

    Read from /proc (the listening socket's inode, then the process holding it): processes of other
    accounts are only found when we may read their file descriptors.
    """
    inodes = {inode for inode, listening in listening_sockets().items() if listening == port}
    if not inodes:
        return None
    for proc in Path("/proc").iterdir():
        if not proc.name.isdigit():
            continue
        try:
            if any(os.readlink(fd) in inodes for fd in (proc / "fd").iterdir()):
                cmdline = (proc / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace").strip()
                return f"pid {proc.name}: {cmdline}"
        except OSError:
            continue
    return "a process this account cannot see"


def tail(path: Path | None, lines: int = 15) -> str:
    """The end of a log, for an error message (logs often live in a temporary directory)."""
    if path is None:
        return "(no log)"
    try:
        return "\n".join(Path(path).read_text(errors="replace").splitlines()[-lines:])
    except OSError:
        return "(no log)"


def wait_for_port(port: int, timeout: float = 10.0, host: str = LOOPBACK, *,
                  proc: subprocess.Popen[Any] | LocalProcess | None = None, what: str = "the process",
                  log: Path | None = None) -> None:
    """Block until something accepts connections on ``port``.

    Raises :class:`TimeoutError` after ``timeout`` s, or :class:`ChildExited` as soon as ``proc``
    (the process expected to listen) exits; both messages end with the tail of ``log``.
    """
    if isinstance(proc, LocalProcess):
        log = log or proc.log
        proc = proc.proc
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc is not None and proc.poll() is not None:
            raise ChildExited(f"{what} exited (code {proc.returncode}) before listening on {host}:{port}:\n"
                              f"{tail(log)}")
        try:
            with socket.create_connection((host, port), timeout=0.2):
                return
        except OSError:
            time.sleep(0.05)
    raise TimeoutError(f"{what}: nothing listens on {host}:{port} after {timeout} s"
                       + (f":\n{tail(log)}" if log is not None else ""))


# -- child processes --------------------------------------------------------------------------------
def _signal_group(popen: subprocess.Popen[Any], sig: int) -> None:
    """``sig`` to the child's process group (its own, see :class:`LocalProcess`), else to the child alone."""
    try:
        os.killpg(popen.pid, sig)
    except (ProcessLookupError, PermissionError):
        try:
            popen.send_signal(sig)
        except ProcessLookupError:
            pass


def stop_process(popen: subprocess.Popen[Any], stop_signal: int = signal.SIGINT, timeout: float = 5.0) -> int:
    """End ``popen`` and its process group; return its exit code.

    SIGCONT first (a frozen process handles nothing), then ``stop_signal``; SIGKILL if it has
    not exited after ``timeout`` s. Whatever is left in its group afterwards is killed too.
    """
    if popen.poll() is None:
        _signal_group(popen, signal.SIGCONT)
        _signal_group(popen, stop_signal)
        try:
            popen.wait(timeout)
        except subprocess.TimeoutExpired:
            _signal_group(popen, signal.SIGKILL)
            popen.wait()
    try:  # grandchildren that outlived the leader (the group id stays reserved while any member lives)
        os.killpg(popen.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass
    return popen.returncode


class LocalProcess:
    """A child process with its output in ``log``; restartable; :meth:`stop` always ends it.

    ``port``: :meth:`start` waits until the child listens there (failing early, with the log's
    tail, if it exits first). ``append``: keep earlier output in ``log`` (restarts always append).
    Usable as a context manager (``with LocalProcess(...) as p``: started, then stopped).
    """

    stop_signal: int = signal.SIGINT
    proc: subprocess.Popen[bytes] | None = None
    log: Path

    def __init__(self, args: Sequence[str], log: Path, *, env: Mapping[str, str] | None = None,
                 cwd: Path | str | None = None, stop_signal: int | None = None, port: int | None = None,
                 what: str | None = None, ready_timeout: float = 15.0, append: bool = False) -> None:
        self._args, self.log = list(args), Path(log)
        self.env = dict(env) if env is not None else None
        self.cwd, self.port, self.ready_timeout, self.append = cwd, port, ready_timeout, append
        self.what = what or Path(self._args[0]).name
        if stop_signal is not None:
            self.stop_signal = stop_signal

    @property
    def args(self) -> list[str]:
        """The command line (a subclass may compute it, e.g. from a port chosen later)."""
        return self._args

    # starting
    def spawn(self, args: Sequence[str] | None = None) -> subprocess.Popen[bytes]:
        """Start the child (no readiness check) in a session (so a process group) of its own."""
        mode = "ab" if self.append or self.proc is not None else "wb"
        with open(self.log, mode) as out:
            self.proc = subprocess.Popen(list(args or self.args), stdout=out, stderr=subprocess.STDOUT,
                                         env=self.env, cwd=self.cwd, start_new_session=True)
        return self.proc

    def start(self) -> LocalProcess:
        self.spawn()
        try:
            self.wait_ready()
        except BaseException:
            self.kill()
            raise
        return self

    def wait_ready(self) -> None:
        """Block until the child is ready (by default: listens on ``port`` if one was given)."""
        if self.port is not None:
            wait_for_port(self.port, self.ready_timeout, proc=self, what=self.what)

    # running
    @property
    def popen(self) -> subprocess.Popen[bytes]:
        assert self.proc is not None, "not started"
        return self.proc

    @property
    def pid(self) -> int:
        return self.popen.pid

    def poll(self) -> int | None:
        return self.popen.poll()

    def signal(self, sig: int) -> None:
        """``sig`` to the child itself (not its group): freeze, continue, reload, ..."""
        self.popen.send_signal(sig)

    def output(self) -> str:
        return self.log.read_text(errors="replace") if self.log.exists() else ""

    # stopping
    def kill(self) -> None:
        if self.proc is not None:
            stop_process(self.proc, signal.SIGKILL, timeout=5.0)

    def stop(self, timeout: float = 5.0) -> int | None:
        """SIGCONT, the stop signal to the group, SIGKILL after ``timeout`` s. Returns the exit code."""
        if self.proc is None:
            return None
        return stop_process(self.proc, self.stop_signal, timeout)

    def __enter__(self) -> Any:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


def start_child(stack: ExitStack, args: Sequence[str], log: Path, env: Mapping[str, str] | None = None, *,
                port: int | None = None, what: str | None = None, cwd: Path | str | None = None,
                stop_signal: int = signal.SIGINT, ready_timeout: float = 15.0) -> LocalProcess:
    """Start a child whose stop is registered on ``stack`` first: no child outlives the stack."""
    child = LocalProcess(args, log, env=env, cwd=cwd, stop_signal=stop_signal, port=port, what=what,
                         ready_timeout=ready_timeout)
    stack.callback(child.stop)
    child.spawn()
    child.wait_ready()
    return child


def start_embedded_broker(stack: ExitStack, fleet: Path | str, port: int, log: Path,
                          env: Mapping[str, str] | None = None, *extra: str, log_level: str = "WARNING",
                          ws_port: int = 0) -> LocalProcess:
    """The embedded broker on 127.0.0.1:``port`` for ``fleet`` (no WebSocket unless ``ws_port``), stopped with
    ``stack``; ``extra``: more command-line options (``--limit user_publish_rate=0``, ``--no-acl``, ``--loop``)."""
    args = [sys.executable, "-m", "roslink_mqtt.broker", "--config", str(fleet), "--host", LOOPBACK, "--port",
            str(port), "--ws-port", str(ws_port), "--log-level", log_level, *extra]
    return start_child(stack, args, log, env, port=port, what="embedded broker")


# -- Mosquitto ---------------------------------------------------------------------------------------
def mosquitto_exe() -> str | None:
    """The installed ``mosquitto`` (the OS package puts it in /usr/sbin), or None."""
    exe = shutil.which("mosquitto") or "/usr/sbin/mosquitto"
    return exe if Path(exe).exists() else None


def _run_as() -> str:
    # Started as root, Mosquitto drops to the user 'mosquitto', who cannot read private temporary
    # directories or the 0600 export: it keeps running as the current account instead.
    return f"user {getpass.getuser()}\n"


def mosquitto_conf(port: int, extra_conf: str = "") -> str:
    """A small Mosquitto config: one listener on 127.0.0.1:``port``, no persistence, ``extra_conf`` appended."""
    # set_tcp_nodelay: without it Mosquitto's small replies wait behind Nagle (~40 ms per service call).
    return (f"{_run_as()}listener {port} {LOOPBACK}\npersistence false\nlog_dest stderr\n"
            f"set_tcp_nodelay true\n{extra_conf}\n")


class Mosquitto(LocalProcess):
    """Mosquitto on 127.0.0.1 with the config text ``conf`` (written to ``workdir/conf_name``); stops with SIGTERM.

    Use :meth:`plain` (a loopback listener, ``extra_conf`` appended) or :meth:`exported` (the
    deployed configuration of a fleet). Restartable on the same port; the log is appended to.
    """

    stop_signal = signal.SIGTERM
    fleet: Any = None  # set by exported(): the loaded fleet and the ExportedFiles
    files: Any = None

    def __init__(self, workdir: Path, conf: str, port: int, *, conf_name: str = "mosquitto.conf",
                 log_name: str = "mosquitto.log", exe: str | None = None, ready_timeout: float = 10.0) -> None:
        exe = exe or mosquitto_exe()
        if exe is None:
            raise FileNotFoundError("mosquitto is not installed (apt-get install mosquitto)")
        self.workdir = Path(workdir)
        self.conf = self.workdir / conf_name
        self.conf.write_text(conf)
        super().__init__([exe, "-c", str(self.conf)], self.workdir / log_name, port=port, what="mosquitto",
                         ready_timeout=ready_timeout, append=True)

    @classmethod
    def plain(cls, workdir: Path, extra_conf: str = "", port: int | None = None, **kwargs: Any) -> Mosquitto:
        port = port or free_port()
        return cls(workdir, mosquitto_conf(port, extra_conf), port, **kwargs)

    @classmethod
    def exported(cls, workdir: Path, config: Path, extra_conf: str = "", *, export_dir: str = "mosquitto-export",
                 conf_name: str = "mosquitto-run.conf", **kwargs: Any) -> Mosquitto:
        """Mosquitto running the exact files ``roslink-mqtt acl export`` writes for the fleet ``config``.

        ``extra_conf`` is appended to a copy of the exported mosquitto.conf (plus a ``user`` line,
        see :func:`_run_as`); the port is the fleet's broker port (see :func:`fleet_copy`).
        """
        from .broker.export import export_mosquitto  # amqtt-free
        from .config import load_fleet

        fleet = load_fleet(config)
        files = export_mosquitto(fleet, Path(workdir) / export_dir)
        conf = files.conf.read_text() + f"{_run_as()}{extra_conf}\n"
        mosquitto = cls(workdir, conf, fleet.broker.port, conf_name=conf_name, **kwargs)
        mosquitto.fleet, mosquitto.files = fleet, files
        return mosquitto


    @classmethod
    def exported_dynsec(cls, workdir: Path, config: Path, extra_conf: str = "", *,
                        export_dir: str = "mosquitto-dynsec", conf_name: str = "mosquitto-run.conf",
                        **kwargs: Any) -> Mosquitto:
        """Mosquitto with its dynamic-security plugin, from ``acl export --format mosquitto-dynsec`` of ``config``
        (changed live by ``fleet apply --broker-kind mosquitto``)."""
        from .broker.export_dynsec import export_dynsec  # amqtt-free
        from .config import load_fleet

        fleet = load_fleet(config)
        files = export_dynsec(fleet, Path(workdir) / export_dir)
        conf = files.conf.read_text() + f"{_run_as()}{extra_conf}\n"
        mosquitto = cls(workdir, conf, fleet.broker.port, conf_name=conf_name, **kwargs)
        mosquitto.fleet, mosquitto.files = fleet, files
        return mosquitto


# -- fleet copies ------------------------------------------------------------------------------------
def replace_once(text: str, old: str, new: str) -> str:
    """``text`` with ``old`` replaced by ``new``; ValueError unless ``old`` occurs exactly once.

    ``str.replace`` does nothing when the text it looks for has changed; an edit of a config
    file that silently did not happen makes a test or a benchmark measure something else.
    """
    count = text.count(old)
    if count != 1:
        raise ValueError(f"expected exactly one {old!r} to replace, found {count}")
    return text.replace(old, new)


def fleet_copy(dest: Path, source: Path, *, port: int | None = None, ws_port: int | None = 0,
               edit: Callable[[dict[str, Any]], object] | None = None) -> Path:
    """Write a copy of the fleet file ``source`` to ``dest``, edited as YAML data, and check that it loads.

    ``port`` / ``ws_port`` set the broker's listeners (``port=None`` keeps the file's,
    ``ws_port=0`` turns WebSocket off); ``edit`` changes the parsed document in place (a missing
    key raises, it does not silently change nothing). Comments are not kept.
    """
    import yaml

    from .config import load_fleet

    data = yaml.safe_load(Path(source).read_text())
    broker = data["broker"]
    if port is not None:
        broker["port"] = port
    if ws_port is not None:
        broker["ws_port"] = ws_port
    if edit is not None:
        edit(data)
    dest = Path(dest)
    dest.write_text(yaml.safe_dump(data, sort_keys=False))
    load_fleet(dest)  # fail here, not in a broker, if the edit broke it
    return dest
