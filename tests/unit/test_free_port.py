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


def test_each_test_worker_draws_from_a_slice_of_its_own(monkeypatch) -> None:
    """Two xdist workers that drew the same free port before either bound it lost a session's broker in CI."""
    from roslink_mqtt.localproc import _share

    monkeypatch.delenv("PYTEST_XDIST_WORKER", raising=False)
    assert _share(10000, 31768) == (10000, 31768)  # not a test worker: the whole range
    slices = []
    for n in range(3):
        monkeypatch.setenv("PYTEST_XDIST_WORKER", f"gw{n}")
        monkeypatch.setenv("PYTEST_XDIST_WORKER_COUNT", "3")
        slices.append(_share(10000, 31768))
        ports = [free_port() for _ in range(20)]
        assert all(slices[-1][0] <= p < slices[-1][1] for p in ports), (slices[-1], ports)
    assert all(a[1] <= b[0] for a, b in zip(slices, slices[1:], strict=False))  # disjoint, in order


def test_a_port_handed_out_is_not_handed_out_again() -> None:
    """A fleet file's port is chosen long before its broker binds it: no later draw of this process may take it."""
    ports = [free_port() for _ in range(500)]
    assert len(set(ports)) == len(ports)
