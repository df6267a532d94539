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

from roslink_mqtt.localproc import Mosquitto
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
    """Mosquitto with its dynamic-security plugin (``acl export --format mosquitto-dynsec``), same fleet."""
    with Mosquitto.exported_dynsec(tmp_path_factory.mktemp("acl-dynsec"), acl_fleet, "sys_interval 1") as broker:
        yield broker
