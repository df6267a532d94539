"""The embedded broker's log: a delivery that raced a disconnect is one line, any other failure keeps its
traceback (roslink_mqtt/broker/main.py, ClosedDeliveryFilter)."""

from __future__ import annotations

import logging
import sys

from roslink_mqtt.broker.main import ClosedDeliveryFilter


def _record(msg: str, error: BaseException) -> logging.LogRecord:
    try:
        raise error
    except BaseException:
        return logging.LogRecord("amqtt.broker", logging.ERROR, __file__, 1, msg, (), sys.exc_info())


def test_a_delivery_to_a_closed_transport_is_one_line_and_other_failures_keep_their_traceback() -> None:
    closed = _record("Task failed during broadcast shutdown: <Task …>",
                     RuntimeError("unable to perform operation on <TCPTransport closed=True>; the handler is closed"))
    assert ClosedDeliveryFilter().filter(closed)
    assert closed.exc_info is None and closed.levelno == logging.INFO
    assert closed.getMessage().startswith("a delivery failed: its client had just disconnected")
    bug = _record("Task failed and will be skipped: <Task …>", KeyError("topic"))
    assert ClosedDeliveryFilter().filter(bug)
    assert bug.exc_info is not None and bug.levelno == logging.ERROR
