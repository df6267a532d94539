"""A RabbitMQ cluster on this machine (Debian's ``rabbitmq-server``, MQTT plugin), for tests and benchmarks.

Each node has its own name, ports, data and log directories and configuration; all listen on 127.0.0.1 only,
with a private epmd port, so nothing here touches (or is disturbed by) a system RabbitMQ. The fleet's logins
and ACLs come from ``roslink-mqtt acl export --format rabbitmq``: each node's ``rabbitmq.conf`` is the exported
one with its own listener, and node 1 loads the exported definitions at boot.

Start order matters in 3.10: node 1 first and alone (its MQTT plugin waits a few seconds for cluster peers,
then forms the client-id Raft cluster), then the others, which join node 1 at boot (classic peer discovery)
and find its Raft cluster at once. Three nodes start in ~15 s on a 2-core machine.

The server programs are run from ``/usr/lib/rabbitmq/bin``: Debian's ``/usr/sbin`` wrappers switch to the
``rabbitmq`` user and its home, which would put every node's files in the system's place.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import time
from pathlib import Path

from .localproc import LOOPBACK, LocalProcess, free_port, tail, wait_for_port

RABBIT_BIN = Path("/usr/lib/rabbitmq/bin")
BOOT_TIMEOUT = 90.0  # s per node: the first boot of a node on a loaded 2-core machine


def rabbitmq_available() -> bool:
    """Whether Debian's rabbitmq-server (with its MQTT plugin) is installed here."""
    return (RABBIT_BIN / "rabbitmq-server").exists() and shutil.which("epmd") is not None


