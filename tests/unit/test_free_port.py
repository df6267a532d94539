"""free_port draws servers' ports below the kernel's ephemeral range (roslink_mqtt/localproc.py): a port from
bind(0) is one the kernel also gives outgoing connections, which took one between pick and bind in CI."""

from __future__ import annotations

from roslink_mqtt.localproc import _ephemeral_low, free_port, port_free


def test_ports_are_free_and_below_the_ephemeral_range() -> None:
    low = _ephemeral_low()
    ports = [free_port() for _ in range(50)]
    assert all(10000 <= p < low for p in ports), ports
    assert all(port_free(p) for p in ports)
    assert len(set(ports)) > 40  # drawn at random, not the same few
