"""Drive a robot along a spiral over MQTT and draw the track it reports back (the ROSLink papers' experiment).

    .venv/bin/python examples/spiral.py [--url mqtt://127.0.0.1:1883] [--username alice]
                                        [--password-file FILE] [--robot turtle1] [--seconds 20]
                                        [--rate 10] [--csv track.csv] [--no-reset]

A program without ROS (the SDK's RobotClient only) streams twist commands with a
constant turn rate and a forward speed that grows with time, so the robot
spirals outwards, while it records the robot's own global_motion reports. At
the end it stops the robot, prints how far the track got from the start at each
quarter of the run (it must grow: that is the spiral), draws the track in the
terminal and optionally writes it as CSV (t, x, y, yaw) for plotting.

The stream is the safe kind of command: if this program dies, the robot's
dead-man switch stops it within ``command_timeout`` (1 s by default).
Exits 0 when the robot reported a track, 1 otherwise.

Connection: ``--url``/``ROSLINK_URL``, ``--username``/``ROSLINK_USERNAME`` and the password from
``ROSLINK_PASSWORD`` or ``--password-file`` (never on the command line), as for every roslink-mqtt
program; without them, the local demo broker and the demo fleet's ``<user>-demo`` login.
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
import threading
import time

from roslink_mqtt.client import RobotClient, RoslinkError
from roslink_mqtt.client.messages import GlobalMotion
from roslink_mqtt.connection_options import add_connection_options, resolve_login


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_connection_options(p, old_password_option=True)  # --url, --username, --password-file, --ca-file
    p.add_argument("--robot", default="turtle1", help="(default: %(default)s)")
    p.add_argument("--seconds", type=float, default=20.0, help="length of the run (default: %(default)s)")
    p.add_argument("--rate", type=float, default=10.0, help="twist commands per second (default: %(default)s)")
    p.add_argument("--turn", type=float, default=0.8, help="turn rate, rad/s (default: %(default)s)")
    p.add_argument("--start-speed", type=float, default=0.05, help="m/s at the start (default: %(default)s)")
    p.add_argument("--end-speed", type=float, default=0.4, help="m/s at the end (default: %(default)s)")
    p.add_argument("--csv", help="write the reported track to this file")
    p.add_argument("--no-reset", action="store_true", help="do not call the robot's reset service first")
    args = p.parse_args(argv)
    if not (args.seconds > 0 and args.rate > 0):
        p.error("--seconds and --rate must be positive")
    login = resolve_login(args, p.prog, default_username="alice")
    # Without ROSLINK_PASSWORD or --password-file: the demo fleet's published <user>-demo login (README.md).
    args.url, args.username, args.ca_file = login.url, login.username, login.ca_file
    args.password = login.password if login.password is not None else f"{login.username}-demo"
    return args


def speed_at(t: float, args: argparse.Namespace) -> float:
    """Forward speed grows linearly, so the turning radius (speed / turn rate) grows: a spiral."""
    return args.start_speed + (args.end_speed - args.start_speed) * min(t / args.seconds, 1.0)


def quarter_distances(track: list[tuple[float, float, float, float]]) -> list[float]:
    """Farthest distance from the first pose reached by the end of each quarter of the run."""
    if not track:
        return []
    t0, x0, y0, _ = track[0]
    span = max(track[-1][0] - t0, 1e-9)
    out = []
    for q in range(1, 5):
        upto = [math.hypot(x - x0, y - y0) for t, x, y, _ in track if t - t0 <= span * q / 4]
        out.append(max(upto, default=0.0))
    return out


def draw(track: list[tuple[float, float, float, float]], width: int = 56) -> str:
    """The track as characters: '.' the path, 'S' the start, 'E' the end (x to the right, y up).

    Rows get half the resolution of columns, since a terminal character is about twice as tall as wide.
    """
    xs, ys = [p[1] for p in track], [p[2] for p in track]
    x_lo, y_hi = min(xs), max(ys)
    span = max(max(xs) - x_lo, y_hi - min(ys), 1e-6)
    height = width // 2
    grid = [[" "] * width for _ in range(height)]

    def put(x: float, y: float, ch: str) -> None:
        grid[round((y_hi - y) / span * (height - 1))][round((x - x_lo) / span * (width - 1))] = ch

    for x, y in zip(xs, ys, strict=True):
        put(x, y, ".")
    put(xs[0], ys[0], "S")
    put(xs[-1], ys[-1], "E")
    return "\n".join("".join(row).rstrip() for row in grid).strip("\n")


def run(client: RobotClient, args: argparse.Namespace) -> list[tuple[float, float, float, float]]:
    track: list[tuple[float, float, float, float]] = []
    lock = threading.Lock()

    def on_motion(m: GlobalMotion) -> None:
        with lock:
            track.append((time.monotonic(), m.x, m.y, m.yaw))

    sub = client.subscribe(args.robot, "global_motion", on_motion)
    period = 1.0 / args.rate
    start = time.monotonic()
    try:
        for i in range(math.ceil(args.seconds * args.rate)):  # bounded: one command per tick, then stop
            client.twist(args.robot, lx=speed_at(i * period, args), az=args.turn)
            time.sleep(max(0.0, start + (i + 1) * period - time.monotonic()))
    finally:
        for _ in range(3):  # stop on purpose, not by the dead-man switch
            client.twist(args.robot, lx=0.0, az=0.0)
            time.sleep(0.05)
    time.sleep(0.3)  # the last reports are on their way
    sub.close()
    with lock:
        return [p for p in track if p[0] >= start]


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        with RobotClient(args.username, args.password, url=args.url, robots=[args.robot],
                         ca_file=args.ca_file) as client:
            client.wait_for_robot(args.robot, timeout=10)
            if not args.no_reset:
                print(f"reset: {client.call(args.robot, 'reset', timeout=10).get('message', 'done')}")
            print(f"spiral on {args.robot}: turn {args.turn} rad/s, speed {args.start_speed} -> {args.end_speed} m/s, "
                  f"{args.seconds:g} s at {args.rate:g} Hz")
            track = run(client, args)
    except (RoslinkError, TimeoutError) as err:
        print(f"spiral: {err}", file=sys.stderr)
        return 1
    if len(track) < 2:
        print(f"spiral: {args.robot} reported no motion (is global_motion mapped?)", file=sys.stderr)
        return 1
    quarters = quarter_distances(track)
    print(f"{len(track)} poses reported; farthest from the start after each quarter: "
          + ", ".join(f"{d:.2f} m" for d in quarters))
    print(draw(track))
    if args.csv:
        with open(args.csv, "w", newline="") as f:
            writer = csv.writer(f)
            writer.writerow(["t", "x", "y", "yaw"])
            t0 = track[0][0]
            writer.writerows((f"{t - t0:.3f}", f"{x:.4f}", f"{y:.4f}", f"{yaw:.4f}") for t, x, y, yaw in track)
        print(f"track written to {args.csv}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
