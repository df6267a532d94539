"""The embedded broker for one fleet: listeners from robots.yaml, plugins wired to a live fleet, reload.

:class:`EmbeddedBroker` owns the :class:`~roslink_mqtt.broker.hardened.HardenedBroker`, the
:class:`~roslink_mqtt.broker.acl.LiveFleet` both plugins read, and the login throttle.
``main.py`` adds the command line and signals on top; tests and benchmarks can run it
in-process.
"""

from __future__ import annotations

import errno
import logging
import ssl
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from amqtt.errors import BrokerError

from ..config import ConfigError, Fleet, TlsSettings, load_fleet
from ..config.grants import grants_of
from ..localproc import can_listen
from .acl import LiveFleet, TopicPolicy
from .admin import FleetControl
from .hardened import CONNECT_TIMEOUT, HardenedBroker
from .limits import BrokerLimits
from .plugins import FleetAclPlugin, FleetAuthPlugin, SysInfoPlugin, plugin_path
from .ratelimit import LoginThrottle

log = logging.getLogger("roslink_mqtt.broker")


class StartError(RuntimeError):
    """The broker could not start (port in use, unreadable certificate, ...); the message says which."""


@dataclass(frozen=True, slots=True)
class Listener:
    name: str  # amqtt listener name; shows up in connect log lines
    kind: str  # tcp | ws | tls | wss
    host: str
    port: int

    @property
    def url(self) -> str:
        scheme = {"tcp": "mqtt", "ws": "ws", "tls": "mqtts", "wss": "wss"}[self.kind]
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{scheme}://{host}:{self.port}"


@dataclass(frozen=True)
class ServerOptions:
    """Everything the runner needs besides the fleet's logins and grants."""

    host: str = "127.0.0.1"
    port: int = 1883
    ws_port: int | None = 8083  # None or 0: no WebSocket listener
    ws_host: str | None = None  # the WebSocket listener's address when not ``host``
    tls: TlsSettings | None = None
    max_payload: int = 4 * 1024 * 1024
    connect_timeout: float = CONNECT_TIMEOUT
    sys_interval: float = 10.0
    session_expiry: int | None = 3600  # s a disconnected persistent session is kept
    acl: bool = True  # False only for benchmarks: authenticate, but no topic checks
    reader: str = "inline"  # TCP/TLS packets read inline (hardened fix 32), or "amqtt": amqtt's reader and queues
    throttle: LoginThrottle | None = field(default_factory=LoginThrottle)
    limits: BrokerLimits = field(default_factory=BrokerLimits)

    @classmethod
    def from_fleet(cls, fleet: Fleet, **overrides: Any) -> ServerOptions:
        """Listener settings from robots.yaml; ``overrides`` that are not None win."""
        b = fleet.broker
        tls = b.tls
        if tls is not None:
            base = Path(fleet.file).resolve().parent
            tls = replace(tls, certfile=str(base / tls.certfile), keyfile=str(base / tls.keyfile),
                          cafile=str(base / tls.cafile) if tls.cafile else None)
        options = cls(host=b.host, port=b.port, ws_port=b.ws_port, ws_host=b.ws_host, tls=tls,
                      max_payload=b.max_payload)
        return replace(options, **{k: v for k, v in overrides.items() if v is not None})

    def listeners(self) -> list[Listener]:
        """The listeners that accept connections (port 0: no plain MQTT one)."""
        out = [Listener("default", "tcp", self.host, self.port)] if self.port else []
        if self.ws_port:
            out.append(Listener("ws", "ws", self.ws_host or self.host, self.ws_port))
        if self.tls is not None:
            out.append(Listener("tls", "tls", self.tls.host or self.host, self.tls.port))
            if self.tls.ws_port:
                out.append(Listener("wss", "wss", self.tls.host or self.host, self.tls.ws_port))
        return out


def amqtt_config(options: ServerOptions, live: LiveFleet) -> dict[str, Any]:
    """The dict ``amqtt.broker.Broker`` takes (0.12.1: underscores in top-level keys, strict)."""
    # amqtt needs a listener called default; without a bind address it is off (bind must be None: amqtt's own default
    # for a missing one is 0.0.0.0:1883, every interface)
    listeners: dict[str, Any] = {"default": {"type": "tcp", "bind": None}}
    for lst in options.listeners():
        bind = f"[{lst.host}]:{lst.port}" if ":" in lst.host else f"{lst.host}:{lst.port}"
        entry: dict[str, Any] = {"type": "ws" if lst.kind in ("ws", "wss") else "tcp", "bind": bind}
        if lst.kind in ("tls", "wss"):
            assert options.tls is not None
            entry.update(ssl=True, certfile=options.tls.certfile, keyfile=options.tls.keyfile)
            if options.tls.cafile:
                entry["cafile"] = options.tls.cafile
        listeners[lst.name] = entry
    # Giving 'plugins' replaces amqtt's defaults (anonymous login, $SYS, packet loggers).
    plugins: dict[str, Any] = {plugin_path(FleetAuthPlugin): {"fleet": live, "throttle": options.throttle}}
    if options.acl:
        plugins[plugin_path(FleetAclPlugin)] = {"fleet": live, "cache_bytes": options.limits.acl_cache_bytes}
    plugins[plugin_path(SysInfoPlugin)] = {"interval": float(options.sys_interval)}
    return {"listeners": listeners, "plugins": plugins, "timeout_disconnect_delay": 0,
            "session_expiry_interval": options.session_expiry}


