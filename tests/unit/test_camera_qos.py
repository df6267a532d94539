"""The camera's subscription follows what its publishers offer (bridge/core/camera_qos.py)."""

from __future__ import annotations

from roslink_mqtt.bridge.core.camera_qos import reads_reliably


def test_reliable_publishers_are_read_reliably() -> None:
    assert reads_reliably([True, True])


def test_one_best_effort_publisher_makes_the_reader_best_effort() -> None:
    # a reliable reader would not match it at all: its pictures would never arrive
    assert not reads_reliably([True, False])


def test_no_publisher_yet_reads_best_effort_which_matches_either_kind() -> None:
    assert not reads_reliably([])
    assert not reads_reliably(iter(()))
