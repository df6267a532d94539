"""``roslink-mqtt fleet apply``: make a running broker enforce robots.yaml, without restarting anything.

As an administrator's login, over MQTT:

* **embedded** (``roslink-mqtt-broker``): ask its control topic for what it enforces (broker/admin.py), print the
  plan (config/plan.py), then have it reload its fleet file: removed logins and users who lost a grant are
  disconnected, the robots' grants republished. The broker applies the file it was started with, so apply
  checks that this file and the broker's are the same bytes (edit it on the broker host, or copy it there).
* **mosquitto** (the dynamic-security plugin, ``acl export --format mosquitto-dynsec``): cli/fleet_dynsec.py.

Then, for every broker, each robot's grants are published retained on ``P/<robot>/grants`` (the embedded broker
does that itself on reload), where the robot's bridge takes them: a revoked operator who is driving stops the
robot. ``--dry-run`` prints the plan and changes nothing.
"""

from __future__ import annotations

import argparse
import hashlib
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

from ..config import ConfigError, Fleet, load_fleet
from ..config.grants import grants_of
from ..config.plan import FleetState, Plan, plan
from ..connection_options import ENV_PASSWORD, Login, add_connection_options, resolve_login
from ..mqtt import parse_broker_urls
from ..topics import FLEET_CONTROL, FLEET_CONTROL_RESPONSE
from .fleet_admin import AdminChannel, AdminError

PROG = "roslink-mqtt fleet apply"
KINDS = ("embedded", "mosquitto", "rabbitmq")