class RabbitNode(LocalProcess):
    """One node: its name, ports and directories under ``root``."""

    def __init__(self, root: Path, index: int, tag: str, epmd_port: int, cookie_home: Path) -> None:
        self.index, self.root = index, root
        self.name = f"rl{index}-{tag}@localhost"
        self.mqtt_port, self.amqp_port, self.dist_port = free_port(), free_port(), free_port()
        root.mkdir(parents=True, exist_ok=True)
        (root / "log").mkdir(exist_ok=True)
        (root / "rabbitmq-env.conf").write_text("")  # keeps /etc/rabbitmq/rabbitmq-env.conf out
        (root / "enabled_plugins").write_text("[rabbitmq_mqtt].\n")
        self.env = {
            **os.environ, "HOME": str(cookie_home), "ERL_EPMD_ADDRESS": LOOPBACK, "ERL_EPMD_PORT": str(epmd_port),
            "RABBITMQ_CONF_ENV_FILE": str(root / "rabbitmq-env.conf"), "RABBITMQ_NODENAME": self.name,
            "RABBITMQ_USE_LONGNAME": "false", "RABBITMQ_NODE_IP_ADDRESS": LOOPBACK,
            "RABBITMQ_NODE_PORT": str(self.amqp_port), "RABBITMQ_DIST_PORT": str(self.dist_port),
            "RABBITMQ_CONFIG_FILE": str(root / "rabbitmq.conf"),
            "RABBITMQ_ADVANCED_CONFIG_FILE": str(root / "advanced.config"),
            "RABBITMQ_ENABLED_PLUGINS_FILE": str(root / "enabled_plugins"),
            "RABBITMQ_MNESIA_BASE": str(root / "mnesia"), "RABBITMQ_MNESIA_DIR": str(root / "mnesia" / "data"),
            "RABBITMQ_LOG_BASE": str(root / "log"), "RABBITMQ_PID_FILE": str(root / "node.pid"),
            # Erlang distribution on loopback only (the node port above covers AMQP, not distribution)
            "RABBITMQ_SERVER_ADDITIONAL_ERL_ARGS": "-kernel inet_dist_use_interface {127,0,0,1}",
            "RABBITMQ_CTL_ERL_ARGS": "-kernel inet_dist_use_interface {127,0,0,1}",
        }
        super().__init__([str(RABBIT_BIN / "rabbitmq-server")], root / "log" / "stdout.log", env=self.env,
                         stop_signal=signal.SIGTERM)

    @property
    def url(self) -> str:
        return f"mqtt://{LOOPBACK}:{self.mqtt_port}"

    def configure(self, exported_conf: str, seed: str | None) -> None:
        """The exported configuration with this node's listeners; ``seed``: the node to join at boot."""
        conf = re.sub(r"(?m)^mqtt\.listeners\.tcp\.default = .*$",
                      f"mqtt.listeners.tcp.default = {LOOPBACK}:{self.mqtt_port}", exported_conf)
        if seed is not None:  # the definitions are cluster-wide: node 1 loads them, the others get them by joining
            conf = re.sub(r"(?m)^load_definitions = .*\n", "", conf)
            conf += ("cluster_formation.peer_discovery_backend = classic_config\n"
                     f"cluster_formation.classic_config.nodes.1 = {seed}\n")
        conf += (f"listeners.tcp.default = {LOOPBACK}:{self.amqp_port}\n"
                 "log.console = false\nlog.file.level = info\n")
        (self.root / "rabbitmq.conf").write_text(conf)

    def boot(self) -> None:
        self.spawn()

    def wait_up(self, timeout: float = BOOT_TIMEOUT) -> None:
        wait_for_port(self.mqtt_port, timeout, proc=self, what=f"RabbitMQ node {self.name}",
                      log=self.root / "log" / f"{self.name}.log")

    def beam_pid(self) -> int | None:
        try:
            return int((self.root / "node.pid").read_text().strip())
        except (OSError, ValueError):
            return None

    def kill(self) -> None:
        """SIGKILL the Erlang VM: the machine lost, as a test's fault."""
        pid = self.beam_pid()
        if pid is not None:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        super().kill()

    def shutdown(self) -> None:
        """SIGTERM to the VM is a clean stop (no CLI boot needed); the group is killed after 20 s regardless."""
        pid = self.beam_pid()
        if pid is not None:
            try:
                os.kill(pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
        self.stop(timeout=20.0)

    def log_tail(self, lines: int = 20) -> str:
        return tail(self.root / "log" / f"{self.name}.log", lines)


class RabbitCluster:
    """``size`` nodes clustered on 127.0.0.1, configured from an export directory (definitions + rabbitmq.conf)."""

    def __init__(self, workdir: Path, export_dir: Path, size: int = 3) -> None:
        if not rabbitmq_available():
            raise RuntimeError("rabbitmq-server is not installed (apt-get install rabbitmq-server)")
        self.workdir, self.export_dir = Path(workdir), Path(export_dir)
        self.epmd_port = free_port()
        home = self.workdir / "home"
        home.mkdir(parents=True, exist_ok=True)
        cookie = home / ".erlang.cookie"
        cookie.write_text(os.urandom(16).hex())
        cookie.chmod(0o400)
        tag = f"{os.getpid()}-{self.epmd_port}"  # node names unique on this machine, across parallel runs
        self.nodes = [RabbitNode(self.workdir / f"n{i}", i, tag, self.epmd_port, home) for i in range(1, size + 1)]

    @property
    def urls(self) -> list[str]:
        return [n.url for n in self.nodes]

    def start(self) -> float:
        """Boot node 1, then the others joining it; return the seconds it took (all MQTT listeners open)."""
        t0 = time.monotonic()
        conf = (self.export_dir / "rabbitmq.conf").read_text()
        seed = self.nodes[0]
        seed.configure(conf, None)
        seed.boot()
        seed.wait_up()
        for node in self.nodes[1:]:
            node.configure(conf, seed.name)
            node.boot()
        for node in self.nodes[1:]:
            node.wait_up()
        return time.monotonic() - t0

    def wait_for_login(self, username: str, password: str, timeout: float = 30.0) -> None:
        """Until ``username`` may log in on every node: node 1 imports the definitions asynchronously at boot."""
        deadline = time.monotonic() + timeout
        while not all(login_works(n.mqtt_port, username, password) for n in self.nodes):
            if time.monotonic() > deadline:
                raise TimeoutError(f"{username} cannot log in on every node {timeout:g} s after the cluster started "
                                   f"(were the definitions imported?):\n{self.nodes[0].log_tail()}")
            time.sleep(0.3)

    def ctl(self, *args: str, node: int = 0, timeout: float = 60.0) -> str:
        """``rabbitmqctl`` against a node (index from 0); raises with its output when it fails."""
        target = self.nodes[node]
        done = subprocess.run([str(RABBIT_BIN / "rabbitmqctl"), "-n", target.name, *args], env=target.env,
                              capture_output=True, text=True, timeout=timeout)
        if done.returncode != 0:
            raise RuntimeError(f"rabbitmqctl {' '.join(args)} on {target.name}: {done.stdout}{done.stderr}")
        return done.stdout

    def running_nodes(self) -> set[str]:
        """The nodes the cluster sees running (from node 1's point of view, or the first alive one)."""
        for i, node in enumerate(self.nodes):
            if node.poll() is None:
                out = self.ctl("eval", "rabbit_nodes:all_running().", node=i)
                return set(re.findall(r"'([^']+)'", out))
        return set()

    def stop(self) -> None:
        for node in self.nodes:
            node.shutdown()
        subprocess.run(["epmd", "-kill"], env={**os.environ, "ERL_EPMD_PORT": str(self.epmd_port)},
                       capture_output=True, timeout=10)

    def __enter__(self) -> RabbitCluster:
        try:
            self.start()
        except BaseException:
            self.stop()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def login_works(port: int, username: str, password: str) -> bool:
    """Whether an MQTT login is accepted on ``port`` now (CONNACK 0)."""
    import queue

    from .mqtt import make_client

    client = make_client(f"login-probe-{time.monotonic_ns()}", username=username, password=password,
                         url=f"mqtt://{LOOPBACK}:{port}")
    codes: queue.Queue[int] = queue.Queue()
    client.on_connect = lambda _c, _u, _f, rc, _p: codes.put(rc.value)
    try:
        client.connect(LOOPBACK, port, keepalive=10)
        client.loop_start()
        return codes.get(timeout=5) == 0
    except (OSError, queue.Empty):
        return False
    finally:
        client.disconnect()
        client.loop_stop()
