"""The Foxglove gateway's front door: who may connect, and one port for both names of the protocol.

**Who may connect.** The gateway acts as its user on the broker, and browsers let any web page open a WebSocket to
``127.0.0.1`` (there is no same-origin rule for WebSockets: the server must look at the handshake). So the front
refuses a handshake, with an HTTP status and before any WebSocket data, unless (:class:`Admission`):

* its ``Origin`` is allowed: none at all (a program, not a page: the ws-protocol client in Node, PlotJuggler, the
  CLI), the hosted apps users open (:data:`HOSTED_APPS`), or one the user adds (``--allow-origin``). A page opened
  from disk — desktop Foxglove and Lichtblick are such pages (Electron, ``file://``), and
  ``tools/foxglove-view.html`` — says ``Origin: null`` (older Chromium: ``file://``); so does a sandboxed frame of
  *any* web site, so that origin is allowed only while a token is required;
* and the URL carries the gateway's per-run secret (``ws://127.0.0.1:8765/?token=…``), compared in constant
  time, unless the user turned it off (``--no-token``).

**The SDK's own server.** Foxglove's server (``foxglove-sdk``) has no such checks and listens on a loopback port of
its own, which a page could find by scanning. It therefore speaks only TLS, with a key and self-signed certificate
made for this run (:func:`loopback_tls`), and the front trusts exactly that certificate: a browser can neither
complete a TLS handshake with a certificate it does not trust (no prompt is shown for a WebSocket) nor speak plain
``ws://`` to it. A program on this machine that skips certificate checks can still connect (docs/foxglove.md).

**Both names.** The SDK's server accepts only the protocol's current name, ``foxglove.sdk.v1``, and refuses a client
that offers only the earlier ``foxglove.websocket.v1`` — the same messages, which Lichtblick releases before December
2025, Foxglove Studio, PlotJuggler's and other tools' clients and ``@foxglove/ws-protocol``'s default offer. The
front accepts either name and relays every frame, unchanged, to the SDK's server; a client that offers both gets
``foxglove.sdk.v1``. A slow client slows only its own relay; the SDK's server drops what waits for it too long, as
it does for a client connected directly.
"""

from __future__ import annotations

import asyncio
import hmac
import logging
import ssl
import threading
import time
from dataclasses import dataclass, field
from http import HTTPStatus
from typing import Any
from urllib.parse import parse_qs, urlsplit

log = logging.getLogger("roslink_mqtt.foxglove")


class _QuietHandshakes(logging.Filter):
    """Drop websockets' "opening handshake failed" (with its traceback): a port check or a scan that connects and
    says nothing is no error of the gateway's; refusals of real handshakes are logged by the front itself."""

    def filter(self, record: logging.LogRecord) -> bool:
        return record.getMessage() != "opening handshake failed"


ws_log = logging.getLogger("roslink_mqtt.foxglove.websockets")
ws_log.addFilter(_QuietHandshakes())

CURRENT, FIRST = "foxglove.sdk.v1", "foxglove.websocket.v1"
NAMES = (CURRENT, FIRST)  # the server's preference: the current name when a client offers both

# The web apps users open Foxglove or Lichtblick in (docs/foxglove.md names where these come from).
HOSTED_APPS = {"https://app.foxglove.dev": "Foxglove's web app",
               "https://lichtblick-suite.github.io": "Lichtblick's hosted app (lichtblick-suite.github.io/lichtblick)"}
# What a page opened from disk sends (desktop Foxglove and Lichtblick, tools/foxglove-view.html): ``null`` since
# Chromium 92, ``file://`` before. A sandboxed frame of any web site sends ``null`` too.
LOCAL_PAGES = frozenset({"null", "file://"})
TOKEN_PARAMETER = "token"
MIN_TOKEN_LENGTH = 16
LOG_AGAIN_AFTER = 10.0  # s: the same refusal is logged once per this (a page may retry in a loop)