def register(actions: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = actions.add_parser(
        "apply", help="make a running broker enforce the fleet file now (logins, grants), and tell the robots",
        description="Compare the fleet file with what a running broker enforces, print the plan, and apply it "
                    "without restarting anything, as an administrator's login: the embedded broker reloads its "
                    "fleet file (which must be this file: edit it on the broker host); Mosquitto's dynamic-security "
                    "plugin gets the logins and access rules that differ. Users who lost a grant are disconnected "
                    "and refused at once; each robot's grants are published retained for its bridge.")
    p.add_argument("--config", default="config/robots.yaml", help="fleet file (default: %(default)s)")
    p.add_argument("--broker-kind", choices=KINDS, default="embedded", help="default: %(default)s")
    p.add_argument("--dry-run", action="store_true", help="print the plan; change nothing")
    p.add_argument("--grants-only", action="store_true",
                   help="publish the robots' grants only: for a broker whose logins and rules are changed another "
                        "way (Mosquitto from exported files, RabbitMQ definitions)")
    p.add_argument("--passwords", metavar="FILE",
                   help="mosquitto: 'login: password' lines for new logins and new passwords (its dynamic-security "
                        "plugin takes passwords in clear text only; each is checked against the fleet file's hash)")
    p.add_argument("--rabbitmqctl", default="rabbitmqctl", metavar="COMMAND",
                   help="rabbitmq: how to run rabbitmqctl against a node of the cluster (default: %(default)s)")
    p.add_argument("--vhost", default="roslink", help="rabbitmq: the fleet's vhost (default: %(default)s)")
    p.add_argument("--timeout", type=float, default=10.0, help="s to wait for each answer (default: %(default)s)")
    add_connection_options(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    try:
        fleet = load_fleet(args.config, need_hashes=True)
    except ConfigError as err:
        print(f"{PROG}: {err}", file=sys.stderr)
        return 2
    login = resolve_login(args, PROG)
    if not login.username or login.password is None:
        print(f"{PROG}: needs an administrator's login: -u NAME and {ENV_PASSWORD} or --password-file",
              file=sys.stderr)
        return 2
    user = fleet.users.get(login.username)
    if user is None or not user.admin:
        print(f"{PROG}: {login.username} is not an administrator in {args.config} (admin: true)", file=sys.stderr)
        return 2
    started = time.monotonic()
    try:
        changed = _apply(args, fleet, login)
    except (AdminError, ValueError) as err:
        print(f"{PROG}: {err}", file=sys.stderr)
        return 1
    if not args.dry_run:
        print(f"applied: {changed} change(s) in {(time.monotonic() - started) * 1000:.0f} ms")
    return 0


def _apply(args: argparse.Namespace, fleet: Fleet, login: Login) -> int:
    """Plan, change the broker, publish the grants: how many changes."""
    changed = 0
    with AdminChannel(login, timeout=args.timeout) as channel:
        published = channel.retained(fleet.topics.grants_filter())  # read first: apply then writes at once

        def grants() -> int:
            return _publish_everywhere(args, channel, published, fleet, login)

        if args.grants_only:
            return grants()
        if args.broker_kind == "embedded":
            changed = apply_embedded(channel, fleet, Path(args.config), dry_run=args.dry_run)
            if changed and not args.dry_run:  # it has just republished them
                published = channel.retained(fleet.topics.grants_filter(), quiet=0.2)
            return changed + grants()
        if args.broker_kind == "mosquitto":
            from .fleet_dynsec import apply_mosquitto

            changed = apply_mosquitto(channel, fleet, passwords_file=args.passwords, dry_run=args.dry_run)
            return changed + grants()
        from .fleet_rabbitmq import Rabbitmqctl, plan_rabbitmq, run_rabbitmq

        ctl = Rabbitmqctl(args.rabbitmqctl)
        lines, document, removed, reconnect = plan_rabbitmq(fleet, ctl=ctl, vhost=args.vhost, url=login.url or "",
                                                            passwords_file=args.passwords, dry_run=args.dry_run)
        # the grants first: each rabbitmqctl call takes a second or two, and a bridge told first stops a revoked
        # driver (and refuses them) at once; a user granted meanwhile is let in a moment later
        changed = grants()
        if not args.dry_run:
            run_rabbitmq(ctl, document, removed, reconnect)
        return changed + len(lines)


def _publish_everywhere(args: argparse.Namespace, channel: AdminChannel, published: dict[str, bytes], fleet: Fleet,
                        login: Login) -> int:
    """The grants on the broker ``channel`` is connected to, then on every other node ``--url`` lists (a cluster
    that keeps retained messages per node: RabbitMQ)."""
    changed = publish_grants(channel, fleet, published, by=login.username or "", dry_run=args.dry_run)
    for other in parse_broker_urls(login.url or "")[1:]:
        with AdminChannel(replace(login, url=str(other)), timeout=args.timeout) as node:
            print(f"node {other}:")
            changed += publish_grants(node, fleet, node.retained(fleet.topics.grants_filter()),
                                      by=login.username or "", dry_run=args.dry_run)
    return changed


def print_plan(title: str, steps: Plan | list[str]) -> None:
    lines = steps.lines() if isinstance(steps, Plan) else (steps or ["nothing to change"])
    print(title)
    for line in lines:
        print(f"  {line}")


def apply_embedded(channel: AdminChannel, fleet: Fleet, config: Path, *, dry_run: bool) -> int:
    """Reload the embedded broker when what it enforces differs from ``fleet``; the steps taken."""
    live = _state(channel.request(FLEET_CONTROL, FLEET_CONTROL_RESPONSE, [{"command": "getFleet"}])[0])
    steps = plan(FleetState.of(fleet), FleetState.from_data(live))
    print_plan(f"embedded broker {channel.login.url} ({live.get('file')}):", steps)
    if dry_run or not steps:
        return 0
    here = hashlib.sha256(config.read_bytes()).hexdigest()
    if live.get("sha256") != here:
        raise AdminError(f"the broker applies {live.get('file')}, whose bytes differ from {config}: copy {config} "
                         "there (or edit the broker's file), then run fleet apply again")
    reloaded = _state(channel.request(FLEET_CONTROL, FLEET_CONTROL_RESPONSE, [{"command": "reload"}])[0])
    left = plan(FleetState.of(fleet), FleetState.from_data(reloaded))
    if left:
        raise AdminError("the broker reloaded but still differs: " + "; ".join(left.lines()))
    return len(steps.steps)


def _state(response: dict[str, Any]) -> dict[str, Any]:
    if "error" in response:
        raise AdminError(f"{response.get('command')}: {response['error']}")
    data = response.get("data")
    if not isinstance(data, dict):
        raise AdminError(f"{response.get('command')}: the broker's answer has no data")
    return data


def publish_grants(channel: AdminChannel, fleet: Fleet, there: dict[str, bytes], *, by: str,
                   dry_run: bool = False) -> int:
    """Each robot's grants, retained, where its bridge reads them; only those that differ from ``there`` (what the
    broker holds) and a removed robot's are cleared. How many were written (``dry_run``: would be)."""
    # "bridge": the retained message its bridge reads, apart from the broker's own "grants" step above it
    verb = "grants would be published" if dry_run else "grants published"
    topics = fleet.topics
    written = 0
    issued = time.time()
    for robot in fleet.robots:
        want = grants_of(fleet, robot, issued=issued, by=by)
        topic = topics.grants(robot)
        if _same_users(there.get(topic), want.users):
            continue
        if not dry_run:
            channel.publish(topic, want.to_json(), retain=True)
        print(f"  bridge   {robot}: {verb} ({', '.join(f'{u}:{r}' for u, r in want.users.items()) or 'nobody'})")
        written += 1
    for topic, payload in there.items():
        parsed = topics.parse(topic)
        if payload and parsed is not None and parsed.robot not in fleet.robots:
            if not dry_run:
                channel.publish(topic, b"", retain=True)
            done = "would be cleared" if dry_run else "cleared"
            print(f"  bridge   {parsed.robot}: grants {done} (no such robot in the fleet)")
            written += 1
    return written


def _same_users(payload: bytes | None, users: dict[str, str]) -> bool:
    from ..protocol.errors import ProtocolError
    from ..protocol.grants import RobotGrants

    if not payload:
        return False
    try:
        return RobotGrants.from_json(payload).users == users
    except ProtocolError:
        return False
