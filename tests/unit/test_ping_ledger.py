"""Which PINGRESP answers the uplink's probe (bridge/core/ping_ledger.py)."""

from __future__ import annotations

import threading

import pytest

from roslink_mqtt.bridge.core.ping_ledger import PingLedger

pytestmark = pytest.mark.unit


def test_only_the_probes_answer_is_the_probes() -> None:
    ledger = PingLedger()
    ledger.sending(probe=False)  # paho's keep-alive, then a probe: answered in that order
    ledger.sending(probe=True)
    assert ledger.answer() is False
    assert ledger.answer() is True
    assert ledger.none_waiting()


def test_an_answer_before_the_senders_next_line_is_the_probes() -> None:
    """The failure this order prevents: the probe entered after it was queued, its answer (on loopback, under
    load) came first, found no probe, and the meter waited for it until the keep-alive dropped the link."""
    ledger = PingLedger()
    queued = threading.Event()
    answered: list[bool] = []

    def broker_answers() -> None:  # paho's thread: the PINGRESP arrives as soon as the PINGREQ is queued
        queued.wait(5)
        answered.append(ledger.answer())

    reader = threading.Thread(target=broker_answers)
    reader.start()
    ledger.sending(probe=True)
    queued.set()  # queued; this thread is held here until the answer has been read
    reader.join(5)
    assert answered == [True]
    assert ledger.none_waiting()  # so the sender clears paho's "waiting for a PINGRESP" mark


def test_a_probe_not_queued_waits_for_nothing() -> None:
    ledger = PingLedger()
    number = ledger.sending(probe=True)
    ledger.not_sent(number)
    assert ledger.none_waiting()
    ledger.sending(probe=True)
    assert not ledger.none_waiting()
    assert ledger.answer() is True


def test_a_new_connection_forgets_the_old_ones_pings() -> None:
    ledger = PingLedger()
    ledger.sending(probe=False)
    ledger.sending(probe=True)
    ledger.reset()
    ledger.sending(probe=True)
    assert ledger.answer() is True  # the new connection's first answer is its own probe's