class EmbeddedBroker:
    """Start, reload and stop the broker for the fleet in ``config_path``."""

    def __init__(self, config_path: str | Path, fleet: Fleet, options: ServerOptions) -> None:
        self.config_path = str(config_path)
        self.options = options
        self.live = LiveFleet(fleet)
        self.broker: HardenedBroker | None = None

    async def start(self) -> None:
        self._check_tls_files()
        broker = HardenedBroker(amqtt_config(self.options, self.live), connect_timeout=self.options.connect_timeout,
                                max_payload=self.options.max_payload, limits=self.options.limits,
                                policy=TopicPolicy(self.live, self.options.limits),
                                inline=self.options.reader == "inline")
        try:
            await broker.start()
        except BrokerError as err:
            raise StartError(self._explain(err)) from None
        broker.control = FleetControl(lambda: self.live.fleet, self.config_path, self.reload)
        self.broker = broker
        fleet = self.live.fleet
        await self.publish_grants(fleet)
        log.info("listening on %s; fleet %s: %d robots, %d users%s",
                 ", ".join(lst.url for lst in self.options.listeners()), self.config_path, len(fleet.robots),
                 len(fleet.users), "" if self.options.acl else "; TOPIC ACL OFF (benchmark mode)")

    async def stop(self) -> None:
        if self.broker is not None and self.broker.transitions.state == "started":
            await self.broker.shutdown()
        log.info("stopped")

    async def reload(self) -> bool:
        """Re-read robots, users and grants; keep the running config if the file is bad."""
        try:
            fleet = load_fleet(self.config_path, need_hashes=True)
        except ConfigError as err:
            log.error("reload refused, still enforcing the previous fleet: %s", err)
            return False
        if fleet.broker != self.live.fleet.broker:
            log.warning("reload: broker listener settings changed in %s; they apply after a restart",
                        self.config_path)
        old = self.live.fleet
        change = self.live.replace(fleet)
        dropped = 0
        if self.broker is not None:
            for login in change.removed_logins + change.changed_passwords + change.reduced_grants:
                dropped += await self.broker.disconnect_user(login)
        await self.publish_grants(fleet, gone=[robot for robot in old.robots if robot not in fleet.robots])
        log.info("reloaded %s: %d robots, %d users; removed %s, added %s, new password %s, fewer grants %s; %d "
                 "connection(s) dropped", self.config_path, len(fleet.robots), len(fleet.users),
                 list(change.removed_logins), list(change.added_logins), list(change.changed_passwords),
                 list(change.reduced_grants), dropped)
        self._reload_certificate()
        return True

    async def publish_grants(self, fleet: Fleet, gone: list[str] | None = None) -> None:
        """Each robot's grants, retained on ``P/<robot>/grants`` (protocol/grants.py), where its bridge reads who
        may use the robot: a robot carries no fleet file. A removed robot's are cleared."""
        if self.broker is None:
            return
        issued = time.time()
        for robot in fleet.robots:
            await self.broker.publish_retained(fleet.topics.grants(robot),
                                               grants_of(fleet, robot, issued=issued, by="broker").to_json())
        for robot in gone or ():
            await self.broker.publish_retained(fleet.topics.grants(robot), b"")

    def _reload_certificate(self) -> None:
        """A renewed certificate (certbot, a new CA) on SIGHUP: new TLS connections get it, connected clients stay."""
        tls = self.options.tls
        if tls is None or self.broker is None:
            return
        try:
            listeners = self.broker.reload_certificates(tls.certfile, tls.keyfile)
        except (OSError, ssl.SSLError) as err:
            log.error("reload: TLS certificate %s not taken, still serving the previous one: %s", tls.certfile, err)
            return
        log.info("reloaded the TLS certificate %s: new connections get it (%d listener(s)); connected clients keep "
                 "theirs", tls.certfile, listeners)

    def _check_tls_files(self) -> None:
        tls = self.options.tls
        if tls is None:
            return
        for what, path in (("certfile", tls.certfile), ("keyfile", tls.keyfile), ("cafile", tls.cafile)):
            if path is None:
                continue
            try:
                with open(path, "rb"):
                    pass
            except OSError as err:
                raise StartError(f"broker.tls.{what}: cannot read {path}: {err.strerror}") from None

    def _explain(self, err: BrokerError) -> str:
        cause: BaseException | None = err
        while cause is not None and not isinstance(cause, OSError):
            cause = cause.__cause__ or cause.__context__
        if isinstance(cause, OSError) and cause.errno == errno.EADDRINUSE:
            busy = next((lst for lst in self.options.listeners() if not can_listen(lst.port, lst.host)), None)
            where = f"{busy.kind} listener {busy.host}:{busy.port}" if busy else "a listener"
            return f"cannot start: {where}: address already in use (another broker running?)"
        if isinstance(cause, OSError):
            return f"cannot start: {cause.strerror or cause}"
        return f"cannot start: {err}"

