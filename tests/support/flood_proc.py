"""An attacker's flood as its own process, so its client's CPU is not the test's (whose clocks measure).

    python -m tests.support.flood_proc PORT USER PASSWORD TOPIC --seconds S --max N

Publishes ``{"id": n, "op": "get", "names": ["max_speed"]}`` at QoS 0 as fast as paho takes it, for at most S
seconds and N messages, waits until paho has written them all (at most 2 s more: a paced broker reads
slowly), then prints one JSON line: ``{"sent": n, "seconds": s}`` (n handed to paho).
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import orjson

from roslink_mqtt.mqtt import make_client
from tests.support.waits import wait_until


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("port", type=int)
    p.add_argument("user")
    p.add_argument("password")
    p.add_argument("topic")
    p.add_argument("--seconds", type=float, required=True)
    p.add_argument("--max", type=int, required=True)
    args = p.parse_args()
    client = make_client(f"{args.user}-flood-{time.monotonic_ns()}", username=args.user, password=args.password,
                         url=f"mqtt://127.0.0.1:{args.port}")
    client.max_queued_messages_set(0)
    client.connect("127.0.0.1", args.port, keepalive=30)
    client.loop_start()
    try:
        wait_until("the flood's connection", client.is_connected, timeout=5, period=0.01)
    except AssertionError:
        sys.exit("flood: could not connect")
    start = time.monotonic()
    n, last = 0, None
    while n < args.max and time.monotonic() - start < args.seconds:
        n += 1
        last = client.publish(args.topic, orjson.dumps({"id": n, "op": "get", "names": ["max_speed"]}), qos=0)
    if last is not None:
        try:
            last.wait_for_publish(timeout=2)
        except (RuntimeError, ValueError):
            pass
    print(orjson.dumps({"sent": n, "seconds": round(time.monotonic() - start, 3)}).decode(), flush=True)
    os._exit(0)  # not disconnect(): its packet would queue behind what a paced broker has not read yet


if __name__ == "__main__":
    main()
