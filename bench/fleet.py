"""Benchmark: a whole fleet on one broker — how many robots each broker carries before latency or loss gives.

    .venv/bin/python bench/fleet.py [--quick] [--brokers embedded,mosquitto,rabbitmq] [--robots 10,50,...] [--plot PATH]

Every simulated robot behaves like turtle1's bridge on the wire, without ROS: one MQTT connection of its own
(its login, a last-will that marks it offline), a retained ROSLink heartbeat at 1 Hz, ``state/global_motion``
at 10 Hz, subscriptions to its ``from/+/#`` commands and its operator's presence. Every robot has its own
operator, one connection each: retained presence at 1 Hz, twist commands at 10 Hz. One fleet monitor (an
admin login) subscribes ``roslink/+/state/global_motion``. A message carries the sender's
``time.monotonic_ns()``; the receiver takes the latency (one clock for every process on the machine).

The load generator is asyncio (uvloop) with gmqtt clients — one MQTT connection per robot and per operator,
never batched — in two worker processes plus the monitor's; each reports its CPU, so a row where the
generator, not the broker, was the limit says so. For each robot count: whole-fleet connect time, then a
2 s warm-up and a measured window; delivered/sent and p50/p99/max latency of state (robot -> monitor) and
commands (operator -> robot); broker CPU (% of one core) and RSS, and its memory per idle connection. A
broker's series stops at the first count that misses the bar (p99 < 50 ms, nothing lost).

Brokers: the embedded one (as deployed), Mosquitto running ``roslink-mqtt acl export``'s files, and a three-node
RabbitMQ cluster from ``acl export --format rabbitmq`` (robot i on node i mod 3, its operator on the next node,
the monitor on the third: state and commands cross nodes; CPU and RSS are the three nodes' sum). Fleet files are
generated (one password for every login, hashed once). Never asserts on timing.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import statistics
import sys
import tempfile
import time
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import latency as lat  # (bench/latency.py: the process helpers shared by the benches)
import orjson
import yaml
from _support import cpu_seconds, rss_bytes

from roslink_mqtt.topics import TopicTree

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_PLOT = ROOT / "docs" / "performance" / "fleet.png"
PASSWORD = "fleet-bench"
MONITOR = "fleetmon"
PREFIX = "roslink"
BAR_P99_MS = 50.0
WARMUP = 2.0
SETTLE = 2.0
WORKERS = 2
LOAD_TOPIC = "$SYS/broker/load"
DEFAULT_COUNTS = {"embedded": (10, 100, 200), "mosquitto": (10, 300, 1000), "rabbitmq": (10, 100, 300)}


def robot_name(i: int) -> str:
    return f"r{i:04d}"


def operator_name(i: int) -> str:
    return f"op{i:04d}"


# -- the fleet file ------------------------------------------------------------------------------------------
def fleet_file(path: Path, robots: int, port: int, users: dict[str, str] | None = None) -> Path:
    """``robots`` robots, one operator each, a monitor; one password hashed once (the bench is not about logins).
    ``users``: more logins without grants, name -> password hash (bench/login_flood.py's, at the deployed strength)."""
    from roslink_mqtt.config.passwords import hash_password

    hashed = hash_password(PASSWORD, iterations=1000)  # weak on purpose: this bench measures messages
    data: dict[str, Any] = {
        "prefix": PREFIX,
        "broker": {"host": "127.0.0.1", "port": port, "ws_port": 0},
        "robots": {robot_name(i): {"system_id": i + 1, "key": f"key-{robot_name(i)}", "type": "ground",
                                   "password": hashed} for i in range(robots)},
        "users": {operator_name(i): {"password": hashed, "grants": [{"key": f"key-{robot_name(i)}",
                                                                     "role": "operator"}]} for i in range(robots)},
    }
    data["users"][MONITOR] = {"password": hashed, "admin": True}
    for user, password_hash in (users or {}).items():
        data["users"][user] = {"password": password_hash, "grants": []}
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


# -- the load generator (child processes) --------------------------------------------------------------------
def envelope(message_id: int, system_id: int, payload: dict[str, Any]) -> bytes:
    from roslink_mqtt.protocol import Envelope, encode

    return encode(Envelope(message_id, payload, system_id, 0))


@dataclass
class Tally:
    sent: int = 0
    latencies: list[float] = field(default_factory=list)  # ms of messages sent inside the window
    received: int = 0  # of messages sent inside the window


async def generator(role: str, first: int, count: int, ports: list[int], start_at: float, seconds: float,
                    with_presence: bool = True) -> dict[str, Any]:
    """One worker: robots and operators ``first .. first+count-1`` (role "fleet"), or the monitor (role "monitor").

    ``ports``: the broker's, or a cluster's nodes: robot i on node i, its operator on the next, the monitor on the
    last (so state and commands cross nodes).
    """
    import gmqtt
    from gmqtt.mqtt.constants import MQTTv311

    from roslink_mqtt.presence import operator_heartbeat
    from roslink_mqtt.protocol import MessageId

    topics = TopicTree(PREFIX)
    window = (start_at, start_at + seconds)
    state, cmd = Tally(), Tally()
    clients: list[Any] = []
    lost: list[str] = []  # client ids whose connection the broker ended before the run did
    load: dict[str, Any] = {}  # the embedded broker's $SYS/broker/load, as the monitor saw it
    ending = False

    def in_window(ns: int) -> bool:
        return window[0] <= ns / 1e9 < window[1]

    def timed(tally: Tally) -> Any:
        def on_message(_client: Any, _topic: str, payload: bytes, _qos: int, _props: Any) -> int:
            now = time.monotonic_ns()
            body = orjson.loads(payload)
            sent = body.get("payload", {}).get("t") if isinstance(body, dict) else None
            if isinstance(sent, int) and in_window(sent):
                tally.received += 1
                tally.latencies.append((now - sent) / 1e6)
            return 0
        return on_message

    async def connect(client_id: str, login: str, will: Any = None, on_message: Any = None, node: int = 0) -> Any:
        client = gmqtt.Client(client_id, will_message=will, clean_session=True)
        client.set_auth_credentials(login, PASSWORD)
        client.set_config({"reconnect_retries": 0})
        client.on_disconnect = lambda *_args: None if ending else lost.append(client_id)
        if on_message is not None:
            client.on_message = on_message
        await client.connect("127.0.0.1", ports[node % len(ports)], keepalive=30, version=MQTTv311)
        clients.append(client)
        return client

    async def periodic(period: float, phase: float, send: Any, tally: Tally | None) -> None:
        """``send(t_ns)`` every ``period`` from ``window[0] - WARMUP`` to the window's end, on absolute deadlines."""
        k, begin = 0, window[0] - WARMUP + phase
        while True:
            due = begin + k * period
            if due >= window[1]:
                return
            if (delay := due - time.monotonic()) > 0:
                await asyncio.sleep(delay)
            ns = time.monotonic_ns()
            send(ns)
            if tally is not None and in_window(ns):
                tally.sent += 1
            k += 1

    began = time.monotonic()
    tasks = []
    if role == "monitor":
        motion = timed(state)

        def on_message(client: Any, topic: str, payload: bytes, qos: int, props: Any) -> int:
            if topic == LOAD_TOPIC:  # the embedded broker's overload status (others have none)
                body = orjson.loads(payload)
                load["overloaded"] = load.get("overloaded", False) or body.get("overloaded", False)
                load["shed"] = max(load.get("shed", 0), body.get("shed_total", 0))
                return 0
            return motion(client, topic, payload, qos, props)

        client = await connect(f"{MONITOR}-{os.getpid()}", MONITOR, on_message=on_message, node=len(ports) - 1)
        client.subscribe(topics.state_filter(name="global_motion"), qos=0)
        client.subscribe(LOAD_TOPIC, qos=0)
    else:
        connected = []
        for i in range(first, first + count):
            robot, operator = robot_name(i), operator_name(i)
            heartbeat_topic = topics.heartbeat(robot)
            offline = envelope(MessageId.HEARTBEAT, i + 1, {"type": 1, "name": robot, "system_status": 0})
            will = gmqtt.Message(heartbeat_topic, offline, qos=1, retain=True)
            connected.append(connect(f"roslink-bridge-{robot}", robot, will, timed(cmd), node=i))
            presence_topic = topics.operator(operator, f"{operator}-bench")
            clear = gmqtt.Message(presence_topic, b"", qos=1, retain=True)
            connected.append(connect(f"{operator}-bench", operator, clear, node=i + 1))
        done = await asyncio.gather(*connected)
        for j, i in enumerate(range(first, first + count)):
            robot, operator = robot_name(i), operator_name(i)
            robot_client, op_client = done[2 * j], done[2 * j + 1]
            robot_client.subscribe(topics.from_user_filter(robot), qos=1)
            robot_client.subscribe(topics.operators_of(operator), qos=1)
            phase = (i % 100) / 1000  # spread the fleet's messages over the 100 ms period
            heartbeat = envelope(MessageId.HEARTBEAT, i + 1, {"type": 1, "name": robot, "system_status": 4})
            heartbeat_topic = topics.heartbeat(robot)  # (this robot's: a heartbeat to another's topic is refused)
            motion_topic, twist_topic = topics.state(robot, "global_motion"), topics.command(robot, operator, "twist")
            presence_topic = topics.operator(operator, f"{operator}-bench")

            def motion(ns: int, c: Any = robot_client, t: str = motion_topic, sid: int = i + 1) -> None:
                c.publish(t, orjson.dumps({"roslink_version": 2, "message_id": 33, "system_id": sid,
                                           "payload": {"t": ns, "x": 1.0, "y": 2.0, "yaw": 0.5}}), qos=0)

            def twist(ns: int, c: Any = op_client, t: str = twist_topic) -> None:
                c.publish(t, orjson.dumps({"roslink_version": 2, "message_id": 100,
                                           "payload": {"t": ns, "lx": 0.1, "az": 0.2}}), qos=0)

            def beat(_ns: int, c: Any = robot_client, t: str = heartbeat_topic, body: bytes = heartbeat) -> None:
                c.publish(t, body, qos=1, retain=True)

            def present(_ns: int, c: Any = op_client, t: str = presence_topic, user: str = operator) -> None:
                c.publish(t, operator_heartbeat(user, f"{user}-bench"), qos=1, retain=True)

            tasks += [periodic(0.1, phase, motion, state), periodic(0.1, phase + 0.05, twist, cmd),
                      periodic(1.0, phase, beat, None)]
            if with_presence:
                tasks.append(periodic(1.0, phase + 0.5, present, None))
    connect_seconds = time.monotonic() - began
    await asyncio.gather(*tasks)
    await asyncio.sleep(max(0.0, window[1] + SETTLE - time.monotonic()))
    ending = True
    for client in clients:
        try:
            await asyncio.wait_for(client.disconnect(), 2)
        except (TimeoutError, OSError):
            pass
    return {"connect_s": connect_seconds, "state_sent": state.sent, "cmd_sent": cmd.sent,
            "state_received": state.received, "cmd_received": cmd.received,
            "state_ms": state.latencies, "cmd_ms": cmd.latencies, "cpu_s": time.process_time(),
            "lost_connections": len(lost), "load": load}


def worker_main(args: argparse.Namespace) -> int:
    import uvloop

    ports = [int(p) for p in args.ports.split(",")]
    result = uvloop.run(generator(args.role, args.first, args.count, ports, args.start_at, args.seconds,
                                  not args.no_presence))
    args.out.write_bytes(orjson.dumps(result))
    return 0


# -- one step --------------------------------------------------------------------------------------------------
@dataclass
class Step:
    broker: str
    robots: int
    seconds: float
    connect_s: float = float("nan")
    state_sent: int = 0
    state_received: int = 0
    cmd_sent: int = 0
    cmd_received: int = 0
    state_ms: list[float] = field(default_factory=list)
    cmd_ms: list[float] = field(default_factory=list)
    broker_cpu: float = float("nan")  # % of one core in the window
    broker_rss: int = 0
    per_connection: float = float("nan")  # bytes of broker RSS per idle connection
    generator_cpu: float = float("nan")  # % of one core, all generator processes together, whole run
    lost_connections: int = 0  # robots' and operators' connections the broker ended during the run
    shed: int | None = None  # superseded state messages the embedded broker shed while overloaded (None: no status)
    broker_pids: list[int] = field(default_factory=list)
    note: str = ""

    def pct(self, values: list[float], q: int) -> float:
        if len(values) < 2:
            return values[0] if values else float("nan")
        return statistics.quantiles(values, n=100, method="inclusive")[q - 1]

    @property
    def passed(self) -> bool:
        complete = self.state_sent and self.state_received >= self.state_sent and self.cmd_received >= self.cmd_sent
        return bool(complete) and max(self.pct(self.state_ms, 99), self.pct(self.cmd_ms, 99)) < BAR_P99_MS


def run_step(kind: str, robots: int, work: Path, env: dict[str, str], seconds: float, loop: str = "auto",
             presence: bool = True, cluster: Any = None, reader: str = "inline",
             users: dict[str, str] | None = None, during: Any = None) -> Step | None:
    """One count on one broker; ``cluster`` (kind "rabbitmq"): a running RabbitCluster whose fleet covers it.
    ``during(phase, port, start_at, step)``: started once the fleet is connected, before the warm-up (another load
    beside the fleet's, e.g. bench/login_flood.py's guessers); ``users``: see fleet_file."""
    names = {"embedded": "embedded", "mosquitto": "Mosquitto", "rabbitmq": "RabbitMQ ×3"}
    name = names[kind]
    if kind == "embedded":
        name += "".join(f" ({part})" for part in (loop if loop != "auto" else "",
                                                   "amqtt reader" if reader != "inline" else "") if part)
    step = Step(name, robots, seconds)
    with ExitStack() as phase:
        port = lat.free_port()
        ports = [port]
        if kind == "rabbitmq":
            ports = [n.mqtt_port for n in cluster.nodes]
            broker_pids = [n.beam_pid() for n in cluster.nodes]
        else:
            fleet = fleet_file(work / f"fleet-{kind}-{robots}.yaml", robots, port, users)
        if kind == "rabbitmq":
            pass
        elif kind == "embedded":
            broker_pids = [lat.start_embedded_broker(phase, fleet, port, work / f"embedded-{robots}.log", env,
                                                     "--loop", loop, "--reader", reader).pid]
        else:
            if lat.mosquitto_exe() is None:
                return None
            mosquitto = lat.Mosquitto.exported(work, fleet, export_dir=f"mosquitto-{robots}")
            phase.callback(mosquitto.stop)
            mosquitto.start()
            broker_pids = [mosquitto.pid]
        rss_idle = sum(map(rss_bytes, broker_pids))
        connect_budget = 2.5 + robots * 0.02  # measured: 1,000 robots and operators connect in ~2 s
        start_at = time.monotonic() + connect_budget + WARMUP
        outs, children = [], []
        split = [robots // WORKERS + (1 if w < robots % WORKERS else 0) for w in range(WORKERS)]
        plan = [("monitor", 0, 0)] + [("fleet", sum(split[:w]), split[w]) for w in range(WORKERS) if split[w]]
        for n, (role, first, count) in enumerate(plan):
            out = work / f"gen-{kind}-{robots}-{n}.json"
            outs.append(out)
            children.append(lat.start_child(phase, [sys.executable, str(Path(__file__).resolve()), "--worker",
                                                    "--role", role, "--first", str(first), "--count", str(count),
                                                    "--ports", ",".join(map(str, ports)), "--start-at",
                                                    repr(start_at), "--seconds",
                                                    str(seconds), "--out", str(out)]
                                            + (["--no-presence"] if not presence else []),
                                            work / f"gen-{kind}-{robots}-{n}.log", env))
        # idle connections: everyone is connected before the warm-up starts sending
        if (delay := start_at - WARMUP - 0.2 - time.monotonic()) > 0:
            time.sleep(delay)
        rss_connected = sum(map(rss_bytes, broker_pids))
        step.broker_pids = broker_pids
        if during is not None:
            during(phase, port, start_at, step)
        # (an Erlang VM's heap moves by more than a small fleet's connections: not shown when it shrank)
        grown = rss_connected - rss_idle
        step.per_connection = grown / (2 * robots + 1) if grown > 0 else float("nan")
        time.sleep(max(0.0, start_at - time.monotonic()))
        cpu0 = sum(map(cpu_seconds, broker_pids))
        time.sleep(max(0.0, start_at + seconds - time.monotonic()))
        step.broker_cpu = 100 * (sum(map(cpu_seconds, broker_pids)) - cpu0) / seconds
        step.broker_rss = sum(map(rss_bytes, broker_pids))
        for child in children:
            try:
                child.popen.wait(timeout=SETTLE + 30)
            except Exception:  # noqa: BLE001  (a stuck generator is stopped by the ExitStack and named below)
                step.note = "a generator overran"
    reports = [orjson.loads(out.read_bytes()) for out in outs if out.exists()]
    if len(reports) != len(outs):
        failed_log = work / f"gen-{kind}-{robots}-1.log"
        step.note = (f"{len(outs) - len(reports)} generator(s) failed: {lat.tail(failed_log, 3)}\nbroker: "
                     f"{lat.tail(work / f'embedded-{robots}.log', 5) if kind == 'embedded' else ''}")
        return step
    step.connect_s = max(r["connect_s"] for r in reports)
    for r in reports:
        step.state_sent += r["state_sent"]
        step.state_received += r["state_received"]
        step.cmd_sent += r["cmd_sent"]
        step.cmd_received += r["cmd_received"]
        step.state_ms += r["state_ms"]
        step.cmd_ms += r["cmd_ms"]
        step.lost_connections += r.get("lost_connections", 0)
        if r.get("load"):
            step.shed = r["load"].get("shed", 0)
    wall = seconds + WARMUP + SETTLE + connect_budget
    step.generator_cpu = 100 * sum(r["cpu_s"] for r in reports) / wall
    return step


def start_cluster(work: Path, robots: int) -> Any:
    """Three RabbitMQ nodes with the largest count's fleet (``acl export --format rabbitmq``), or None."""
    from roslink_mqtt.broker.export_rabbitmq import export_rabbitmq
    from roslink_mqtt.config import load_fleet
    from roslink_mqtt.rabbit_cluster import RabbitCluster, rabbitmq_available

    if not rabbitmq_available():
        return None
    fleet = load_fleet(fleet_file(work / f"fleet-rabbitmq-{robots}.yaml", robots, 1883))
    export_rabbitmq(fleet, work / "rabbitmq-export", {login: PASSWORD for login in [*fleet.robots, *fleet.users]})
    cluster = RabbitCluster(work / "rabbitmq", work / "rabbitmq-export")
    took = cluster.start()
    cluster.wait_for_login(MONITOR, PASSWORD)
    for i in range(0, robots, max(1, robots // 5)):  # the last users of the definitions too, not just the first
        cluster.wait_for_login(operator_name(i), PASSWORD)
    cluster.wait_for_login(operator_name(robots - 1), PASSWORD)
    print(f"(RabbitMQ: three nodes clustered in {took:.0f} s; robot i on node i mod 3, its operator on the next, "
          "the monitor on node 3)", flush=True)
    return cluster


# -- report ----------------------------------------------------------------------------------------------------
def fmt(step: Step) -> str:
    def share(got: int, sent: int) -> str:
        return f"{got} of {sent}"

    return (f"{step.broker:<10} {step.robots:>6} {step.connect_s:8.1f} "
            f"{share(step.state_received, step.state_sent):>16} {step.pct(step.state_ms, 50):7.1f} "
            f"{step.pct(step.state_ms, 99):7.1f} {max(step.state_ms, default=float('nan')):7.0f} "
            f"{share(step.cmd_received, step.cmd_sent):>16} {step.pct(step.cmd_ms, 50):7.1f} "
            f"{step.pct(step.cmd_ms, 99):7.1f} {max(step.cmd_ms, default=float('nan')):7.0f} "
            f"{step.broker_cpu:6.0f} {step.broker_rss / 2**20:7.0f} {step.per_connection / 1024:7.1f} "
            f"{step.generator_cpu:6.0f} {'—' if step.shed is None else step.shed:>6} {step.lost_connections:>5}  "
            f"{'pass' if step.passed else 'MISS'} {step.note}")


HEADER = (f"{'broker':<10} {'robots':>6} {'connect':>8} {'state recv':>16} {'p50':>7} {'p99':>7} {'max':>7} "
          f"{'cmd recv':>16} {'p50':>7} {'p99':>7} {'max':>7} {'CPU %':>6} {'RSS MB':>7} {'kB/conn':>7} "
          f"{'gen %':>6} {'shed':>6} {'lost':>5}  bar")


def plot(steps: list[Step], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 3.8), dpi=100)
    for broker in dict.fromkeys(s.broker for s in steps):
        series = [s for s in steps if s.broker == broker]
        xs = [s.robots for s in series]
        axes[0].plot(xs, [max(s.pct(s.state_ms, 99), s.pct(s.cmd_ms, 99)) for s in series], marker="o",
                     label=broker)
        axes[1].plot(xs, [s.broker_cpu for s in series], marker="o", label=broker)
    axes[0].axhline(BAR_P99_MS, color="grey", linestyle="--", linewidth=0.8, label="bar: 50 ms")
    axes[0].set_yscale("log")
    axes[0].set_ylabel("worst p99 (state, commands), ms")
    axes[1].set_ylabel("broker CPU, % of one core")
    for ax in axes:
        ax.set_xlabel("robots (each with its operator)")
        ax.set_xscale("log")
        ax.legend(fontsize=8)
    fig.suptitle("A fleet on one broker: latency and broker CPU per robot count", fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="4 s windows and fewer counts")
    p.add_argument("--seconds", type=float, default=5.0, help="measured window per count (default: %(default)s)")
    p.add_argument("--brokers", default="embedded,mosquitto,rabbitmq", help="comma-separated (default: %(default)s)")
    p.add_argument("--robots", help="comma-separated robot counts for every broker (default: per broker)")
    p.add_argument("--plot", type=Path, default=DEFAULT_PLOT, help="(default: %(default)s)")
    p.add_argument("--loops", default="auto", help="event loops of the embedded broker to run, comma-separated: "
                                                   "auto, uvloop, asyncio (default: %(default)s)")
    p.add_argument("--readers", default="inline", help="readers of the embedded broker to run, comma-separated: "
                                                       "inline, amqtt (default: %(default)s)")
    p.add_argument("--no-presence", action="store_true",
                   help="operators send no presence heartbeats (what presence costs a broker; robots then refuse "
                        "their commands on a real bridge)")
    p.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)  # the bench's own generator processes
    p.add_argument("--role", default="fleet", help=argparse.SUPPRESS)
    p.add_argument("--first", type=int, default=0, help=argparse.SUPPRESS)
    p.add_argument("--count", type=int, default=0, help=argparse.SUPPRESS)
    p.add_argument("--ports", default="0", help=argparse.SUPPRESS)
    p.add_argument("--start-at", type=float, default=0.0, help=argparse.SUPPRESS)
    p.add_argument("--out", type=Path, default=Path("fleet-worker.json"), help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.quick:
        args.seconds = 4.0
    args.brokers = [b.strip() for b in args.brokers.split(",") if b.strip()]
    if set(args.brokers) - set(DEFAULT_COUNTS):
        p.error(f"--brokers from {', '.join(DEFAULT_COUNTS)}")
    try:
        args.counts = [int(n) for n in args.robots.split(",")] if args.robots else None
    except ValueError:
        p.error("--robots is a comma-separated list of numbers")
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.worker:
        return worker_main(args)
    began = time.monotonic()
    env = dict(os.environ)
    steps: list[Step] = []
    print(HEADER, flush=True)
    try:
        with tempfile.TemporaryDirectory(prefix="roslink-fleet-") as tmp:
            runs = [(kind, loop, reader) for kind in args.brokers
                    for loop in (args.loops.split(",") if kind == "embedded" else ["auto"])
                    for reader in (args.readers.split(",") if kind == "embedded" else ["inline"])]
            for kind, loop, reader in runs:
                counts = args.counts or DEFAULT_COUNTS[kind]
                if args.quick and not args.counts:
                    counts = counts[::2]
                cluster = None
                if kind == "rabbitmq":
                    cluster = start_cluster(Path(tmp), max(counts))
                    if cluster is None:
                        print("rabbitmq: rabbitmq-server not installed, skipped")
                        continue
                try:
                    for robots in counts:
                        step = run_step(kind, robots, Path(tmp), env, args.seconds, loop, not args.no_presence,
                                        cluster, reader)
                        if step is None:
                            print(f"{kind}: Mosquitto not installed, skipped")
                            break
                        steps.append(step)
                        print(fmt(step), flush=True)
                        if not step.passed:
                            break
                finally:
                    if cluster is not None:
                        cluster.stop()
    except KeyboardInterrupt:
        print("fleet bench: interrupted", file=sys.stderr)
        return 130
    except (lat.ChildExited, TimeoutError) as e:
        raise SystemExit(f"fleet bench: {e}") from None
    print(f"\nA fleet on one broker, loopback, {os.cpu_count()} cores, {args.seconds:g} s windows after {WARMUP:g} s "
          f"warm-up; latency in ms; bar: p99 < {BAR_P99_MS:g} ms and nothing lost. connect = s until the whole "
          f"fleet was connected; CPU % and RSS of the broker; kB/conn = broker memory per idle connection; gen % = "
          f"the load generator's CPU (all its processes, % of one core). {lat.versions()}\n")
    print(HEADER)
    for step in steps:
        print(fmt(step))
    if any(step.state_ms for step in steps):
        plot(steps, args.plot)
        print(f"plot: {args.plot}")
    print(f"run took {time.monotonic() - began:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
