"""``roslink-mqtt teleop ROBOT``: drive with the keyboard, like teleop_twist_keyboard.

Streams the current velocity at 10 Hz while it runs; let go (space), quit
(q, Ctrl-C) or lose the connection and the robot's dead-man stops it.
"""

from __future__ import annotations

import argparse
import select
import sys
import termios
import time
import tty

from .connect import add_connection_options, open_client

KEYS = {"w": (1, 0), "s": (-1, 0), "a": (0, 1), "d": (0, -1), "x": (0, 0), " ": (0, 0)}
HELP = "w/s forward/back, a/d turn, space or x stop, e emergency stop, r arm, q quit"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("teleop", help="drive a robot with the keyboard", description=__doc__.split("\n\n")[0])
    p.add_argument("robot")
    p.add_argument("--linear", type=float, default=0.3, help="m/s per key press (default %(default)s)")
    p.add_argument("--angular", type=float, default=0.8, help="rad/s per key press (default %(default)s)")
    add_connection_options(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    if not sys.stdin.isatty():
        raise SystemExit("roslink-mqtt teleop: needs a terminal")
    client = open_client(args, robots=[args.robot])
    fd = sys.stdin.fileno()
    saved = termios.tcgetattr(fd)
    lx = az = 0.0
    print(f"teleop {args.robot}: {HELP}\r")
    try:
        tty.setcbreak(fd)
        while True:
            if select.select([sys.stdin], [], [], 0.1)[0]:
                key = sys.stdin.read(1).lower()
                if key == "q":
                    break
                if key == "e":
                    client.emergency_stop(args.robot, "teleop")
                    lx = az = 0.0
                elif key == "r":
                    client.arm(args.robot)
                elif key in KEYS:
                    dv, dw = KEYS[key]
                    lx, az = (0.0, 0.0) if (dv, dw) == (0, 0) else (dv * args.linear, dw * args.angular)
                print(f"\rlx={lx:+.2f} m/s az={az:+.2f} rad/s   ", end="", flush=True)
            client.twist(args.robot, lx=lx, az=az)
    except KeyboardInterrupt:
        pass
    finally:
        termios.tcsetattr(fd, termios.TCSADRAIN, saved)
        client.twist(args.robot)  # an explicit zero before leaving
        time.sleep(0.1)
        client.close()
        print()
    return 0
