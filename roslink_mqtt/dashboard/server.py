"""A static file server for the web dashboard: the page, its script and style, and MQTT.js's browser bundle.

The server holds no credentials and proxies nothing. The browser connects to the broker's WebSocket
listener itself, with the user's own login, so the broker's ACL stays the only access path: anyone who can
reach this server learns the page and the broker's WebSocket address, nothing else (not even the fleet's
robot names — the page discovers robots from what the broker lets the user read).

ROS-free and amqtt-free (stdlib ``http.server`` only), so it runs on any client machine with the core
install. Serving is a fixed table of files: no path from a request ever reaches the file system.
"""

from __future__ import annotations

import json
import threading
from dataclasses import dataclass
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path, PurePosixPath
from urllib.parse import urlsplit

from .vendor import VENDOR_DIR

STATIC = Path(__file__).resolve().parent / "static"
# The npm bundles travel inside the package (dashboard/vendor.py: `make install` copies them from what
# package-lock.json pins), so a wheel installed without the repository or npm serves the whole page.
DEFAULT_MQTT_JS = VENDOR_DIR / "mqtt.min.js"
UPLOT_DIST = VENDOR_DIR
CONTENT_TYPES = {".html": "text/html; charset=utf-8", ".mjs": "text/javascript; charset=utf-8",
                 ".js": "text/javascript; charset=utf-8", ".css": "text/css; charset=utf-8"}
DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8090
DEFAULT_WS_PORT = 8083
DEFAULT_PREFIX = "roslink"

# The page talks to nothing but this server (its files) and a broker's WebSocket (ws: or wss:, any host: the user
# may type another broker's URL). No inline script, no framing (an e-stop button must not be clickjacked). MQTT.js
# runs its keep-alive timer in a worker made from a blob: URL (timers in workers are not throttled in background tabs).
# Map tiles, when configured (`--tiles`), come from that one origin too.
def csp(tile_origin: str = "") -> str:
    images = f"img-src 'self' data: blob:{' ' + tile_origin if tile_origin else ''}"
    return ("default-src 'none'; script-src 'self'; worker-src blob:; style-src 'self'; " + images + "; "
            "connect-src 'self' ws: wss:; base-uri 'none'; form-action 'none'; frame-ancestors 'none'")


CSP = csp()


def tile_origin(template: str) -> str:
    """The origin of a map tile URL template (``https://tile.example.org/{z}/{x}/{y}.png``); ValueError says what is
    wrong with it (the page fills in {z}, {x} and {y}; nothing else of the URL is the page's to choose)."""
    parts = urlsplit(template)
    if parts.scheme not in ("http", "https") or not parts.hostname:
        raise ValueError(f"map tiles URL {template!r}: expected http(s)://host/…/{{z}}/{{x}}/{{y}}…")
    missing = [k for k in ("{z}", "{x}", "{y}") if k not in template]
    if missing:
        raise ValueError(f"map tiles URL {template!r}: {', '.join(missing)} missing (the page fills them in)")
    if any(c in template for c in " '\";\n"):
        raise ValueError(f"map tiles URL {template!r}: spaces, quotes and semicolons are not allowed")
    return f"{parts.scheme}://{parts.netloc}"


class MqttJsMissing(FileNotFoundError):
    """An npm bundle the page loads (MQTT.js, uPlot) is not where the server looks (``make install`` not run)."""


@dataclass(frozen=True)
class PageConfig:
    """What the page is told at ``/config.json``: where the broker's WebSocket is and the topic prefix.

    ``ws_url`` empty means "derive it in the browser": ``ws://<the host the page came from>:<ws_port>``, so a
    page opened through an SSH tunnel or a LAN address points at the same machine's broker.
    """

    ws_port: int = DEFAULT_WS_PORT
    ws_url: str = ""
    prefix: str = DEFAULT_PREFIX
    tiles: str = ""  # a map tile URL template ({z}/{x}/{y}) for the fleet map's GPS view; empty: no tiles
    tiles_attribution: str = ""  # shown under the map, as tile servers ask

    def to_json(self) -> bytes:
        return json.dumps({"ws_port": self.ws_port, "ws_url": self.ws_url, "prefix": self.prefix,
                           "tiles": self.tiles, "tiles_attribution": self.tiles_attribution}).encode()


def _routes(mqtt_js: Path, config: PageConfig, uplot: Path = UPLOT_DIST) -> dict[str, tuple[str, Path | bytes]]:
    """URL path → (content type, file or bytes). The whole surface of the server: the page's own files (listed
    once, at start), the two npm bundles it loads, and its settings."""
    routes: dict[str, tuple[str, Path | bytes]] = {}
    for path in sorted(STATIC.rglob("*")):
        ctype = CONTENT_TYPES.get(path.suffix)
        if ctype and path.is_file():
            routes[str(PurePosixPath("/", path.relative_to(STATIC).as_posix()))] = (ctype, path)
    routes["/"] = routes["/index.html"]
    routes["/vendor/mqtt.min.js"] = ("text/javascript; charset=utf-8", mqtt_js)
    routes["/vendor/uPlot.esm.js"] = ("text/javascript; charset=utf-8", uplot / "uPlot.esm.js")
    routes["/vendor/uPlot.min.css"] = ("text/css; charset=utf-8", uplot / "uPlot.min.css")
    routes["/config.json"] = ("application/json", config.to_json())
    return routes


