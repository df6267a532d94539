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
