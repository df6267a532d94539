"""Timings the tests measured, printed in the run's closing summary (tests/conftest.py prints them)."""

from __future__ import annotations

MEASUREMENTS: list[tuple[str, float, float]] = []


def record_measurement(name: str, seconds: float, deadline: float) -> None:
    """Keep a timing for the closing summary (tests print what they measured)."""
    MEASUREMENTS.append((name, seconds, deadline))
