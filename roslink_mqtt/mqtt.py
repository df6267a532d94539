"""Making paho-mqtt clients the way every roslink-mqtt component needs them.

One place decides the things that are easy to forget per call site:
TCP_NODELAY (paho leaves Nagle on, which stalls small messages 20–40 ms at
≥ 20 Hz), MQTT 3.1.1, version-2 callbacks, TLS from the URL scheme and a
capped reconnect backoff.
"""

from __future__ import annotations

import socket
import ssl
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal
from urllib.parse import urlsplit

import paho.mqtt.client as mqtt

DEFAULT_PORTS = {"mqtt": 1883, "mqtts": 8883, "ws": 8083, "wss": 8084}

# -- what a person is told when a broker will not have us (CLI, SDK, bridge log and, generated, the dashboard) --
WRONG_LOGIN = "wrong username or password"
# MQTT 3.1.1 CONNACK return codes. 5 ("not authorized") is what the embedded broker and Mosquitto answer to a wrong
# password and to an unknown username alike (never saying which: that would tell a guesser which logins exist).
CONNACK_REFUSALS = {
    1: "the broker does not accept this MQTT protocol version",
    2: "the broker rejected the client id",
    3: "the broker is unavailable",
    4: WRONG_LOGIN,
    5: WRONG_LOGIN,
}
LOGIN_REFUSALS = frozenset({4, 5})  # the login itself was refused: retrying the same password cannot help
_PAHO_REASONS = {132: 1, 133: 2, 136: 3, 134: 4, 135: 5}  # paho reports 3.1.1 return codes as MQTT 5 reason codes
# How long a client waits for the broker's CONNACK. Longer than the embedded broker's login throttle may hold an
# answer (LoginThrottle.max_wait, 10 s, after failed logins from the same address), so that a slowed-down but
# valid verdict ("wrong username or password", or success) is heard instead of a timeout.
LOGIN_WAIT = 12.0


def connack_code(reason: Any) -> int | None:
    """The MQTT 3.1.1 return code of a refused CONNACK: a paho ReasonCode, its value or the 3.1.1 code itself."""
    value = getattr(reason, "value", reason)
    if not isinstance(value, int):
        return None
    return value if value in CONNACK_REFUSALS else _PAHO_REASONS.get(value)


def connack_refusal(reason: Any) -> str:
    """Why the broker refused the CONNECT, in the words every roslink-mqtt program uses."""
    code = connack_code(reason)
    return CONNACK_REFUSALS[code] if code is not None else str(reason)


def login_refused(reason: Any) -> bool:
    """The broker refused the login itself (CONNACK 4 or 5): a wrong password, an unknown or barred user."""
    return connack_code(reason) in LOGIN_REFUSALS


def acknowledged(info: mqtt.MQTTMessageInfo, wait: float) -> bool:
    """Wait up to ``wait`` s for a QoS 1 publish to be acknowledged; False when it was not, including when paho
    raises because the publish itself failed (the connection was gone): the caller's answer is the same."""
    try:
        info.wait_for_publish(wait)
        return info.is_published()
    except (RuntimeError, ValueError):
        return False


def speaks_tls(host: str, port: int, timeout: float = 2.0) -> bool:
    """Does ``host:port`` complete a TLS handshake? Asked when a plain ``mqtt://`` CONNECT was met with a closed
    connection: a TLS listener reads our CONNECT as a broken handshake and hangs up without a word."""
    context = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    context.check_hostname = False
    context.verify_mode = ssl.CERT_NONE  # only whether it speaks TLS; nothing is sent over it
    try:
        with socket.create_connection((host, port), timeout=timeout) as raw, \
                context.wrap_socket(raw, server_hostname=host):
            return True
    except (OSError, ValueError):  # ssl.SSLError is an OSError
        return False


def tls_hint(url: BrokerUrl) -> str:
    """What to say when :func:`speaks_tls` found TLS behind a plain ``mqtt://`` (or ``ws://``) URL."""
    secure = BrokerUrl("wss" if url.transport == "websockets" else "mqtts", url.host, url.port, url.path)
    return f"this port speaks TLS: use {secure}"


def closed_before_connack(url: BrokerUrl) -> str:
    """The reason for a broker that closed the connection without answering our CONNECT (probed first for TLS)."""
    if not url.tls and speaks_tls(url.host, url.port):
        return tls_hint(url)
    return "the server closed the connection without answering the MQTT CONNECT (is this an MQTT port?)"


@dataclass(frozen=True, slots=True)
class BrokerUrl:
    scheme: str
    host: str
    port: int
    path: str = "/mqtt"

    @property
    def tls(self) -> bool:
        return self.scheme in ("mqtts", "wss")

    @property
    def transport(self) -> Literal["websockets", "tcp"]:
        return "websockets" if self.scheme in ("ws", "wss") else "tcp"

    def __str__(self) -> str:
        tail = self.path if self.transport == "websockets" else ""
        return f"{self.scheme}://{self.host}:{self.port}{tail}"


