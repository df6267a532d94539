"""rosbridge as a peer row for bench/weak_link.py: the same simulated robot served by rosbridge, timed at a client.

The peer is the Rust rosbridge server from PyPI (``rosbridge-server-rs``), run on this project's ROS 2 Jazzy
wheels instead of a sourced /opt/ros, and a client that records how old each odometry message is when it arrives
(arrival − ``header.stamp``, one wall clock: everything runs on this machine).

Why the environment is unusual (:func:`rosbridge_env`): the server is a native binary linked against ``librcl``,
``librmw_implementation`` and ``librosidl_runtime_c``, and the wheels lay those out for rclpy, not for a C program:

* the wheels' libraries are in ``<venv>/lib`` and their private dependencies (OpenSSL, tinyxml2, lttng, yaml) in
  ``site-packages/ros_*.libs``; rclpy finds them because ``ros_wheels_bootstrapper.pth`` re-executes Python with
  them on ``LD_LIBRARY_PATH``, a binary has to be given the same path;
* the wheels ship no ``librmw_implementation.so`` (their ``librcl.so`` links the Fast DDS RMW directly): a symlink
  of that name to ``librmw_fastrtps_cpp.so`` in a private directory stands in for it (the RMW exports the same
  ``rmw_*`` API, and the loader then sees one library, not two);
* ``librcl.so`` needs the ``*__rosidl_generator_py.so`` libraries, which use the Python C API without linking
  libpython (they expect to be loaded into a Python process): libpython is preloaded;
* its built-in rosapi needs ``rosapi_msgs``, which no wheel provides: ``--no-rosapi`` (the bench needs no rosapi);
* without ``--config`` the server writes and reads ``~/.rosbridge_server_rs/rosbridge.toml``: it gets an empty
  file of its own, so nobody's settings there change a row;
* the wheel's binaries install without their execute bit (the wheel stores their mode without the regular-file
  type, so pip does not mark them executable) and its ``rosbridge-server-rs`` launcher needs ``ROS_DISTRO``: the
  binary is run directly, from a private executable copy when needed.

DDS stays on this machine as for every ROS process here (:mod:`roslink_mqtt.ros_env`): localhost discovery, the
loopback-only Fast DDS profile and the caller's ``ROS_DOMAIN_ID``. The WebSocket listens on 127.0.0.1 only (the
server's default is 0.0.0.0:9090).

Direction on the shaped link: ``roslink_mqtt.shaped_link``'s "up" is client → target. The MQTT bridge is the
client of its link, rosbridge is the *target* of the viewer's connection, so the robot's uplink is the proxy's
``--down-kbit`` here (:func:`shaped_link_args`).
"""

from __future__ import annotations

import atexit
import contextlib
import importlib.util
import json
import os
import shutil
import signal
import subprocess
import sys
import sysconfig
import tempfile
import threading
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from roslink_mqtt.localproc import LOOPBACK, start_child
from roslink_mqtt.ros_env import local_ros_env

ODOM_TOPIC = "/odom"  # the simulated robot (python -m roslink_mqtt.sim, no namespace) publishes odom at 20 Hz
ODOM_TYPE = "nav_msgs/msg/Odometry"
BINARY_VAR = "ROSBRIDGE_RS_BIN"  # an explicit path to the server binary wins over the installed package's
DISTRO = "jazzy"  # the project's wheels; the package also holds a humble build
READY_TIMEOUT = 15.0  # s for the server to listen (it loads rcl and creates a DDS participant first)

_private_dir: Path | None = None


def _private() -> Path:
    """A directory of this process for the ``librmw_implementation.so`` stand-in and an executable copy of the
    server: never shared with another run (whose venv may differ), removed when this process exits."""
    global _private_dir
    if _private_dir is None or not _private_dir.is_dir():
        _private_dir = Path(tempfile.mkdtemp(prefix="roslink-rosbridge-"))
        atexit.register(shutil.rmtree, _private_dir, True)
    return _private_dir


def ros_wheel_dirs() -> tuple[Path, Path]:
    """``(venv lib, site-packages)`` of the ROS wheels this interpreter imports rclpy from (found, not imported)."""
    spec = importlib.util.find_spec("rclpy")
    if spec is None or spec.origin is None:
        raise RuntimeError("rclpy is not installed in this interpreter: install the project's [bridge] extra")
    site = Path(spec.origin).resolve().parents[1]
    lib = site.parents[1]  # <venv>/lib/pythonX.Y/site-packages -> <venv>/lib
    if not (lib / "librmw_fastrtps_cpp.so").is_file():
        raise RuntimeError(f"no librmw_fastrtps_cpp.so in {lib}: the ROS wheels are not laid out as expected")
    return lib, site