def _handler(routes: dict[str, tuple[str, Path | bytes]], quiet: bool,
             policy: str = CSP) -> type[BaseHTTPRequestHandler]:
    class Handler(BaseHTTPRequestHandler):
        def version_string(self) -> str:  # no Python version in the Server header
            return "roslink-mqtt-dashboard"

        def _send(self, head_only: bool) -> None:
            path = self.path.split("?", 1)[0].split("#", 1)[0]
            route = routes.get(path)
            if route is None:
                self.send_error(404, "not found")
                return
            ctype, source = route
            try:
                body = source if isinstance(source, bytes) else source.read_bytes()
            except OSError:
                self.send_error(404, "not found")
                return
            self.send_response(200)
            self.send_header("Content-Type", ctype)
            self.send_header("Content-Length", str(len(body)))
            # Files change with the checkout; a stale cached module next to a new index.html would break the page.
            self.send_header("Cache-Control", "no-store")
            self.send_header("Content-Security-Policy", policy)
            self.send_header("X-Content-Type-Options", "nosniff")
            self.send_header("X-Frame-Options", "DENY")
            self.send_header("Referrer-Policy", "no-referrer")
            self.end_headers()
            if not head_only:
                self.wfile.write(body)

        def do_GET(self) -> None:  # noqa: N802 (http.server's naming)
            self._send(head_only=False)

        def do_HEAD(self) -> None:  # noqa: N802
            self._send(head_only=True)

        def log_message(self, format: str, *args: object) -> None:  # noqa: A002 (http.server's signature)
            if not quiet:
                super().log_message(format, *args)

    return Handler


class DashboardServer:
    """The dashboard's HTTP server, in a background thread (``start``/``stop``) or in the foreground (``serve``).

    ``port=0`` picks a free port (see :attr:`url`). Raises :class:`MqttJsMissing` at construction when the
    MQTT.js or uPlot bundle is absent, so a missing ``make install`` is a clear error and not a blank page, and
    ValueError for a map tiles URL template that is not one.
    """

    def __init__(self, host: str = DEFAULT_HOST, port: int = DEFAULT_PORT, *, ws_port: int = DEFAULT_WS_PORT,
                 ws_url: str = "", prefix: str = DEFAULT_PREFIX, mqtt_js: Path = DEFAULT_MQTT_JS,
                 tiles: str = "", tiles_attribution: str = "", quiet: bool = True) -> None:
        mqtt_js = Path(mqtt_js)
        if not mqtt_js.is_file():
            raise MqttJsMissing(f"MQTT.js browser bundle not found at {mqtt_js}: in a repository, run `make "
                                f"install` (npm ci, then the copy into the package); or install roslink-mqtt from "
                                f"a wheel, which carries it; or pass its path")
        origin = tile_origin(tiles) if tiles else ""
        if not (UPLOT_DIST / "uPlot.esm.js").is_file():
            raise MqttJsMissing(f"uPlot not found in {UPLOT_DIST}: in a repository, run `make install` (npm ci, "
                                "then the copy into the package); or install roslink-mqtt from a wheel")
        self.config = PageConfig(ws_port=ws_port, ws_url=ws_url, prefix=prefix, tiles=tiles,
                                 tiles_attribution=tiles_attribution)
        self.httpd = ThreadingHTTPServer((host, port), _handler(_routes(mqtt_js, self.config), quiet, csp(origin)))
        self.httpd.daemon_threads = True  # a browser's keep-alive connection must not hold up stop()
        self._thread: threading.Thread | None = None

    @property
    def host(self) -> str:
        return str(self.httpd.server_address[0])

    @property
    def port(self) -> int:
        return int(self.httpd.server_address[1])

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.port}/"

    def start(self) -> DashboardServer:
        """Serve in a daemon thread and return at once."""
        self._thread = threading.Thread(target=self.httpd.serve_forever, kwargs={"poll_interval": 0.2},
                                        name="dashboard-http", daemon=True)
        self._thread.start()
        return self

    def serve(self) -> None:
        """Serve in this thread until :meth:`stop` is called from another one (or KeyboardInterrupt)."""
        try:
            self.httpd.serve_forever(poll_interval=0.2)
        finally:
            self.httpd.server_close()

    def stop(self) -> None:
        """Stop serving and close the socket (returns within about the poll interval)."""
        self.httpd.shutdown()
        self.httpd.server_close()
        if self._thread is not None:
            self._thread.join(5)
            self._thread = None

    def __enter__(self) -> DashboardServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
