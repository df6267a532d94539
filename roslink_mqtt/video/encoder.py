"""One camera's frames as a low-latency bitstream, with PyAV (libx264, libvpx, SVT-AV1). No ROS, no MQTT.

Settings chosen for a viewer who drives by the picture, not for a recording: no B-frames and no look-ahead (a frame
leaves the encoder as soon as it went in), H.264 constrained baseline (every browser's decoder), parameter sets in
front of every keyframe (a viewer may start at any keyframe), keyframes only when asked for (a viewer joins, a frame
was lost, the encoder changed): a periodic keyframe would cost several frames' worth of a thin link for nobody.

A new :class:`~.ladder.Target` (size or bitrate) opens a new encoder at the next frame: the codecs here do not take a
new bitrate on an open encoder (``ladder``'s docstring), so the first frame of each is a keyframe.
"""

from __future__ import annotations

import time
from fractions import Fraction
from typing import Any, cast

import av
import numpy as np
from av.video.codeccontext import VideoCodecContext

from ..protocol.video import VideoFrame
from .ladder import Target

# codec → PyAV's encoder, its options, and the WebCodecs codec string when the bitstream does not say it
ENCODERS: dict[str, tuple[str, dict[str, str], str]] = {
    "h264": ("libx264", {"preset": "veryfast", "tune": "zerolatency", "profile": "baseline",
                         "x264-params": "repeat-headers=1:scenecut=0:annexb=1"}, "avc1.42e01f"),
    "vp8": ("libvpx", {"deadline": "realtime", "cpu-used": "8", "lag-in-frames": "0", "error-resilient": "1"},
            "vp8"),
    "vp9": ("libvpx-vp9", {"deadline": "realtime", "cpu-used": "8", "lag-in-frames": "0", "error-resilient": "1",
                           "row-mt": "1"}, "vp09.00.10.08"),
    "av1": ("libsvtav1", {"preset": "12", "svtav1-params": "pred-struct=1:lookahead=0"}, "av01.0.04M.08"),
}
PIXEL_FORMATS = {"rgb8": "rgb24", "bgr8": "bgr24", "mono8": "gray", "rgba8": "rgba", "bgra8": "bgra"}
TIME_BASE = Fraction(1, 1000)  # pts in ms since the encoder opened
VBV_SECONDS = 0.25  # the rate control's buffer: a frame is at most this much of a second's bits above the average


class VideoEncoder:
    """Frames in, :class:`VideoFrame` out; opens a new encoder whenever the target changes."""

    def __init__(self, codec: str = "h264") -> None:
        if codec not in ENCODERS:
            raise ValueError(f"video codec '{codec}' is not one of {', '.join(ENCODERS)}")
        self.codec = codec
        self._context: Any = None
        self._target: Target | None = None
        self._pending: Target | None = None
        self._opened_at = 0.0
        self._last_pts = -1
        self._profile = ENCODERS[codec][2]
        self.seq = 0  # frames encoded so far (the next frame's number)
        self.encoders_opened = 0

    def configure(self, target: Target) -> None:
        """Use ``target`` from the next frame on (a new encoder: that frame is a keyframe)."""
        if target != self._target:
            self._pending = target

    def encode(self, image: av.VideoFrame, stamp: float, key: bool = False) -> VideoFrame | None:
        """Encode ``image`` captured at ``stamp`` (s since the epoch); ``key`` asks for a keyframe. None when the
        encoder held the frame back (it does not, with these settings, but a codec may)."""
        if self._pending is not None:
            self._open(self._pending, stamp)
        if self._context is None or self._target is None:
            raise RuntimeError("VideoEncoder.configure() first")
        rung = self._target.rung
        frame = image.reformat(width=rung.width, height=rung.height, format="yuv420p")
        pts = max(self._last_pts + 1, round((stamp - self._opened_at) * 1000))
        frame.pts, self._last_pts = pts, pts
        if key:
            frame.pict_type = av.video.frame.PictureType.I
        packets = self._context.encode(frame)
        if not packets:
            return None
        data = b"".join(bytes(p) for p in packets)
        is_key = any(p.is_keyframe for p in packets)
        if is_key and self.codec == "h264":
            self._profile = avc_codec_string(data) or self._profile
        out = VideoFrame(codec=self.codec, key=is_key, seq=self.seq, stamp=stamp, width=rung.width,
                         height=rung.height, profile=self._profile, data=data, encoded=time.time(),
                         kbit_s=round(self._target.bitrate / 1000, 1), fps=rung.fps)
        self.seq += 1
        return out

    def _open(self, target: Target, stamp: float) -> None:
        name, options, _ = ENCODERS[self.codec]
        rung = target.rung
        context = cast(VideoCodecContext, av.CodecContext.create(name, "w"))
        context.width, context.height, context.pix_fmt = rung.width, rung.height, "yuv420p"
        context.time_base = TIME_BASE
        context.framerate = Fraction(rung.fps).limit_denominator(1000)
        context.bit_rate = int(target.bitrate)
        context.gop_size = 1 << 30  # keyframes only when asked for
        context.max_b_frames = 0
        opts = dict(options)
        if self.codec == "h264":
            kbit = max(1, int(target.bitrate / 1000))
            opts["x264-params"] += f":vbv-maxrate={kbit}:vbv-bufsize={max(1, int(kbit * VBV_SECONDS))}"
        context.options = opts
        context.open()
        self._close()
        self._context, self._target, self._pending = context, target, None
        self._opened_at, self._last_pts = stamp, -1
        self.encoders_opened += 1

    def _close(self) -> None:
        if self._context is not None:
            try:
                self._context.close()
            except (av.FFmpegError, AttributeError):  # an encoder with frames in flight: they are not wanted
                pass
            self._context = None

    def close(self) -> None:
        """Free the encoder (the last watcher left); the next :meth:`configure` opens a new one."""
        self._close()
        self._pending, self._target = self._target, None


def frame_from_pixels(pixels: np.ndarray, encoding: str) -> av.VideoFrame:
    """A PyAV frame over a ``sensor_msgs/Image``'s pixels (height × width × channels, or height × width for mono8)
    in one of :data:`PIXEL_FORMATS`, without copying them.

    Why not ``from_ndarray``: it copies the picture row by row holding the GIL, and measured here (640×480 rgb8,
    back to back) another Python thread then waited up to 27–100 ms for its turn (p99 8–62 ms); in the bridge those
    threads carry stops. Over the buffer, the copy happens in the conversion to YUV (swscale, the GIL released):
    the other thread's worst wait was 2 ms."""
    fmt = PIXEL_FORMATS.get(encoding)
    if fmt is None:
        raise ValueError(f"video from an image with encoding '{encoding}': only {', '.join(PIXEL_FORMATS)}")
    return av.VideoFrame.from_numpy_buffer(np.ascontiguousarray(pixels), format=fmt)


def avc_codec_string(annexb: bytes) -> str | None:
    """``avc1.PPCCLL`` from the first sequence parameter set in an Annex B bitstream (profile, constraint flags,
    level): the string WebCodecs wants for exactly this stream. None when there is no SPS."""
    at = annexb.find(b"\x00\x00\x01")
    while at >= 0:
        nal = annexb[at + 3:at + 7]
        if len(nal) == 4 and nal[0] & 0x1F == 7:
            return f"avc1.{nal[1]:02x}{nal[2]:02x}{nal[3]:02x}"
        at = annexb.find(b"\x00\x00\x01", at + 3)
    return None
