"""broker.tls.host: TLS on an address of its own, in the fleet file, the embedded broker's listeners and the
Mosquitto export (the embedded broker serving it is tests/integration/test_broker_runtime.py's TLS test)."""

from __future__ import annotations

from pathlib import Path

import pytest

from roslink_mqtt.broker.export import mosquitto_conf_text
from roslink_mqtt.broker.server import ServerOptions
from roslink_mqtt.config import ConfigError, load_fleet

DEMO = Path(__file__).resolve().parents[2] / "config" / "robots.yaml"


def _fleet(tmp_path: Path, tls: str) -> Path:
    text = DEMO.read_text()
    assert "  ws_port: 8083\n" in text
    path = tmp_path / "robots.yaml"
    path.write_text(text.replace("  ws_port: 8083\n", f"  ws_port: 8083\n  tls: {tls}\n", 1))
    return path


def test_tls_binds_its_own_host_and_the_others_stay(tmp_path: Path) -> None:
    fleet = load_fleet(_fleet(tmp_path, "{host: 0.0.0.0, port: 8883, certfile: c.pem, keyfile: k.pem}"))
    assert fleet.broker.host == "127.0.0.1" and fleet.broker.tls_host() == "0.0.0.0"
    listeners = {lst.kind: lst.host for lst in ServerOptions.from_fleet(fleet).listeners()}
    assert listeners == {"tcp": "127.0.0.1", "ws": "127.0.0.1", "tls": "0.0.0.0"}
    conf = mosquitto_conf_text(fleet, tmp_path / "passwd", tmp_path / "acl")
    assert "listener 1883 127.0.0.1\n" in conf and "listener 8883 0.0.0.0\n" in conf


def test_without_tls_host_tls_follows_the_broker_host(tmp_path: Path) -> None:
    fleet = load_fleet(_fleet(tmp_path, "{port: 8883, certfile: c.pem, keyfile: k.pem}"))
    assert fleet.broker.tls_host() == "127.0.0.1" and fleet.broker.tls_host("10.0.0.5") == "10.0.0.5"


def test_a_misspelt_tls_key_is_named(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="hots"):
        load_fleet(_fleet(tmp_path, "{hots: 0.0.0.0, port: 8883, certfile: c.pem, keyfile: k.pem}"))


def test_port_0_turns_plain_mqtt_off_everywhere(tmp_path: Path) -> None:
    """A TLS-only broker: no plain listener in the embedded broker (amqtt's required 'default' left unbound) or the
    Mosquitto export; a fleet with no listener at all is refused with the reason."""
    from roslink_mqtt.broker.acl import LiveFleet
    from roslink_mqtt.broker.export_rabbitmq import rabbitmq_conf_text
    from roslink_mqtt.broker.server import amqtt_config

    path = _fleet(tmp_path, "{host: 0.0.0.0, port: 8883, certfile: c.pem, keyfile: k.pem}")
    path.write_text(path.read_text().replace("  port: 1883\n", "  port: 0\n", 1).replace("  ws_port: 8083\n",
                                                                                           "  ws_port: 0\n", 1))
    fleet = load_fleet(path)
    options = ServerOptions.from_fleet(fleet)
    assert [(lst.kind, lst.host, lst.port) for lst in options.listeners()] == [("tls", "0.0.0.0", 8883)]
    listeners = amqtt_config(options, LiveFleet(fleet))["listeners"]
    assert listeners["default"] == {"type": "tcp", "bind": None} and listeners["tls"]["bind"] == "0.0.0.0:8883"
    conf = mosquitto_conf_text(fleet, tmp_path / "passwd", tmp_path / "acl")
    assert [line for line in conf.splitlines() if line.startswith("listener ")] == ["listener 8883 0.0.0.0"]
    assert "mqtt.listeners.tcp = none\n" in rabbitmq_conf_text(fleet, tmp_path / "definitions.json")
    path.write_text(path.read_text().replace("  tls: {host: 0.0.0.0, port: 8883, certfile: c.pem, keyfile: k.pem}\n",
                                             "", 1))
    with pytest.raises(ConfigError, match="the broker would accept no connection"):
        load_fleet(path)