def normalize_origin(text: str) -> str:
    """An origin as browsers send it (``https://app.example.com``, ``http://localhost:3000``, ``null``), lower
    case, no trailing slash; ValueError for anything else (a path, a query, no scheme)."""
    value = text.strip().lower()
    if value in LOCAL_PAGES:
        return value
    parts = urlsplit(value)
    if parts.scheme not in ("http", "https") or not parts.hostname or parts.path not in ("", "/") or parts.query \
            or parts.fragment \
            or parts.username is not None:
        raise ValueError(f"{text!r} is not an origin: expected scheme://host[:port] (https://app.example.com), "
                         "or null for pages opened from disk")
    return f"{parts.scheme}://{parts.netloc}"


def check_token(token: str) -> str:
    """A token chosen by the user: URL-safe (it goes into the URL as it is) and long enough not to be guessed."""
    if len(token) < MIN_TOKEN_LENGTH or not all(c.isascii() and (c.isalnum() or c in "-_") for c in token):
        raise ValueError(f"a gateway token needs at least {MIN_TOKEN_LENGTH} characters, only letters, digits, "
                         "- and _ (make one: python3 -c 'import secrets; print(secrets.token_urlsafe())')")
    return token


@dataclass(frozen=True)
class Refusal:
    """Why a handshake is refused: the HTTP status it gets and the reason (logged; sent as the body)."""

    status: HTTPStatus
    reason: str


@dataclass(frozen=True)
class Admission:
    """Who may open a WebSocket: ``token`` (None: no token asked for) and the origins added to the defaults."""

    token: str | None
    extra_origins: frozenset[str] = field(default_factory=frozenset)

    @property
    def origins(self) -> frozenset[str]:
        """Every allowed ``Origin`` value (a handshake without one is always allowed: it is not a page's)."""
        local = LOCAL_PAGES if self.token is not None else frozenset()
        return frozenset(HOSTED_APPS) | local | self.extra_origins

    def check(self, origins: list[str], path: str) -> Refusal | None:
        """None when a handshake with these ``Origin`` headers and this request path (with its query) may go on."""
        if len(origins) > 1:
            return Refusal(HTTPStatus.FORBIDDEN, "more than one Origin header")
        if origins:
            try:
                origin = normalize_origin(origins[0])
            except ValueError:
                origin = origins[0]
            if origin not in self.origins:
                return Refusal(HTTPStatus.FORBIDDEN, "origin not allowed (--allow-origin adds one)")
        if self.token is None:
            return None
        given = parse_qs(urlsplit(path).query).get(TOKEN_PARAMETER)
        if not given:
            return Refusal(HTTPStatus.UNAUTHORIZED, "no token (use the URL the gateway printed, with its ?token=…)")
        if len(given) > 1 or not hmac.compare_digest(given[0].encode(), self.token.encode()):
            return Refusal(HTTPStatus.FORBIDDEN, "wrong token")
        return None


def loopback_tls(host: str = "127.0.0.1") -> tuple[bytes, bytes, ssl.SSLContext]:
    """A new EC key and self-signed certificate for ``host`` (PEM certificate, PEM PKCS#8 key) and a client context
    that trusts that certificate and no other: the SDK's server gets the first two, the front the context."""
    import datetime
    import ipaddress

    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "roslink-mqtt foxglove gateway (this run only)")])
    now = datetime.datetime.now(datetime.timezone.utc)
    cert = (x509.CertificateBuilder().subject_name(name).issuer_name(name).public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5))
            .not_valid_after(now + datetime.timedelta(days=3650))  # the key lives as long as the process
            .add_extension(x509.SubjectAlternativeName([x509.IPAddress(ipaddress.ip_address(host))]), critical=False)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH]), critical=False)
            .sign(key, hashes.SHA256()))
    cert_pem = cert.public_bytes(serialization.Encoding.PEM)
    key_pem = key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                serialization.NoEncryption())
    context = ssl.create_default_context(cadata=cert_pem.decode())
    context.verify_flags |= ssl.VERIFY_X509_PARTIAL_CHAIN  # the certificate itself is the trust anchor
    return cert_pem, key_pem, context


