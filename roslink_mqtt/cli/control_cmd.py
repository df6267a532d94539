"""``roslink-mqtt control claim|release|take-over|status ROBOT``: who drives a robot, and changing it."""

from __future__ import annotations

import argparse
import queue
import sys

from ..client import CommandRefused, RobotClient, RoslinkError
from ..protocol import ProtocolError
from ..protocol.lease import CONTROL, ControlOp, ControlState
from ..topics import Verb
from .connect import add_connection_options, open_client

ACTIONS = ("claim", "release", "take-over", "status")


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("control", help="claim, release or take over control of a robot, or see who holds it",
                       description="A robot takes motion and other state-changing commands from one holder of "
                                   "control at a time. `claim` takes it when nobody holds it, `take-over` takes it "
                                   "from its holder (the robot stops and the holder is told), `release` gives it "
                                   "back, `status` says who holds it. `claim` and `take-over` hold control until "
                                   "Ctrl-C, which releases it, and exit 1 if someone takes it over meanwhile. The "
                                   "lease is the user's: your other programs (pub, teleop, the dashboard) drive "
                                   "under it, and their ending does not end it.")
    p.add_argument("action", choices=ACTIONS)
    p.add_argument("robot")
    p.add_argument("--timeout", type=float, default=3.0, help="seconds to wait for the robot (default %(default)s)")
    add_connection_options(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    client = open_client(args, robots=[args.robot], presence=args.action != "status")
    try:
        if args.action == "status":
            state = client.control(args.robot, timeout=args.timeout)
            if state is None:
                print(f"roslink-mqtt control: no control state from {args.robot} within {args.timeout:g} s "
                      "(offline, or a bridge without control leases)", file=sys.stderr)
                return 1
            print(f"{args.robot}: {state.summary()}" + (f" — {state.event}" if state.event else ""))
            return 0
        client.wait_for_robot(args.robot, timeout=args.timeout)
        if args.action == "release":
            client.release_control(args.robot, timeout=args.timeout)
            print(f"{args.robot}: released")
            return 0
        state = client.claim_control(args.robot, take_over=args.action == "take-over", timeout=args.timeout)
        print(f"{args.robot}: {state.summary()}" + (f" — {state.event}" if state.event else ""))
        print("holding control; Ctrl-C releases it", flush=True)
        return _hold(client, args.robot)
    except CommandRefused as err:
        print(f"roslink-mqtt control: refused: {err}", file=sys.stderr)
        return 1
    except (TimeoutError, RoslinkError) as err:
        print(f"roslink-mqtt control: {err}", file=sys.stderr)
        return 1
    finally:
        client.close()


def _hold(client: RobotClient, robot: str) -> int:
    """Keep presence until Ctrl-C, then release; 1 when someone takes control over meanwhile."""
    lost: queue.Queue[ControlState] = queue.Queue()

    def on_state(_topic: str, payload: bytes, _retained: bool) -> None:
        try:
            state = ControlState.from_json(payload) if payload else None
        except ProtocolError:
            return
        if state is not None and state.holder != client.username:
            lost.put(state)

    topic = client.topics.state(robot, CONTROL)
    client.connection.subscribe(topic, on_state)
    try:
        state = lost.get()
    except KeyboardInterrupt:
        # the lease is the user's and outlives this client while another of theirs is live: give it back here
        try:
            client.release_control(robot, timeout=2.0)
            print(f"{robot}: released", flush=True)
        except (CommandRefused, TimeoutError, RoslinkError) as err:
            print(f"{robot}: not released ({err})", file=sys.stderr)
        return 0
    print(f"{robot}: control lost — {state.event or state.summary()}", file=sys.stderr)
    return 1


def claim_if_free(client: RobotClient, robot: str, timeout: float = 2.0) -> str | None:
    """What ``pub``, ``teleop`` and the dashboard's drive pad do before driving: claim control when nobody holds it.
    None when we hold it now (or the robot has no control leases); else why not, naming the holder."""
    if client.refusal(robot, Verb.CONTROL, ControlOp.CLAIM.value) is not None:
        return None  # not an operator: the command itself says so (with the broker's reason), not a claim
    state = client.control(robot, timeout=timeout)
    if state is None or state.holder == client.username:
        return None
    if state.holder is not None and client.username not in state.supervisors:
        if state.supervisor:
            return f"{robot} is {state.summary()}: only another supervisor can take it over"
        return (f"{robot} is {state.summary()}: `roslink-mqtt control take-over {robot}` takes it over "
                f"(the robot stops, and {state.holder} is told)")
    try:
        client.claim_control(robot, timeout=timeout)
    except CommandRefused as err:
        return str(err)
    return None
