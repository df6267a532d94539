"""``roslink-mqtt teleop ROBOT``: drive with the keyboard, like teleop_twist_keyboard.

Keys step the velocity: each w/s adds or takes one linear step, each a/d one
angular step, so w then a drives an arc and a second w goes faster. Streams the
current velocity at 10 Hz while it runs; let go (space), quit (q, Ctrl-C) or lose
the connection and the robot's dead-man stops it.
"""

from __future__ import annotations

import argparse
import select
import sys
import time
from dataclasses import dataclass

from .connect import add_connection_options, open_client
from .control_cmd import claim_if_free

# key -> (linear steps, angular steps) added to the current velocity
STEPS = {"w": (1, 0), "s": (-1, 0), "a": (0, 1), "d": (0, -1)}
STOP_KEYS = (" ", "x")
HELP = "w/s faster/slower, a/d turn left/right (each press adds a step), space or x stop, e emergency stop, " \
       "r arm, q quit"
QUIT, ESTOP, ARM = "quit", "estop", "arm"


@dataclass
class Drive:
    """The commanded velocity and what each key does to it (no terminal, no MQTT: testable as is)."""

    linear_step: float
    angular_step: float
    max_linear: float
    max_angular: float
    lx: float = 0.0
    az: float = 0.0
    estopped: bool = False

    def key(self, key: str) -> str | None:
        """Apply one key; returns QUIT, ESTOP or ARM when the caller must act, else None."""
        key = key.lower()
        if key == "q":
            return QUIT
        if key == "e":
            self.lx = self.az = 0.0
            self.estopped = True
            return ESTOP
        if key == "r":
            self.lx = self.az = 0.0
            self.estopped = False
            return ARM
        if key in STOP_KEYS:
            self.lx = self.az = 0.0
        elif key in STEPS and not self.estopped:  # the robot refuses motion until armed: do not build any up
            dv, dw = STEPS[key]
            self.lx = _clamp(round(self.lx + dv * self.linear_step, 6), self.max_linear)
            self.az = _clamp(round(self.az + dw * self.angular_step, 6), self.max_angular)
        return None

    @property
    def streaming(self) -> bool:
        """Whether twists go out: not while e-stopped (the robot would refuse each one)."""
        return not self.estopped

    def status(self) -> str:
        if self.estopped:
            return "EMERGENCY STOP — r to arm, q to quit"
        return f"lx={self.lx:+.2f} m/s az={self.az:+.2f} rad/s"


def _clamp(value: float, limit: float) -> float:
    return max(-limit, min(limit, value))


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("teleop", help="drive a robot with the keyboard",
                       description=" ".join(__doc__.split("\n\n")[:2]))
    p.add_argument("robot")
    p.add_argument("--linear", type=float, default=0.1, help="m/s added per w/s press (default %(default)s)")
    p.add_argument("--angular", type=float, default=0.3, help="rad/s added per a/d press (default %(default)s)")
    p.add_argument("--max-linear", type=float, default=0.5,
                   help="largest |lx| the keys build up, m/s (default %(default)s; the robot clamps to its limits)")
    p.add_argument("--max-angular", type=float, default=1.5,
                   help="largest |az| the keys build up, rad/s (default %(default)s)")
    add_connection_options(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    if not sys.stdin.isatty():
        raise SystemExit("roslink-mqtt teleop: needs a terminal")
    import termios
    import tty

    drive = Drive(abs(args.linear), abs(args.angular), abs(args.max_linear), abs(args.max_angular))
    client = open_client(args, robots=[args.robot])
    held = claim_if_free(client, args.robot)
    if held:
        client.close()
        raise SystemExit(f"roslink-mqtt teleop: {held}")
    fd = sys.stdin.fileno()
    saved = termios.tcgetattr(fd)
    try:
        # keys typed while connecting are dropped (TCSAFLUSH: they were not meant for a robot that now moves); the
        # help appears once the keyboard is read key by key, so every key pressed after it counts
        tty.setcbreak(fd, termios.TCSAFLUSH)
        print(f"teleop {args.robot}: {HELP}\r", flush=True)
        while True:
            if select.select([sys.stdin], [], [], 0.1)[0]:
                action = drive.key(sys.stdin.read(1))
                if action == QUIT:
                    break
                if action == ESTOP:
                    client.emergency_stop(args.robot, "teleop")
                elif action == ARM:
                    client.arm(args.robot)
                print(f"\r{drive.status():<48}", end="", flush=True)
            if drive.streaming:
                client.twist(args.robot, lx=drive.lx, az=drive.az)
    except KeyboardInterrupt:
        pass
    finally:
        termios.tcsetattr(fd, termios.TCSADRAIN, saved)
        try:
            if drive.streaming:
                client.twist(args.robot)  # an explicit zero before leaving
                time.sleep(0.1)
        finally:
            client.close()  # even when that zero cannot go out (a viewer, the broker gone): presence must end
            print()
    return 0