def libpython() -> Path:
    """The shared libpython of this interpreter (the one the wheels' ``*_generator_py`` libraries were built for)."""
    name = sysconfig.get_config_var("INSTSONAME") or sysconfig.get_config_var("LDLIBRARY")
    libdir = sysconfig.get_config_var("LIBDIR")
    path = Path(libdir or "", name or "")
    if not name or not name.startswith("libpython") or not path.is_file():
        raise RuntimeError(f"this Python has no shared libpython ({path}): rosbridge on the ROS wheels needs one "
                           "(build Python with --enable-shared)")
    return path


def _path_list(*parts: str | Path | None) -> str:
    """Join path entries, first occurrence wins, empty ones dropped (a stray ``::`` would mean the cwd)."""
    seen: list[str] = []
    for part in parts:
        for entry in str(part or "").split(os.pathsep):
            if entry and entry not in seen:
                seen.append(entry)
    return os.pathsep.join(seen)


def rosbridge_env(base_env: Mapping[str, str]) -> dict[str, str]:
    """The environment to run the rosbridge server against this project's ROS wheels, from ``base_env``.

    ``base_env`` must already carry a ``ROS_DOMAIN_ID`` (:func:`roslink_mqtt.ros_env.apply_local_ros_env`): the
    server must join the sim's graph, and a default of 0 could join a stranger's. Loopback-only DDS (localhost
    discovery, the project's loopback Fast DDS profile) is applied again here whatever ``base_env`` says.
    """
    raw = base_env.get("ROS_DOMAIN_ID", "").strip()
    if not raw.isdigit():
        raise ValueError("base_env has no ROS_DOMAIN_ID: build it with roslink_mqtt.ros_env.local_ros_env / "
                         "apply_local_ros_env first")
    env = local_ros_env(int(raw), dict(base_env))  # localhost discovery, the project's loopback profile, Fast DDS
    lib, site = ros_wheel_dirs()
    private = _private()
    shim = private / "librmw_implementation.so"
    if not shim.exists():
        shim.symlink_to(lib / "librmw_fastrtps_cpp.so")
    ros_libs = sorted(str(p) for p in site.glob("ros_*.libs") if p.is_dir())
    env["LD_LIBRARY_PATH"] = _path_list(private, lib, *ros_libs, base_env.get("LD_LIBRARY_PATH"))
    env["LD_PRELOAD"] = _path_list(libpython(), base_env.get("LD_PRELOAD"))
    # the server reads message definitions from the ament index (share/ament_index/... of the venv)
    env["AMENT_PREFIX_PATH"] = _path_list(lib.parent, base_env.get("AMENT_PREFIX_PATH"))
    env["ROS_DISTRO"] = DISTRO
    env["NO_COLOR"] = "1"  # plain log lines in the log file
    return env


def rosbridge_binary() -> Path:
    """The server binary: ``$ROSBRIDGE_RS_BIN``, else the Jazzy build in the installed ``rosbridge_server_rs``
    package, copied to a private executable file when pip installed it without its execute bit."""
    explicit = os.environ.get(BINARY_VAR)
    if explicit:
        return Path(explicit)
    spec = importlib.util.find_spec("rosbridge_server_rs")
    if spec is None or spec.origin is None:
        raise FileNotFoundError("rosbridge-server-rs is not installed: pip install 'rosbridge-server-rs==0.1.6' "
                                f"(or set {BINARY_VAR})")
    binary = Path(spec.origin).with_name(f"rosbridge_server_rs_{DISTRO}")
    if not binary.is_file():
        raise FileNotFoundError(f"{binary} is missing from the rosbridge-server-rs package")
    if os.access(binary, os.X_OK):
        return binary
    copy = _private() / binary.name
    if not copy.exists():
        shutil.copy2(binary, copy)
        copy.chmod(0o755)
    return copy


def start_rosbridge(stack: contextlib.ExitStack, port: int, env: Mapping[str, str], log: Path, *,
                    extra_args: tuple[str, ...] = (), log_level: str = "info",
                    ready_timeout: float = READY_TIMEOUT) -> subprocess.Popen:
    """Start the server on 127.0.0.1:``port`` with ``env`` (see :func:`rosbridge_env`), its output in ``log``.

    Returns once the port accepts connections; raises ``ChildExited`` (with the log's tail) as soon as the server
    dies first, ``TimeoutError`` after ``ready_timeout`` s. Its stop (SIGINT, SIGKILL 5 s later, to its whole
    process group) is registered on ``stack`` before it starts, so it never outlives the stack.
    """
    # An empty config file of our own: without --config the server creates and reads ~/.rosbridge_server_rs/
    # rosbridge.toml, where someone's settings (topic globs, queue sizes) would change what the row measures.
    config = _private() / "rosbridge.toml"
    if not config.exists():
        config.write_text("# every setting at its default; the command line sets the rest\n")
    args = [str(rosbridge_binary()), "--config", str(config), "--bind", f"{LOOPBACK}:{port}", "--no-rosapi",
            "--log-level", log_level, *extra_args]
    child = start_child(stack, args, log, env, port=port, what="rosbridge-server-rs", stop_signal=signal.SIGINT,
                        ready_timeout=ready_timeout)
    return child.popen


