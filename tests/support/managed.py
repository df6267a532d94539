"""A child process (a broker) that tests can freeze, kill, stop and restart.

Subclasses say how to start it; stopping (SIGCONT, SIGTERM to its process group, SIGKILL
after the timeout), signalling and reading the log come from
:class:`roslink_mqtt.localproc.LocalProcess`, shared with the demo and the benchmarks.
"""

from __future__ import annotations

import signal

from roslink_mqtt.localproc import LocalProcess


class ManagedProcess(LocalProcess):
    """A :class:`LocalProcess` stopped with SIGTERM whose log is appended to across restarts."""

    stop_signal = signal.SIGTERM
    append = True