def parse_broker_url(url: str) -> BrokerUrl:
    """``mqtt://host[:port]``, ``mqtts://``, ``ws://host[:port][/path]``, ``wss://``; bare ``host[:port]`` = mqtt."""
    if "://" not in url:
        url = "mqtt://" + url
    parts = urlsplit(url)
    if parts.scheme not in DEFAULT_PORTS:
        raise ValueError(f"unsupported broker URL scheme '{parts.scheme}' (use mqtt, mqtts, ws or wss)")
    if not parts.hostname:
        raise ValueError(f"broker URL {url!r} has no host")
    try:
        port = parts.port or DEFAULT_PORTS[parts.scheme]
    except ValueError:
        raise ValueError(f"broker URL {url!r} has an invalid port") from None
    return BrokerUrl(parts.scheme, parts.hostname, port, parts.path or "/mqtt")


def parse_broker_urls(urls: str | Sequence[str | BrokerUrl] | BrokerUrl) -> tuple[BrokerUrl, ...]:
    """One broker URL, or the nodes of one cluster: comma-separated (``mqtt://a:1883,mqtt://b:1883``) or a list.

    The nodes of a list must be reached the same way (one scheme): a client moves between them without being
    rebuilt, and a list that mixed TLS and plain TCP would silently drop encryption when one node failed.
    """
    if isinstance(urls, BrokerUrl):
        return (urls,)
    parts = [p.strip() for p in urls.split(",")] if isinstance(urls, str) else list(urls)
    parsed = tuple(p if isinstance(p, BrokerUrl) else parse_broker_url(p) for p in parts if p)
    if not parsed:
        raise ValueError("no broker URL given")
    schemes = sorted({u.scheme for u in parsed})
    if len(schemes) > 1:
        raise ValueError(f"broker URLs {', '.join(map(str, parsed))} mix schemes ({', '.join(schemes)}): the "
                         "nodes of one list are reached one way (all mqtts://, say)")
    return parsed


class BrokerRing:
    """The brokers a client may use, and the one it (re)connects to next: failover across a cluster's nodes.

    Every node of a cluster serves the same topics and logins, so when a connection fails or is lost the
    client simply moves on to the next node (round robin) instead of waiting for the dead one to return.
    With one URL nothing moves.
    """

    def __init__(self, client: mqtt.Client, urls: Sequence[BrokerUrl]) -> None:
        self.client, self.urls, self.index, self.moves = client, tuple(urls), 0, 0
        self._client_id: bytes = client._client_id

    @property
    def url(self) -> BrokerUrl:
        """The broker of the current (or next) connection attempt."""
        return self.urls[self.index]

    def advance(self) -> BrokerUrl | None:
        """Point the client's next (re)connect at the next node; None with a single broker (nothing to move)."""
        if len(self.urls) < 2:
            return None
        self.index = (self.index + 1) % len(self.urls)
        nxt = self.url
        # paho reconnects to the address it keeps in these; its public setters refuse to change it until a lost
        # connection is fully torn down, which is exactly when failover must act
        # (tests/integration/test_failover.py proves it against real brokers, so a paho release that renames them
        # fails there, not in the field).
        self.client._host, self.client._port = nxt.host, nxt.port
        if nxt.transport == "websockets":
            self.client.ws_set_options(path=nxt.path)
        # A fresh MQTT client id on the new node: RabbitMQ keeps a QoS 1 subscription in a durable queue named
        # after the client id and homed on the node it was made on; with that node dead, the same id is refused
        # everywhere until it returns. Our sessions are clean, so nothing depends on the id staying the same.
        self.moves += 1
        self.client._client_id = self._client_id + f"-{self.moves}".encode()
        return nxt

    def __str__(self) -> str:
        return str(self.url) if len(self.urls) == 1 else f"{self.url} (of {len(self.urls)} brokers)"


def set_nodelay(sock: Any) -> None:
    """Disable Nagle on a paho socket (plain, TLS or the websocket wrapper's inner socket)."""
    raw = getattr(sock, "_socket", sock)
    try:
        raw.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    except (OSError, AttributeError):  # unix sockets, or already closed
        pass


def make_client(client_id: str, *, username: str | None = None, password: str | None = None,
                url: BrokerUrl | str | Sequence[BrokerUrl] | None = None, ca_file: str | None = None,
                insecure_tls: bool = False, max_reconnect_delay: float = 3.0) -> mqtt.Client:
    """A configured paho client (not yet connected); for a list of brokers, configured for the first.

    ``max_reconnect_delay`` caps the backoff so a robot is back within a few
    seconds of its broker returning.
    """
    broker = parse_broker_urls(url)[0] if url is not None else None
    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=client_id, clean_session=True,
                         protocol=mqtt.MQTTv311,
                         transport=broker.transport if broker else "tcp")
    if username is not None:
        client.username_pw_set(username, password)
    if broker is not None and broker.transport == "websockets":
        client.ws_set_options(path=broker.path)
    if broker is not None and broker.tls:
        context = ssl.create_default_context(cafile=ca_file)
        if insecure_tls:
            context.check_hostname = False
            context.verify_mode = ssl.CERT_NONE
        client.tls_set_context(context)
    client.on_socket_open = lambda _client, _userdata, sock: set_nodelay(sock)
    # paho annotates the delays int, but they are seconds used as numbers: a float works (a 0.1 s first retry)
    client.reconnect_delay_set(min_delay=0.1, max_delay=max(0.1, max_reconnect_delay))  # type: ignore[arg-type]
    return client