def shaped_link_args(listen_port: int, rosbridge_port: int, kbit: float, *, delay_ms: float, down_factor: float,
                     hidden: bool = False) -> list[str]:
    """``python -m roslink_mqtt.shaped_link`` arguments for a viewer → rosbridge link whose *robot uplink* is
    ``kbit``: the robot is the link's target here, so its uplink is the proxy's down direction."""
    return [sys.executable, "-m", "roslink_mqtt.shaped_link", "--listen", f"{LOOPBACK}:{listen_port}", "--to",
            f"{LOOPBACK}:{rosbridge_port}", "--delay-ms", str(delay_ms),
            *reversed_link(["--jitter-ms", "0", "--up-kbit", str(kbit), "--down-kbit", str(kbit * down_factor)]),
            *(["--hidden-queue"] if hidden else [])]


SWAPPED = {"--up-kbit": "--down-kbit", "--down-kbit": "--up-kbit", "--phases": "--down-phases",
           "--down-phases": "--phases"}


def reversed_link(robot_side: list[str]) -> list[str]:
    """shaped_link options written from the robot's side (up: robot → broker) for a link whose target is the robot
    (a viewer dialling rosbridge): every direction-bound option swapped."""
    return [SWAPPED.get(arg, arg) for arg in robot_side]


def stamp_seconds(msg: Mapping[str, Any]) -> float | None:
    """``header.stamp`` of a rosbridge JSON message in seconds (ROS 2 ``sec``/``nanosec``; ROS 1 names too)."""
    try:
        stamp = msg["header"]["stamp"]
        sec = stamp["sec"] if "sec" in stamp else stamp["secs"]
        nsec = stamp["nanosec"] if "nanosec" in stamp else stamp["nsecs"]
        return float(sec) + float(nsec) / 1e9
    except (KeyError, TypeError, ValueError):
        return None


def client_backend() -> str:
    """``roslibpy`` when it is installed (the usual Python rosbridge client), else ``websockets``."""
    return "roslibpy" if importlib.util.find_spec("roslibpy") is not None else "websockets"


