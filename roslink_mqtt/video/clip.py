"""Frames of a video stream into a file, as they came: no decoding, no re-encoding (PyAV's muxers).

``.mp4`` and ``.mkv`` are written with PyAV (the container's codec parameters come from the first keyframe's own
parameter sets); ``.h264`` (an H.264 stream) and ``.ivf`` are not needed: ``.mkv`` takes every codec the robot
sends. A clip starts at a keyframe (the frames before the first one cannot be shown) and stops at a gap it cannot
bridge: after a lost frame the next keyframe carries on.
"""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path
from typing import Any, cast

import av
from av.video.stream import VideoStream

from ..protocol.video import VideoFrame

FORMATS = {".mp4": "mp4", ".mkv": "matroska", ".webm": "webm"}
TIME_BASE = Fraction(1, 1000)


class Clip:
    """A file being written; :meth:`add` each frame in order, :meth:`close` at the end."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        fmt = FORMATS.get(self.path.suffix.lower())
        if fmt is None:
            raise ValueError(f"{self.path.name}: a clip is .mp4, .mkv or .webm")
        self._format = fmt
        self._container: Any = None
        self._stream: Any = None
        self._t0 = 0.0
        self._next_seq: int | None = None
        self._last_pts = -1
        self.frames = 0
        self.skipped = 0  # frames before the first keyframe, or after a gap until the next one

    def add(self, frame: VideoFrame) -> bool:
        """Write ``frame``; False when it was skipped (no keyframe yet since the start or a gap)."""
        if self._container is None:
            if not frame.key:
                self.skipped += 1
                return False
            self._open(frame)
        if not frame.key and frame.seq != self._next_seq:
            self._next_seq = None
            self.skipped += 1
            return False
        self._next_seq = frame.seq + 1
        packet = av.Packet(frame.data)
        packet.stream = self._stream
        packet.time_base = TIME_BASE
        pts = max(self._last_pts + 1, round((frame.stamp - self._t0) * 1000))
        packet.pts = packet.dts = self._last_pts = pts
        packet.is_keyframe = frame.key
        self._container.mux(packet)
        self.frames += 1
        return True

    def _open(self, first: VideoFrame) -> None:
        container = av.open(str(self.path), "w", format=self._format)
        stream = cast(VideoStream, container.add_stream(first.codec if first.codec != "vp8" else "libvpx",
                                                        rate=round(first.fps or 30)))
        stream.width, stream.height = first.width, first.height
        stream.time_base = TIME_BASE
        self._container, self._stream, self._t0 = container, stream, first.stamp

    def close(self) -> None:
        if self._container is not None:
            self._container.close()
            self._container = None
