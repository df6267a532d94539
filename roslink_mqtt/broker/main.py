"""``roslink-mqtt-broker``: the embedded MQTT broker for a fleet.

    roslink-mqtt-broker --config config/robots.yaml [--host 127.0.0.1] [--port 1883] [--ws-port 8083]

Listens on TCP, WebSocket (browsers, Node-RED dashboards) and, when robots.yaml names a
certificate and key, TLS. Every connection must log in as a robot or user of the fleet;
topics are checked per broker/README.md, "What it enforces". SIGHUP re-reads robots, users and grants (connected
clients stay; a revoked grant stops deliveries at once) and the TLS certificate (new connections get it).
SIGINT/SIGTERM stop cleanly.
Exit codes: 0 after a clean stop, 2 for a bad config or arguments, 1 when the broker
cannot start (port in use, unreadable certificate).
"""

from __future__ import annotations

import argparse
import asyncio
import gc
import logging
import signal
import sys
from collections.abc import Coroutine, Sequence
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .server import EmbeddedBroker

PROG = "roslink-mqtt-broker"
log = logging.getLogger("roslink_mqtt.broker")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0].strip())
    p.add_argument("--config", default="config/robots.yaml", help="fleet file (default: %(default)s)")
    p.add_argument("--host", help="address to listen on (default: broker.host from the config)")
    p.add_argument("--port", type=_port, help="MQTT/TCP port, 0 = off (default: broker.port)")
    p.add_argument("--ws-port", type=_port, help="MQTT/WebSocket port, 0 = off (default: broker.ws_port)")
    p.add_argument("--log-level", default="INFO", choices=("DEBUG", "INFO", "WARNING", "ERROR"))
    p.add_argument("--connect-timeout", type=float, default=10.0, metavar="S",
                   help="close connections that send no CONNECT within S seconds (default: %(default)s)")
    p.add_argument("--sys-interval", type=float, default=10.0, metavar="S",
                   help="publish $SYS/broker/... every S seconds, 0 = version only (default: %(default)s)")
    p.add_argument("--session-expiry", type=int, default=3600, metavar="S",
                   help="forget disconnected persistent sessions after S seconds (default: %(default)s)")
    p.add_argument("--login-free-failures", type=int, default=5, metavar="N",
                   help="failed logins per client address before attempts are slowed (default: %(default)s)")
    p.add_argument("--login-max-delay", type=float, default=8.0, metavar="S",
                   help="longest spacing between login attempts from a guessing address (default: %(default)s)")
    p.add_argument("--limit", action="append", default=[], metavar="NAME=VALUE", type=_limit,
                   help="override one of the broker's per-login limits (docs/safety.md lists them), "
                        "e.g. --limit max_queued_bytes=1048576; repeatable")
    p.add_argument("--loop", choices=("auto", "uvloop", "asyncio"), default="auto",
                   help="event loop: uvloop (libuv, installed with the [broker] extra) or Python's own; auto = "
                        "uvloop when installed (default: %(default)s)")
    p.add_argument("--reader", choices=("inline", "amqtt"), default="inline",
                   help="how TCP and TLS connections are read: inline (each packet handled in order as it is read) "
                        "or amqtt (amqtt's own reader, a Task and queues per packet; slower, kept to compare and "
                        "to fall back on) (default: %(default)s)")
    p.add_argument("--no-acl", action="store_true", help=argparse.SUPPRESS)  # benchmarks only: no topic checks
    return p


def run_loop(coroutine: Coroutine[Any, Any, int], choice: str) -> int:
    """Run the broker on uvloop when asked or available: amqtt spends most of a message's cost in the event
    loop itself (a task, a timer and a queue hand-off per delivery), which uvloop does in C."""
    if choice != "asyncio":
        try:
            import uvloop
        except ImportError:
            if choice == "uvloop":
                coroutine.close()
                raise SystemExit(f"{PROG}: --loop uvloop needs uvloop: pip install 'roslink-mqtt[broker]'") from None
        else:
            return uvloop.run(coroutine)
    return asyncio.run(coroutine)


def tune_gc() -> None:
    """Keep the cyclic garbage collector from pausing the loop for a tenth of a second.

    With a fleet connected (300 robots and their operators: ~a million objects) a full collection took 60-120 ms
    -- every client waited that long (bench/fleet.py, docs/scaling.md: one run in four missed its p99 bar on that
    alone, measured with an experimental faster message path). What the
    broker loaded at start is frozen out of every collection; collections run after 50,000 allocations instead of
    700, and full ones a tenth as often. Per-message garbage is freed by reference counting, not by the collector.
    """
    gc.collect()
    gc.freeze()
    gc.set_threshold(50_000, 20, 100)


def _port(text: str) -> int:
    value = int(text)
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"port must be 0..65535, got {value}")
    return value


