"""Brokers shared by the modules that test the brokers themselves (one of each for the whole run).

The ACL matrix (test_broker_matrix.py) and the MQTT conformance tests (test_broker_mqtt_conformance.py) both need
the embedded broker and the exported Mosquitto (files; the matrix also the dynamic-security plugin) loaded with the
same fleet; starting them once saves the suite a few seconds. Tests that share them use topics and client ids of
their own.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from roslink_mqtt.config import load_fleet
from roslink_mqtt.localproc import Mosquitto, fleet_copy, free_port
from tests.support.broker_setup import ExportedMosquitto, write_fleet
from tests.support.embedded_broker import EmbeddedBrokerProcess


@pytest.fixture(scope="session")
def acl_fleet(tmp_path_factory) -> Path:
    return write_fleet(tmp_path_factory.mktemp("acl-fleet"))


@pytest.fixture(scope="session")
def acl_embedded(acl_fleet: Path, tmp_path_factory) -> Iterator[EmbeddedBrokerProcess]:
    broker = EmbeddedBrokerProcess(tmp_path_factory.mktemp("acl-embedded"), acl_fleet, "--sys-interval", "1",
                                   "--login-free-failures", "100")
    with broker:
        yield broker


@pytest.fixture(scope="session")
def acl_mosquitto(acl_fleet: Path, tmp_path_factory) -> Iterator[ExportedMosquitto]:
    with ExportedMosquitto(tmp_path_factory.mktemp("acl-mosquitto"), acl_fleet, "sys_interval 1") as broker:
        yield broker


@pytest.fixture(scope="session")
def acl_mosquitto_dynsec(acl_fleet: Path, tmp_path_factory) -> Iterator[Mosquitto]:
    """Mosquitto with its dynamic-security plugin (``acl export --format mosquitto-dynsec``), same fleet on a port of
    its own: on the fleet file's port it met ``acl_mosquitto``'s listener, and either died ("address already in use",
    every test on it lost) or, when that listener answered the readiness check first, the dynsec rows were run
    against the other Mosquitto."""
    work = tmp_path_factory.mktemp("acl-dynsec")
    fleet = fleet_copy(work / "robots.yaml", acl_fleet, port=free_port())
    with Mosquitto.exported_dynsec(work, fleet, "sys_interval 1") as broker:
        assert broker.port != load_fleet(acl_fleet).broker.port
        yield broker