class OdomAges:
    """A rosbridge client subscribed to the robot's odometry that records each message's age on arrival.

    ``throttle_rate`` (ms between messages) and ``queue_length`` go to rosbridge's ``subscribe`` as they are: the
    server then holds or drops messages on the robot's side, which is part of what the row measures.
    ``backend``: ``roslibpy`` (Twisted or asyncio underneath, ``transport``), ``websockets`` (this project's
    WebSocket library: the JSON protocol by hand, one reader thread), or ``auto`` (:func:`client_backend`).
    Ages are kept until :meth:`take`; :attr:`statuses` keeps the server's status/error messages (websockets only);
    :attr:`disconnects` counts connections lost before :meth:`close` (a server may drop a client whose outbound
    queue overflows on a thin link: roslibpy then reconnects and subscribes again, the websockets client stops).
    """

    def __init__(self, url: str, topic: str = ODOM_TOPIC, msg_type: str = ODOM_TYPE, *, throttle_rate: int = 0,
                 queue_length: int = 0, backend: str = "auto", transport: str | None = None,
                 connect_timeout: float = 10.0, clock: Callable[[], float] = time.time) -> None:
        self.url, self.topic, self.msg_type = url, topic, msg_type
        self.throttle_rate, self.queue_length = int(throttle_rate), int(queue_length)
        self.backend = client_backend() if backend == "auto" else backend
        if self.backend not in ("roslibpy", "websockets"):
            raise ValueError(f"backend: roslibpy, websockets or auto, not {backend!r}")
        self.clock = clock
        self.received = 0
        self.disconnects = 0
        self.statuses: list[str] = []
        self._ages: list[float] = []
        self.timed: list[tuple[float, float]] = []  # (time.monotonic() on arrival, age) of every message, kept
        self._lock = threading.Lock()
        self._first = threading.Event()
        self._stop = threading.Event()
        self._closed = False
        self._ros: Any = None
        self._listener: Any = None
        self._ws: Any = None
        self._reader: threading.Thread | None = None
        if self.backend == "roslibpy":
            self._open_roslibpy(transport, connect_timeout)
        else:
            self._open_websockets(connect_timeout)

    # recording
    def _record(self, msg: Mapping[str, Any], arrived: float) -> None:
        stamp = stamp_seconds(msg)
        if stamp is None:
            return
        with self._lock:
            self._ages.append(arrived - stamp)
            self.timed.append((time.monotonic(), arrived - stamp))
            self.received += 1
        self._first.set()

    def wait_first(self, timeout: float) -> bool:
        """Whether a message arrived within ``timeout`` s (DDS discovery and the subscription take a moment)."""
        return self._first.wait(timeout)

    def take(self) -> list[float]:
        """The ages (s) recorded since the last call, oldest first; recording goes on."""
        with self._lock:
            ages, self._ages = self._ages, []
        return ages

    def subscribe_message(self) -> dict[str, Any]:
        return {"op": "subscribe", "id": f"odom_ages_{id(self):x}", "topic": self.topic, "type": self.msg_type,
                "throttle_rate": self.throttle_rate, "queue_length": self.queue_length}

    # roslibpy
    def _open_roslibpy(self, transport: str | None, timeout: float) -> None:
        import roslibpy

        parts = urlsplit(self.url)
        self._ros = roslibpy.Ros(parts.hostname or LOOPBACK, parts.port or 9090, is_secure=parts.scheme == "wss",
                                 transport=transport)
        self._ros.on("close", self._lost)
        try:
            self._ros.run(timeout=timeout)
        except Exception:
            self._stop_roslibpy()
            raise
        self._listener = roslibpy.Topic(self._ros, self.topic, self.msg_type, throttle_rate=self.throttle_rate,
                                        queue_length=self.queue_length)
        # roslibpy calls back after its own json.loads; the clock is read first thing there
        self._listener.subscribe(lambda msg: self._record(msg, self.clock()))

    def _stop_roslibpy(self) -> None:
        """Close without stopping roslibpy's event loop: Twisted's reactor cannot start again in this process, and
        the next row's client needs it. Reconnecting is turned off first (a closed server would be retried)."""
        ros, self._ros = self._ros, None
        if ros is None:
            return
        stop_trying = getattr(ros.factory, "stopTrying", None)  # Twisted's ReconnectingClientFactory
        if stop_trying is not None:
            ros.call_later(0, stop_trying)
        with contextlib.suppress(Exception):  # a server already gone: nothing to close
            ros.close(timeout=2)

    def _lost(self, *_: object) -> None:
        if not self._closed:
            self.disconnects += 1

    # websockets (sync client)
    def _open_websockets(self, timeout: float) -> None:
        import inspect

        from websockets.sync.client import connect

        # no compression: the server offers none, and deflate would only cost the client CPU; no pings: a thin
        # link's queue would delay the pong and close a healthy connection
        options: dict[str, Any] = {"open_timeout": timeout, "compression": None, "max_size": None,
                                   "ping_interval": None, "close_timeout": 2}
        if "proxy" in inspect.signature(connect).parameters:  # websockets >= 15 reads proxies from the environment:
            options["proxy"] = None  # a loopback benchmark never goes through one
        self._ws = connect(self.url, **options)
        self._ws.send(json.dumps(self.subscribe_message()))
        self._reader = threading.Thread(target=self._read, name="odom-ages", daemon=True)
        self._reader.start()

    def _read(self) -> None:
        from websockets.exceptions import ConnectionClosed

        while not self._stop.is_set():
            try:
                data = self._ws.recv(timeout=0.2)
            except TimeoutError:
                continue
            except ConnectionClosed:
                self._lost()
                return
            arrived = self.clock()
            try:
                frame = json.loads(data)
            except ValueError:
                continue
            op = frame.get("op")
            if op == "publish" and frame.get("topic") == self.topic:
                self._record(frame.get("msg") or {}, arrived)
            elif op == "status":
                self.statuses.append(f"{frame.get('level', '')}: {frame.get('msg', '')}"[:300])

    # closing
    def close(self) -> None:
        """Unsubscribe and disconnect (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        if self._ros is not None:
            if self._listener is not None:
                with contextlib.suppress(Exception):
                    self._listener.unsubscribe()
            self._stop_roslibpy()
        if self._ws is not None:
            with contextlib.suppress(Exception):
                self._ws.close()
            if self._reader is not None:
                self._reader.join(3)

    def __enter__(self) -> OdomAges:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
