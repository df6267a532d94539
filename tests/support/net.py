"""Loopback-only networking helpers for tests (from :mod:`roslink_mqtt.localproc`, shared with the demo and bench)."""

from __future__ import annotations

from roslink_mqtt.localproc import free_port, port_free, wait_for_port

__all__ = ["free_port", "port_free", "wait_for_port"]