class ProtocolFront:
    """Listen on ``host:port`` (0: a free port), admit clients as ``admission`` says and relay each one to
    ``wss://127.0.0.1:<upstream>`` (``upstream_tls``: the context that trusts its certificate; None: ``ws://``)."""

    def __init__(self, host: str, port: int, upstream: int, *, admission: Admission,
                 upstream_tls: ssl.SSLContext | None = None) -> None:
        self.host, self.port, self.upstream = host, port, upstream
        self.admission, self.upstream_tls = admission, upstream_tls
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: Any = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._logged: dict[tuple[str, str], tuple[float, int]] = {}  # (reason, peer) → (last logged, refused since)
        self._thread = threading.Thread(target=self._run, name="foxglove-front", daemon=True)

    def start(self, timeout: float = 10.0) -> int:
        """Listen; the port listened on. OSError when the address cannot be had."""
        self._thread.start()
        if not self._ready.wait(timeout):
            raise OSError(f"the Foxglove front did not start within {timeout:g} s")
        if self._error is not None:
            raise self._error
        return self.port

    def stop(self) -> None:
        loop, server = self._loop, self._server
        if loop is not None and server is not None:
            loop.call_soon_threadsafe(server.close)
        self._thread.join(5)

    def _run(self) -> None:
        asyncio.run(self._serve())

    async def _serve(self) -> None:
        from websockets.asyncio.server import serve
        from websockets.typing import Subprotocol

        self._loop = asyncio.get_running_loop()
        try:
            self._server = await serve(self._relay, self.host, self.port, process_request=self._admit,
                                       subprotocols=[Subprotocol(name) for name in NAMES], max_size=None,
                                       compression=None, logger=ws_log)
        except OSError as err:
            self._error = err
            self._ready.set()
            return
        self.port = self._server.sockets[0].getsockname()[1]
        self._ready.set()
        await self._server.wait_closed()

    def _admit(self, connection: Any, request: Any) -> Any:
        """The handshake's check, before the WebSocket opens: a refusal is an HTTP error, logged with the origin."""
        origins = request.headers.get_all("Origin")
        refusal = self.admission.check(origins, request.path)
        if refusal is None:
            return None
        self._log_refusal(refusal, origins[0] if origins else "none", connection.remote_address)
        return connection.respond(refusal.status, f"roslink-mqtt foxglove gateway: {refusal.reason}\n")

    def _log_refusal(self, refusal: Refusal, origin: str, peer: Any) -> None:
        """Each kind of refusal once per :data:`LOG_AGAIN_AFTER` per origin, with the count in between (a page
        retrying in a loop must not flood the terminal)."""
        now = time.monotonic()
        key = (refusal.reason, origin)
        last, count = self._logged.get(key, (-LOG_AGAIN_AFTER, 0))
        if now - last < LOG_AGAIN_AFTER:
            self._logged[key] = (last, count + 1)
            return
        self._logged[key] = (now, 0)
        more = f" ({count} more since)" if count else ""
        log.warning("refused a Foxglove WebSocket from %s, origin %s: %s (HTTP %d)%s", peer[0] if peer else "?",
                    origin, refusal.reason, refusal.status, more)

    async def _relay(self, client: Any) -> None:
        from websockets.asyncio.client import connect
        from websockets.exceptions import WebSocketException
        from websockets.typing import Subprotocol

        scheme = "wss" if self.upstream_tls is not None else "ws"
        try:
            async with connect(f"{scheme}://127.0.0.1:{self.upstream}", subprotocols=[Subprotocol(CURRENT)],
                               max_size=None, compression=None, ping_interval=None, ssl=self.upstream_tls) as server:
                pumps = [asyncio.create_task(_pump(client, server)), asyncio.create_task(_pump(server, client))]
                _done, pending = await asyncio.wait(pumps, return_when=asyncio.FIRST_COMPLETED)
                for task in pending:
                    task.cancel()
        except (OSError, WebSocketException) as err:
            log.warning("a Foxglove client (%s) was dropped: %s", client.subprotocol, err)


async def _pump(source: Any, sink: Any) -> None:
    """Every frame from ``source`` to ``sink`` as it came (text as text, binary as binary), until either closes."""
    from websockets.exceptions import ConnectionClosed

    try:
        async for frame in source:
            await sink.send(frame)
    except ConnectionClosed:
        pass
    finally:
        await sink.close()
