"""The bridge's exit (roslink_mqtt/bridge/main.py): after rclpy's shutdown, an executor collected at the
interpreter's exit whose guard condition was destroyed already is not reported; anything else still is."""

from __future__ import annotations

import sys
from typing import Any

import pytest

from roslink_mqtt.bridge.main import _ignore_executor_teardown

pytestmark = pytest.mark.unit


class InvalidHandle(Exception):  # the name rclpy's pybind11 exception has
    pass


class Executor:  # an rclpy executor's __del__ after rclpy's shutdown, as seen by Python's unraisable hook
    def __init__(self, error: type[Exception]) -> None:
        self.error = error

    def __del__(self) -> None:
        raise self.error("cannot use Destroyable because destruction was requested")


def test_only_an_executors_destroyed_handle_is_kept_quiet() -> None:
    reported: list[Any] = []
    saved = sys.unraisablehook
    sys.unraisablehook = lambda unraisable: reported.append((unraisable.object, unraisable.exc_type))
    try:
        _ignore_executor_teardown()
        executor = Executor(InvalidHandle)
        del executor
        assert reported == []
        other = Executor(ValueError)
        del other
        assert len(reported) == 1 and reported[0][1] is ValueError
    finally:
        sys.unraisablehook = saved
