"""Who drives the robot: the control lease, as pure decisions (no ROS, no MQTT, no clock of its own).

Motion and every other state-changing command of a robot come from one holder at a time. Before, the bridge's
"owner" was simply the last sender, and two operators streaming twists at once had both reach ``/cmd_vel``,
interleaved. Now:

* an operator claims control (``control/claim``); in ``control: auto`` (the default) the first command of an
  operator with live presence claims a free lease too, so a single driver never notices the lease;
* anyone else's command is refused with the holder's name; ``control/take_over`` moves the lease explicitly (the
  robot stops, and the old holder is told at once);
* the lease is the user's: it ends with the holder's last live client (last-will, sign-off, silence), their grant,
  or ``control/release``; one of their programs ending stops the robot (failsafe) but leaves the lease;
* ``supervisors`` (robots.yaml) take over by claiming, and nobody but another supervisor takes their lease;
* emergency stops, read-only services, actions open to viewers, parameter reads and all viewing need no lease
  (the endpoint decides which inputs ask here).

:class:`ControlLease` holds the state and answers; the endpoint (bridge/core/endpoint.py) calls it under its lock,
publishes ``state/control`` when :attr:`ControlLease.version` moves, and tells a displaced holder.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime
from enum import Enum

from ...protocol.lease import CONTROL_MODES, ControlOp, ControlState

CONTROL_AUTO, CONTROL_EXPLICIT = CONTROL_MODES


def clock_text(since: float) -> str:
    """``12:03:05``: when a lease began, as people read it (the robot's local time)."""
    return datetime.fromtimestamp(since).strftime("%H:%M:%S")


class Outcome(Enum):
    GRANTED = "granted"  # the user holds control now (it was free, or theirs already)
    TAKEN = "taken"  # the user holds control now; ``displaced`` held it before
    RELEASED = "released"
    REFUSED = "refused"


@dataclass(frozen=True, slots=True)
class Answer:
    outcome: Outcome
    reason: str = ""  # why refused; what happened otherwise (for the log and state/control's event)
    displaced: str | None = None  # the holder a take-over displaced


class ControlLease:
    """The lease of one robot. Not thread-safe by itself: the endpoint calls it under its lock."""

    def __init__(self, robot: str, mode: str = CONTROL_AUTO, supervisors: frozenset[str] = frozenset()) -> None:
        self.robot, self.mode, self.supervisors = robot, mode, supervisors
        self.holder: str | None = None
        self.since: float | None = None  # wall clock, s since the epoch
        self.event = "nobody has claimed control yet"
        self.version = 0  # grows with every change: state/control is published when it moves

    # -- what the endpoint shows --------------------------------------------------------------
    def state(self, estop: str, blocked: str = "") -> ControlState:
        return ControlState(self.holder, self.since, self.holder in self.supervisors if self.holder else False,
                            self.mode, tuple(sorted(self.supervisors)), estop, self.event, blocked)

    def driven_by(self) -> str:
        """``driven by alice since 12:03:05`` (or ``free``)."""
        if self.holder is None or self.since is None:
            return "free"
        return f"driven by {self.holder} since {clock_text(self.since)}"

    # -- the gate -------------------------------------------------------------------------------
    def gate(self, user: str, *, live: bool, now: float, claim: bool = True) -> str | None:
        """None when ``user`` may send a state-changing command now (claiming a free lease in auto mode when the
        user's presence is live, unless ``claim`` is False: the command has other checks to pass first); else why
        not, naming the holder."""
        if self.holder == user:
            return None
        if self.holder is None:
            if self.mode == CONTROL_EXPLICIT:
                return (f"nobody holds control of {self.robot} (control: explicit): claim it first "
                        f"(roslink-mqtt control claim {self.robot})")
            if live and claim:  # without presence nothing could end the lease: the command runs, nobody holds it
                self._set(user, now, f"claimed by {user} (first command)")
            return None
        return self._held_reason(user)

    def _held_reason(self, user: str) -> str:
        supervisor = " (a supervisor)" if self.holder in self.supervisors else ""
        if self.holder in self.supervisors and user not in self.supervisors:
            how = "only another supervisor can take it over"
        elif user in self.supervisors and self.holder not in self.supervisors:
            how = f"claim it to take it over (roslink-mqtt control claim {self.robot})"
        else:
            how = f"take it over explicitly with roslink-mqtt control take-over {self.robot}"
        return f"{self.robot} is {self.driven_by()}{supervisor}: {how}"

    # -- requests -------------------------------------------------------------------------------
    def request(self, user: str, op: ControlOp, *, live: bool, now: float) -> Answer:
        """``control/<op>`` from ``user`` (an operator; the endpoint checked that)."""
        if op is ControlOp.RELEASE:
            if self.holder != user:
                held = f"it is {self.driven_by()}" if self.holder else "nobody holds it"
                return Answer(Outcome.REFUSED, f"you do not hold control of {self.robot}: {held}")
            self._set(None, now, f"released by {user}")
            return Answer(Outcome.RELEASED, f"released by {user}")
        if not live:
            return Answer(Outcome.REFUSED, f"control of {self.robot} needs a live operator heartbeat from '{user}' "
                                           "(its end ends the lease, and stops the robot)")
        if self.holder == user:
            return Answer(Outcome.GRANTED, f"{user} holds control already")
        if self.holder is None:
            self._set(user, now, f"claimed by {user}")
            return Answer(Outcome.GRANTED, f"claimed by {user}")
        preempts = user in self.supervisors and self.holder not in self.supervisors
        if op is ControlOp.CLAIM and not preempts:
            return Answer(Outcome.REFUSED, self._held_reason(user))
        if self.holder in self.supervisors and user not in self.supervisors:
            return Answer(Outcome.REFUSED, self._held_reason(user))
        displaced = self.holder
        self._set(user, now, f"taken over by {user} from {displaced}")
        return Answer(Outcome.TAKEN, f"taken over by {user} from {displaced}", displaced)

    def ended(self, user: str, why: str, now: float) -> bool:
        """``user``'s presence or grant ended: the lease ends if they held it. True if it did."""
        if self.holder != user:
            return False
        self._set(None, now, f"{user}'s lease ended: {why}")
        return True

    def _set(self, holder: str | None, now: float, event: str) -> None:
        self.holder, self.since, self.event = holder, (now if holder else None), event
        self.version += 1
