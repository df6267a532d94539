"""A viewer's side of a video stream, with PyAV: frames in, pictures out, never a picture built on a missing frame.

A frame whose number does not follow the last one decoded means frames were not sent (the robot skipped them, or
they were lost): the frames after it until the next keyframe would decode as smeared garbage, so they are skipped
and counted (:attr:`VideoDecoder.waiting_for_key`), which is when a viewer asks the robot for a keyframe.
"""

from __future__ import annotations

from typing import Any

import av

from ..protocol.video import VideoFrame

DECODERS = {"h264": "h264", "vp8": "vp8", "vp9": "vp9", "av1": "libdav1d"}


class VideoDecoder:
    """Decodes one stream's :class:`VideoFrame` s in order; a new decoder when the codec or size changes."""

    def __init__(self) -> None:
        self._context: Any = None
        self._shape: tuple[str, int, int] | None = None
        self._next_seq: int | None = None
        self.decoded = 0
        self.skipped = 0  # frames that could not be decoded: they followed a gap, before a keyframe

    @property
    def waiting_for_key(self) -> bool:
        """Nothing can be shown until a keyframe comes (none yet, or frames went missing)."""
        return self._next_seq is None

    def decode(self, frame: VideoFrame) -> av.VideoFrame | None:
        """The picture of ``frame``, or None (skipped: it follows a gap; or the decoder holds it back)."""
        shape = (frame.codec, frame.width, frame.height)
        if frame.key:
            if shape != self._shape:
                self._context = av.CodecContext.create(DECODERS.get(frame.codec, frame.codec), "r")
                self._shape = shape
        elif self._next_seq != frame.seq or self._context is None:
            self._next_seq = None
            self.skipped += 1
            return None
        self._next_seq = frame.seq + 1
        pictures = self._context.decode(av.Packet(frame.data))
        if not pictures:
            return None
        self.decoded += 1
        picture: av.VideoFrame = pictures[-1]
        return picture