def _limit(text: str) -> tuple[str, float]:
    from .limits import BrokerLimits

    name, sep, value = text.partition("=")
    if not sep or name not in BrokerLimits.names():
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE with NAME one of {', '.join(BrokerLimits.names())}")
    try:
        number = float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{name}: expected a number, got {value!r}") from None
    if number < 0:
        raise argparse.ArgumentTypeError(f"{name}: must be >= 0, got {value}")
    return name, number


class ClosedDeliveryFilter(logging.Filter):
    """One line, not a traceback, for a delivery that failed because its client had just disconnected.

    amqtt delivers each message in a task of its own and logs a failed one with its traceback at ERROR ("Task failed
    and will be skipped", or "… during broadcast shutdown" when the broker stops). A subscriber that disconnects
    while a message is on its way (a bridge's last words at shutdown reaching a client that is leaving too) makes
    the transport raise ``RuntimeError: unable to perform operation on <TCPTransport closed=True …>``: a race, not
    a fault. Any other exception keeps its traceback.
    """

    def filter(self, record: logging.LogRecord) -> bool:
        error = record.exc_info[1] if record.exc_info else None
        if isinstance(error, (RuntimeError, ConnectionError)) and "closed" in str(error) \
                and str(record.msg).startswith("Task failed"):
            record.msg, record.args = f"a delivery failed: its client had just disconnected ({error})", ()
            record.exc_info = record.exc_text = None
            record.levelno, record.levelname = logging.INFO, "INFO"
        return True


def setup_logging(level: str) -> None:
    logging.basicConfig(level=level, stream=sys.stderr, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    logging.getLogger("transitions").setLevel(logging.WARNING)
    logging.getLogger("websockets").setLevel(logging.WARNING)  # one line per WebSocket connection otherwise
    if level != "DEBUG":
        # amqtt logs every connection (and our refusals a second time) at INFO/WARNING;
        # our own log has one line per connect, deny and disconnect.
        logging.getLogger("amqtt").setLevel(logging.ERROR)
        # amqtt logs a failed start (port in use) with a traceback; StartError explains it in one line
        logging.getLogger("amqtt.broker").addFilter(lambda record: "startup failed" not in record.getMessage())
    logging.getLogger("amqtt.broker").addFilter(ClosedDeliveryFilter())


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    setup_logging(args.log_level)
    try:
        import amqtt  # noqa: F401
    except ImportError:
        print(f"{PROG}: the broker needs the [broker] extra: pip install 'roslink-mqtt[broker]'", file=sys.stderr)
        return 2
    from ..config import ConfigError, load_fleet
    from .limits import BrokerLimits
    from .ratelimit import LoginThrottle
    from .server import EmbeddedBroker, ServerOptions

    try:
        fleet = load_fleet(args.config, need_hashes=True)
    except ConfigError as err:
        print(f"{PROG}: {err}", file=sys.stderr)
        return 2
    from ..config.exposure import exposure_problems

    problems = exposure_problems(fleet, args.host, args.ws_port, args.port)
    for problem in problems:
        print(f"{PROG}: refused to start: {problem}", file=sys.stderr)
    if problems:
        return 2
    try:
        throttle = LoginThrottle(free_failures=args.login_free_failures,
                                 base_delay=min(0.5, args.login_max_delay), max_delay=args.login_max_delay)
    except ValueError as err:
        print(f"{PROG}: {err}", file=sys.stderr)
        return 2
    options = ServerOptions.from_fleet(
        fleet, host=args.host, port=args.port, ws_port=args.ws_port, connect_timeout=args.connect_timeout,
        sys_interval=args.sys_interval, session_expiry=args.session_expiry, throttle=throttle,
        acl=not args.no_acl, limits=BrokerLimits.from_mapping(dict(args.limit)), reader=args.reader)
    server = EmbeddedBroker(args.config, fleet, options)
    try:
        return run_loop(serve(server), args.loop)
    except KeyboardInterrupt:  # a second Ctrl-C while stopping
        return 130


async def serve(server: EmbeddedBroker) -> int:
    from .server import StartError

    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    reloads: set[asyncio.Task[bool]] = set()

    state = {"started": False, "hup_pending": False}

    def on_hup() -> None:
        if not state["started"]:  # reloaded once the listeners are up: a change saved meanwhile is not lost
            state["hup_pending"] = True
            return
        log.info("SIGHUP: reloading %s", server.config_path)
        task = loop.create_task(server.reload())
        reloads.add(task)
        task.add_done_callback(reloads.discard)

    # Before the listeners open: a SIGTERM the moment the port answers (systemd, a test) is a clean stop, not a
    # death by signal (it was: exit -15 when it came before the handlers, while the collector was being tuned).
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    loop.add_signal_handler(signal.SIGHUP, on_hup)
    try:
        await server.start()
    except StartError as err:
        print(f"{PROG}: {err}", file=sys.stderr)
        return 1
    state["started"] = True
    if state["hup_pending"]:
        on_hup()
    tune_gc()
    await stop.wait()
    log.info("stopping")
    await asyncio.gather(*reloads, return_exceptions=True)
    await server.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
