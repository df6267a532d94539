"""Pure logic of tests/integration/test_failover.py: no processes, no sockets."""

from __future__ import annotations

import pytest

from roslink_mqtt.mqtt import parse_broker_urls


def test_a_list_of_brokers_parses_and_refuses_mixed_schemes() -> None:
    urls = parse_broker_urls("mqtt://a:1883, mqtt://b:1884,mqtt://c")
    assert [(u.host, u.port) for u in urls] == [("a", 1883), ("b", 1884), ("c", 1883)]
    assert parse_broker_urls(["mqtts://a", "mqtts://b:9883"])[1].port == 9883
    with pytest.raises(ValueError, match="mix schemes"):
        parse_broker_urls("mqtts://a,mqtt://b")
    with pytest.raises(ValueError, match="no broker URL"):
        parse_broker_urls(" , ")
