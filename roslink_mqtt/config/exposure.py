"""Whether a broker about to listen beyond this machine would expose something it must not. ROS-free, pure.

Two mistakes a copied demo makes on its way to a server: plain MQTT (and MQTT over WebSocket) on a public address,
where every login's password crosses the network in clear text, and the demo fleet's published passwords
(README: ``alice-demo`` …), which anybody can log in with. Neither matters on loopback (the demo, the tests, a
broker behind a TLS terminator on the same host); both are refused on any other address -- the first unless the
fleet file says the network is trusted (``broker.allow_plaintext: true``). The broker checks at start and
``roslink-mqtt fleet`` when it validates.
"""

from __future__ import annotations

import ipaddress

from .model import Fleet
from .passwords import verify_password

DEMO_PASSWORD_SUFFIX = "-demo"  # the demo fleet's published passwords are "<login>-demo" (README, "The demo fleet")


def is_loopback(host: str) -> bool:
    """``127.0.0.0/8``, ``::1`` and ``localhost``: reachable from this machine only."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:  # a name: it resolves to whatever the network says
        return False


def demo_logins(fleet: Fleet) -> list[str]:
    """Logins whose password is still the demo fleet's published one (``<login>-demo``)."""
    logins = [(name, robot.password_hash) for name, robot in fleet.robots.items()]
    logins += [(name, user.password_hash) for name, user in fleet.users.items()]
    return [name for name, hashed in logins if hashed and verify_password(f"{name}{DEMO_PASSWORD_SUFFIX}", hashed)]


def exposure_problems(fleet: Fleet, host: str | None = None, ws_port: int | None = None,
                      port: int | None = None) -> list[str]:
    """Why a broker for ``fleet`` must not listen on ``host`` (default ``broker.host``) with these listeners; empty when
    it may. ``ws_port``, ``port``: the WebSocket and plain MQTT listeners in use when not the fleet's (command-line
    overrides; 0 = off). A TLS listener on a host of its own (``broker.tls.host``) beyond loopback needs fresh
    passwords, not allow_plaintext; so does a TLS-only broker (``port: 0``, ``ws_port: 0``) on a public host."""
    tls_host = fleet.broker.tls_host(host)
    ws_host = fleet.broker.ws_bind(host)
    host = fleet.broker.host if host is None else host
    ws = fleet.broker.ws_port if ws_port is None else ws_port
    mqtt = fleet.broker.port if port is None else port
    public = [h for h, on in ((host, mqtt), (ws_host, ws), (tls_host, True)) if on and h and not is_loopback(h)]
    if not public:
        return []
    problems = []
    # the plain listeners beyond loopback, by the key that sets their address
    by_key: dict[tuple[str, str], list[str]] = {}
    ws_key = "broker.ws_host" if fleet.broker.ws_host else "broker.host"
    for name, on, key, where in (("plain MQTT", mqtt, "broker.host", host),
                                 ("MQTT over WebSocket", ws, ws_key, ws_host)):
        if on and not is_loopback(where):
            by_key.setdefault((key, where), []).append(name)
    if by_key and not fleet.broker.allow_plaintext:
        for (key, where), names in by_key.items():
            problems.append(f"{key} {where} is not loopback, and {' and '.join(names)} would carry every login's "
                            "password in clear text: keep host: 127.0.0.1 and give TLS an address of its own "
                            "(broker.tls.host; tls.ws_port for wss://) or a TLS terminator, turn them off (port: 0, "
                            "ws_port: 0), or set broker.allow_plaintext: true for a network you trust")
    demo = demo_logins(fleet)
    if demo:
        problems.append(f"{', '.join(demo)} still log in with the demo fleet's published passwords (<login>-demo): "
                        f"make new ones with `roslink-mqtt passwd NAME` before the broker listens on "
                        f"{' and '.join(dict.fromkeys(public))}")
    return problems
