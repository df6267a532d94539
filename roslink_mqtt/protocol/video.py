"""Video frames on the wire (docs/protocol.md, "Video"): a JSON header line, a newline, then the frame's bitstream.

Why this shape: a robot encodes a camera once and the broker fans that one upload out to every viewer, so a frame
must be readable by any MQTT client without ROS and without a CBOR library: split the payload at its first newline,
read the header as JSON, hand the rest to a decoder (WebCodecs' ``EncodedVideoChunk``, PyAV, ffmpeg). The same
framing as snapshot chunks.

The bitstream is one encoded frame: H.264 in Annex B with its parameter sets (SPS, PPS) in front of every keyframe,
so a decoder may start at any keyframe without out-of-band configuration; VP8, VP9 and AV1 as their encoders write
one frame (AV1: a temporal unit of OBUs). ``profile`` is the codec string WebCodecs' ``VideoDecoder.configure`` takes
(RFC 6381), so a browser needs nothing else.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from ..topics import TopicTree, Verb
from .body import SENDER, BodyField, Boolean, Choice, Integer, Number, Text, read, split_header, write
from .errors import ProtocolError

CODECS = ("h264", "vp8", "vp9", "av1")
MAX_SIDE = 8192  # pixels: more than any camera a robot streams
MAX_SEQ = (1 << 53) - 1  # a JSON integer every client reads exactly
WATCH_LEASE = 10.0  # s a watch lasts after its last renewal (a client that vanished stops costing the uplink)
WATCH_RENEW = 3.0  # s between a watching client's renewals
_DOC = TopicTree()


@dataclass(frozen=True, slots=True)
class WatchRequest:
    """Watch a video stream, on ``from/<user>/watch/<stream>`` (read by the bridge; not retained).

    A lease, not a switch: the robot encodes while any watch is fresh, so a viewer whose program crashed stops
    costing the robot's uplink :data:`WATCH_LEASE` seconds later (or when its presence ends), and a retained message
    left behind cannot keep a camera streaming for nobody."""

    client_id: str
    key: bool = False
    leave: bool = False

    FIELDS = (
        BodyField("client_id", SENDER, True, "the watching client's id (its presence id, when it has one: the watch "
                                             "ends with its presence)", names="sender"),
        BodyField("key", Boolean(), False, "send a keyframe now (a viewer that just joined, or lost frames)", False),
        BodyField("leave", Boolean(), False, f"stop watching now; without it a watch lasts {WATCH_LEASE:g} s after "
                                             f"the last request (renew every {WATCH_RENEW:g} s)", False),
    )
    QOS = 0
    RETAINED = False

    def to_json(self) -> bytes:
        return write(self.FIELDS, self)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> WatchRequest:
        return cls(**read(cls.FIELDS, data, shape='expected a JSON object {"client_id": "<your client id>"}'))


@dataclass(frozen=True, slots=True)
class VideoFrame:
    """One encoded frame of a video stream, on ``state/<stream>`` (QoS 0, not retained: an old frame is never kept)."""

    codec: str
    key: bool
    seq: int
    stamp: float  # s since the epoch: when the camera captured it (the ROS header's stamp)
    width: int
    height: int
    profile: str
    data: bytes = b""
    encoded: float | None = None  # s since the epoch: when the bridge had it encoded
    kbit_s: float | None = None  # the bitrate the encoder aimed at for this frame
    fps: float | None = None  # the frame rate the stream was sent at when it was encoded

    FIELDS = (
        BodyField("codec", Choice(CODECS), True, "the bitstream's codec"),
        BodyField("key", Boolean(), True, "a keyframe: a decoder may start here (H.264: the parameter sets come "
                                          "with it)"),
        BodyField("seq", Integer(0, MAX_SEQ), True, "the frame's number in the stream; a number skipped is a frame "
                                                    "not sent, and the next frame sent after a gap is a keyframe"),
        BodyField("stamp", Number(), True, "when the camera captured the frame, seconds since the epoch (the ROS "
                                           "header's stamp): the frame's age is now − `stamp`"),
        BodyField("width", Integer(1, MAX_SIDE), True, "pixels"),
        BodyField("height", Integer(1, MAX_SIDE), True, "pixels"),
        BodyField("profile", Text(1, 64), True, "the codec string `VideoDecoder.configure` takes (RFC 6381), e.g. "
                                                "`avc1.42e01f`"),
        BodyField("encoded", Number(), False, "when the bridge had the frame encoded, seconds since the epoch", None),
        BodyField("kbit_s", Number(0, 1e6), False, "the bitrate the encoder aimed at, kbit/s", None),
        BodyField("fps", Number(0, 1000), False, "the frame rate the stream was sent at", None),
    )
    QOS = 0
    RETAINED = False

    def to_json(self) -> bytes:
        """The header line (the bitstream follows it: :meth:`to_bytes`)."""
        return write(self.FIELDS, self)

    def to_bytes(self) -> bytes:
        return self.to_json() + b"\n" + self.data

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> VideoFrame:
        """A frame from its header line alone (``data`` empty)."""
        return cls(**read(cls.FIELDS, data, shape='video frame: expected a JSON header {"codec": "h264", "key": '
                                                  'true, …}', strict=False, what="video frame"))

    @classmethod
    def from_bytes(cls, payload: bytes | bytearray | memoryview) -> VideoFrame:
        """A frame as the bridge sends it: the header line, a newline, the bitstream."""
        line, data = split_header(payload, "video frame", "the bitstream")
        if not data:
            raise ProtocolError("video frame: the bitstream after the header is empty")
        return replace(cls.from_json(line), data=data)


VIDEO_BODIES: tuple[tuple[str, str, type], ...] = (
    ("watch request", f"`{_DOC.user_topic('<robot>', '<user>', Verb.WATCH, '<stream>')}`", WatchRequest),
    ("video frame", f"`{_DOC.state('<robot>', '<stream>')}`: this JSON header line, a newline, then the frame's "
                    "bitstream", VideoFrame),
)
