"""``roslink-mqtt fleet apply``'s plan: what differs between robots.yaml and what a broker enforces now.

Both sides are reduced to one shape, :class:`FleetState` (logins with their kind and a password fingerprint, and
each robot's users with their role), so the same diff serves every broker: the embedded broker reports its state
on its control topic (broker/admin.py), Mosquitto's dynamic-security plugin and RabbitMQ are read by their own
adapters (cli/fleet_apply.py). A :class:`Plan` lists the steps in the order they must run: new logins first (a
grant may name them), then passwords, then grants, removed logins last.

The fingerprint is the first 16 hex digits of SHA-256 over the stored PBKDF2 hash (hashes, while a robot's password
rotates): equal hashes, equal
fingerprints; it tells a changed password without sending a hash anywhere, and guessing passwords from it is
harder than from the hash itself (which needs its salt and 210,000 iterations per guess anyway).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from typing import Any

from .model import Fleet

ROBOT, USER, ADMIN = "robot", "user", "admin"


def fingerprint(password_hash: str) -> str:
    """A stored hash's fingerprint (see the module's docstring); "" for no hash."""
    return hashlib.sha256(password_hash.encode()).hexdigest()[:16] if password_hash else ""


@dataclass(frozen=True)
class FleetState:
    """Who may log in (login → (kind, password fingerprint)) and each robot's users (robot → user → role)."""

    logins: dict[str, tuple[str, str]] = field(default_factory=dict)
    grants: dict[str, dict[str, str]] = field(default_factory=dict)

    @classmethod
    def of(cls, fleet: Fleet) -> FleetState:
        def accepted(login: str) -> str:  # every hash it may log in with (a robot's previous one while rotating)
            return fingerprint("|".join(fleet.accepted_hashes(login)))

        logins = {name: (ROBOT, accepted(name)) for name in fleet.robots}
        logins.update({name: (ADMIN if u.admin else USER, accepted(name)) for name, u in fleet.users.items()})
        grants = {robot: {u: role.value for u, role in sorted(fleet.users_of(robot).items())}
                  for robot in fleet.robots}
        return cls(dict(sorted(logins.items())), grants)

    def to_data(self) -> dict[str, Any]:
        return {"logins": {name: {"kind": kind, "password": fp} for name, (kind, fp) in self.logins.items()},
                "grants": self.grants}

    @classmethod
    def from_data(cls, data: Any) -> FleetState:
        """Read what a broker reported (broker/admin.py's ``getFleet``); ValueError names what is wrong."""
        if not isinstance(data, dict) or not isinstance(data.get("logins"), dict) \
                or not isinstance(data.get("grants"), dict):
            raise ValueError('expected {"logins": {…}, "grants": {…}}')
        logins = {}
        for name, entry in data["logins"].items():
            if not isinstance(entry, dict) or entry.get("kind") not in (ROBOT, USER, ADMIN):
                raise ValueError(f"logins.{name}: expected {{\"kind\": robot|user|admin, \"password\": …}}")
            logins[name] = (entry["kind"], str(entry.get("password", "")))
        grants = {robot: {str(u): str(r) for u, r in users.items()} for robot, users in data["grants"].items()
                  if isinstance(users, dict)}
        return cls(logins, grants)


@dataclass(frozen=True)
class Step:
    """One change: ``verb`` (add, remove, password, kind, grants) on ``login`` (a login, or a robot for grants)."""

    verb: str
    name: str
    detail: str = ""

    def __str__(self) -> str:
        return f"{self.verb:<8} {self.name}" + (f": {self.detail}" if self.detail else "")


@dataclass(frozen=True)
class Plan:
    steps: tuple[Step, ...]

    def __bool__(self) -> bool:
        return bool(self.steps)

    def of(self, verb: str) -> list[Step]:
        return [s for s in self.steps if s.verb == verb]

    def lines(self) -> list[str]:
        return [str(s) for s in self.steps] or ["nothing to change: the broker enforces robots.yaml"]


def _roles(users: dict[str, str]) -> str:
    return ", ".join(f"{u}:{r}" for u, r in sorted(users.items())) or "nobody"


def plan(target: FleetState, live: FleetState, *, passwords_known: bool = True) -> Plan:
    """The steps that make ``live`` equal ``target``. ``passwords_known``: the live side reports fingerprints (the
    embedded broker); Mosquitto and RabbitMQ keep theirs to themselves, so a password is set only when the caller
    has it (``--passwords``), never planned from a difference."""
    steps: list[Step] = []
    for name, (kind, _) in target.logins.items():
        if name not in live.logins:
            steps.append(Step("add", name, kind))
    for name, (kind, fp) in target.logins.items():
        if name in live.logins:
            live_kind, live_fp = live.logins[name]
            if live_kind != kind:
                steps.append(Step("kind", name, f"{live_kind} → {kind}"))
            if passwords_known and live_fp != fp:
                steps.append(Step("password", name, "new password hash(es)"))
    for robot in sorted(set(target.grants) | set(live.grants)):
        want, have = target.grants.get(robot), live.grants.get(robot)
        if want is not None and want != have:
            steps.append(Step("grants", robot, f"{_roles(have or {})} → {_roles(want)}"))
        elif want is None and have:
            steps.append(Step("grants", robot, f"{_roles(have)} → cleared (robot removed)"))
    for name in live.logins:
        if name not in target.logins:
            steps.append(Step("remove", name, live.logins[name][0]))
    return Plan(tuple(steps))
