"""A teleoperating client as its own process, so tests can SIGKILL or SIGSTOP it.

    python -m tests.support.operator_proc PORT USER PASSWORD ROBOT [--stream-seconds S] [--lx V] [--goal ACTION]

Runs operator presence and publishes twist commands at 10 Hz for S seconds
(forever if not given), then keeps only its presence alive.
"""

from __future__ import annotations

import argparse
import math
import threading
import time

import orjson

from roslink_mqtt.client.presence import OperatorPresence
from roslink_mqtt.mqtt import make_client
from roslink_mqtt.topics import TopicTree
from tests.support.waits import paced, wait_until


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("port", type=int)
    p.add_argument("user")
    p.add_argument("password")
    p.add_argument("robot")
    p.add_argument("--stream-seconds", type=float, default=None)
    p.add_argument("--lx", type=float, default=0.2)
    p.add_argument("--client-id", default=None)
    p.add_argument("--first-seq", type=int, default=1, help="the stream's first sequence_number (a program of a user "
                                                            "who commanded before must continue above it)")
    p.add_argument("--waypoint", action="store_true", help="send one go_to_waypoint instead of a twist stream")
    p.add_argument("--goal", metavar="ACTION", help="send one goal (Fibonacci order 40, id 'proc-goal') to ACTION "
                                                  "instead of a twist stream, then keep only presence")
    args = p.parse_args()
    client_id = args.client_id or f"op-{args.user}-{time.monotonic_ns()}"
    client = make_client(client_id, username=args.user, password=args.password,
                         url=f"mqtt://127.0.0.1:{args.port}")
    presence = OperatorPresence(client, args.user, client_id)
    client.connect("127.0.0.1", args.port, keepalive=2)
    client.loop_start()
    wait_until("the broker connection", client.is_connected, timeout=60, period=0.02)
    presence.beat()
    presence.start()
    print("operator ready", flush=True)
    topic = TopicTree().command(args.robot, args.user, "twist")
    if args.goal:
        client.publish(TopicTree().goal(args.robot, args.user, args.goal),
                       orjson.dumps({"id": "proc-goal", "goal": {"order": 40}, "client_id": client_id}), qos=1)
        print("goal sent", flush=True)
        threading.Event().wait()  # only presence runs now, until the test stops this process
    if args.waypoint:  # the same goal once a second (idempotent), no velocity stream, until stopped
        for _ in paced(1.0, within=math.inf):
            client.publish(TopicTree().command(args.robot, args.user, "go_to_waypoint"),
                           orjson.dumps({"x": 2.0, "y": 1.0}), qos=1)
    seq = args.first_seq - 1
    streaming = math.inf if args.stream_seconds is None else args.stream_seconds
    for _ in paced(0.1, within=streaming):  # S s of wall time
        seq += 1
        client.publish(topic, orjson.dumps({"message_id": 100, "sequence_number": seq,
                                            "payload": {"lx": args.lx}}), qos=0)
    threading.Event().wait()  # the stream is over: only presence runs, until the test stops this process


if __name__ == "__main__":
    main()
