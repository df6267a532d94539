"""Which ROS domains are taken, read from the kernel's UDP tables (fake ones here) and the RTPS port mapping."""

from __future__ import annotations

import random
from pathlib import Path

import pytest

from roslink_mqtt.ros_env import (
    SAFE_DOMAINS,
    bound_udp_ports,
    domain_of_port,
    domains_in_use,
    unused_domain_id,
    unused_domain_ids,
)

HEADER = "  sl  local_address rem_address   st tx_queue rx_queue tr tm->when retrnsmt   uid  timeout inode\n"


def _table(path: Path, *ports: int) -> Path:
    rows = "".join(f"  {i}: 0100007F:{p:04X} 00000000:0000 07 00000000:00000000 00:00000000 00000000 0 0 1 2\n"
                   for i, p in enumerate(ports))
    path.write_text(HEADER + rows)
    return path


def test_ports_are_read_from_every_table_and_a_missing_one_is_skipped(tmp_path: Path) -> None:
    v4, v6 = _table(tmp_path / "udp", 7410, 53), _table(tmp_path / "udp6", 26661)
    assert bound_udp_ports([v4, v6, tmp_path / "absent"]) == {7410, 53, 26661}


@pytest.mark.parametrize(("port", "domain"), [(7399, None), (7400, 0), (7649, 0), (7650, 1), (26661, 77)])
def test_the_rtps_mapping_names_the_domain_of_a_port(port: int, domain: int | None) -> None:
    assert domain_of_port(port) == domain


def test_a_domain_with_a_bound_port_is_in_use_and_never_picked(tmp_path: Path) -> None:
    table = _table(tmp_path / "udp", 7400 + 250 * 5 + 11, 80)
    taken = domains_in_use(tmp_path / "no-shm", [table])
    assert taken == {5}
    rng = random.Random(1)
    assert 5 not in {unused_domain_id(rng, in_use=taken) for _ in range(2000)}


def test_the_last_free_domain_is_found_and_none_left_is_a_clear_error() -> None:
    everything = set(SAFE_DOMAINS)
    assert unused_domain_id(in_use=everything - {42}) == 42
    with pytest.raises(RuntimeError, match="every ROS domain id 1..101 is in use"):
        unused_domain_id(in_use=everything)


def test_domains_picked_together_differ_and_avoid_the_ones_in_use() -> None:
    """A parallel test run's workers each take one of these: none may share a graph with another or with a
    ROS process already running."""
    taken = set(range(1, 90))
    picked = unused_domain_ids(9, random.Random(3), in_use=taken)
    assert len(set(picked)) == 9 and not set(picked) & taken
    with pytest.raises(RuntimeError, match="10 ROS domain ids are needed and only 9"):
        unused_domain_ids(10, in_use=set(range(1, 93)))
