"""When must the robot stop? Pure decision logic, driven by the bridge's clock.

Triggers (docs/safety.md, "When the robot stops"): the operator who last commanded motion goes away; the
bridge loses the broker; the velocity stream goes silent for
``command_timeout`` (dead-man). The bridge calls :meth:`Failsafe.tick`
often (20 Hz) and acts on the reason it returns; events that are known at
once (a last-will, a disconnect) are checked with :meth:`operator_gone` and
:meth:`link_lost` straight away.

"Motion" is a velocity stream (twist) or an autonomous goal (waypoint,
takeoff): both stop when their operator or the broker goes away; only the
stream has a dead-man timeout.

:func:`late_motion` keeps a backlog inside the bridge from replaying old
motion: a motion command is only worth executing while the dead-man would
still accept the stream it belongs to.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class Failsafe:
    command_timeout: float
    motion_owner: str | None = None  # who commanded the current motion
    active: bool = False  # motion in progress since the last stop
    last_velocity_at: float | None = None  # set while a velocity stream moves the robot
    goal_active: bool = False  # an autonomous goal (waypoint, takeoff) was commanded since the last stop
    link_up: bool = False

    def velocity_command(self, user: str, now: float, *, standstill: bool = False) -> None:
        """A velocity command from ``user``. A standstill (all zero: a released drive pad, the end of a stream) is
        the operator stopping the robot: the dead-man has nothing left to stop, so it does not fire later and
        report a failsafe that never happened; the failsafe stays armed only for a goal still under way."""
        self.motion_owner = user
        if standstill:
            self.last_velocity_at, self.active = None, self.goal_active
        else:
            self.active, self.last_velocity_at = True, now

    def goal_command(self, user: str) -> None:
        self.motion_owner, self.active, self.goal_active = user, True, True

    def tick(self, now: float, live_users: set[str]) -> str | None:
        """The reason to stop now, or None. Only reports while motion is in progress."""
        if not self.active:
            return None
        if not self.link_up:
            return "lost the broker"
        if self.motion_owner not in live_users:
            return f"operator {self.motion_owner} went away"
        if self.last_velocity_at is not None and now - self.last_velocity_at > self.command_timeout:
            return f"no velocity command for {self.command_timeout:g} s (dead-man)"
        return None

    def operator_gone(self, user: str) -> str | None:
        """Reason to stop when ``user`` goes away, if they own the motion."""
        if self.active and user == self.motion_owner:
            return f"operator {user} went away"
        return None

    def link_lost(self) -> str | None:
        self.link_up = False
        return "lost the broker" if self.active else None

    def stopped(self) -> None:
        """A stop was carried out: no motion until a live operator commands again."""
        self.active, self.last_velocity_at, self.goal_active = False, None, False


def late_motion(arrived: float | None, now: float, command_timeout: float, *, stop: bool) -> str | None:
    """Why a motion command must not be executed now, or None.

    ``arrived`` is when the command reached the bridge (paho's callback) and
    ``now`` is just before it would be published to ROS. A command that waited
    longer than ``command_timeout`` in between is stale: the operator may have
    let go, or sent a stop that is still queued behind it. A stop is always
    executed, however late; ``arrived`` None (not from MQTT) is never late.
    """
    if stop or arrived is None:
        return None
    waited = now - arrived
    if waited <= command_timeout:
        return None
    return (f"dropped a motion command that waited {waited:.2f} s inside the bridge "
            f"(more than command_timeout {command_timeout:g} s); send it again")
