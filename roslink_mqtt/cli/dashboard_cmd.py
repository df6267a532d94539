"""``roslink-mqtt dashboard``: serve the web dashboard (static files only) on 127.0.0.1.

The command takes no login: the browser logs in to the broker's WebSocket listener itself, with the user's own
fleet credentials (docs/dashboard.md, "Security model"). The fleet file is read only for the WebSocket port and
the topic prefix, never for robot names or users: the page shows what the broker lets its user read.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..config import load_fleet
from ..dashboard.server import (
    DEFAULT_HOST,
    DEFAULT_MQTT_JS,
    DEFAULT_PORT,
    DEFAULT_PREFIX,
    DEFAULT_WS_PORT,
    DashboardServer,
    MqttJsMissing,
)


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("dashboard", help="serve the web dashboard (the browser logs in to the broker itself)",
                       description="Serve the dashboard page on HOST:PORT. The page connects to the broker's "
                                   "WebSocket listener with the user's own login, so the broker's ACL decides "
                                   "what it shows and allows; this server holds no credentials.")
    p.add_argument("--config", default=None,
                   help="fleet file, for the broker's WebSocket port and the topic prefix (default: none; "
                        f"port {DEFAULT_WS_PORT}, prefix '{DEFAULT_PREFIX}')")
    p.add_argument("--host", default=DEFAULT_HOST, help="address to serve on (default: %(default)s)")
    p.add_argument("--port", type=int, default=DEFAULT_PORT, help="HTTP port, 0 = any free one (default: %(default)s)")
    p.add_argument("--ws-url", default="",
                   help="the broker's WebSocket URL the page offers (default: ws://<the page's host>:<ws port>)")
    p.add_argument("--ws-port", type=int, default=None,
                   help="the broker's WebSocket port when --ws-url is not given (default: the fleet file's "
                        f"broker.ws_port, else {DEFAULT_WS_PORT})")
    p.add_argument("--mqtt-js", type=Path, default=DEFAULT_MQTT_JS,
                   help="MQTT.js browser bundle (default: the copy inside the package, roslink_mqtt/dashboard/vendor/)")
    p.add_argument("--tiles", default="",
                   help="map tile URL template for the fleet map's GPS view, e.g. "
                        "'https://tile.openstreetmap.org/{z}/{x}/{y}.png' (default: none; the map works without)")
    p.add_argument("--tiles-attribution", default="", help="attribution the tile server asks to be shown under the map")
    p.add_argument("--verbose", action="store_true", help="log every HTTP request")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    ws_port, prefix = DEFAULT_WS_PORT, DEFAULT_PREFIX
    if args.config:
        fleet = load_fleet(args.config)
        ws_port, prefix = fleet.broker.ws_port or 0, fleet.prefix
    if args.ws_port is not None:
        ws_port = args.ws_port
    if not ws_port and not args.ws_url:
        print("roslink-mqtt: the broker has no WebSocket listener (ws_port 0): pass --ws-url or --ws-port",
              file=sys.stderr)
        return 2
    try:
        server = DashboardServer(args.host, args.port, ws_port=ws_port, ws_url=args.ws_url, prefix=prefix,
                                 mqtt_js=args.mqtt_js, tiles=args.tiles, tiles_attribution=args.tiles_attribution,
                                 quiet=not args.verbose)
    except (MqttJsMissing, ValueError) as err:
        print(f"roslink-mqtt: {err}", file=sys.stderr)
        return 2
    except OSError as err:
        print(f"roslink-mqtt: cannot serve on {args.host}:{args.port}: {err.strerror or err}", file=sys.stderr)
        return 2
    target = args.ws_url or f"ws://<page host>:{ws_port}"
    print(f"dashboard on {server.url} (broker WebSocket {target}); Ctrl-C stops it", flush=True)
    try:
        server.serve()
    except KeyboardInterrupt:
        pass
    return 0
