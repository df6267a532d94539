"""``roslink-mqtt video ROBOT STREAM [--out clip.mp4]``: watch a robot's video stream, save it as it came."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time

from ..topics import check_name
from .connect import PROG, add_connection_options, open_client


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("video", help="watch a robot's video stream: its rate, size and age, or save it to a file",
                       description="Watch one of the robot's video streams (its robot file's video:; docs/video.md). "
                                   "The robot encodes it only while someone watches. Without --out, print once a "
                                   "second what arrives (frames/s, kbit/s, size, age); with --out, save the frames "
                                   "as they came, without decoding or re-encoding (.mp4, .mkv or .webm; needs PyAV: "
                                   "pip install roslink-mqtt[video]).")
    p.add_argument("robot", metavar="ROBOT")
    p.add_argument("stream", metavar="STREAM")
    p.add_argument("-o", "--out", metavar="FILE", help="save to FILE (.mp4, .mkv or .webm)")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds (default: at Ctrl-C)")
    add_connection_options(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from ..client.errors import RoslinkError

    check_name(args.robot, "robot")
    clip = None
    if args.out:
        try:
            from ..video.clip import Clip
        except ImportError:
            print(f"{PROG} video: saving needs PyAV: pip install roslink-mqtt[video]", file=sys.stderr)
            return 2
        try:
            clip = Clip(args.out)
        except ValueError as err:
            print(f"{PROG} video: {err}", file=sys.stderr)
            return 2
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    client = open_client(args, robots=[args.robot])
    frames = size = 0
    ages: list[float] = []
    shape = ""
    started = time.monotonic()
    next_line = started + 1.0
    try:
        with client.video(args.robot, args.stream) as sub:
            while not stop.is_set() and (args.duration is None or time.monotonic() - started < args.duration):
                try:
                    frame = sub.get(timeout=0.2)
                except RoslinkError:  # nothing this moment
                    frame = None
                if frame is not None:
                    frames, size = frames + 1, size + len(frame.data)
                    ages.append(time.time() - frame.stamp)
                    shape = f"{frame.width}×{frame.height} {frame.codec}"
                    if clip is not None:
                        clip.add(frame)
                if time.monotonic() >= next_line:
                    median = sorted(ages)[len(ages) // 2] * 1000 if ages else float("nan")
                    print(f"{args.robot}/{args.stream}: {frames} fps, {size * 8 / 1000:.0f} kbit/s, {shape or '-'}, "
                          f"age {median:.0f} ms" + (f", {clip.frames} saved" if clip is not None else ""),
                          file=sys.stderr, flush=True)
                    frames, size, ages = 0, 0, []
                    next_line += 1.0
    except RoslinkError as err:
        print(f"{PROG} video: {err}", file=sys.stderr)
        return 1
    finally:
        client.close()
        if clip is not None:
            clip.close()
    if clip is not None:
        print(f"{clip.frames} frames → {clip.path}" + (f" ({clip.skipped} skipped: before a keyframe or after a gap)"
                                                         if clip.skipped else ""), file=sys.stderr)
        if not clip.frames:
            return 1
    return 0
