"""The encoder and decoder round-trip the simulator's camera (real PyAV: libx264, libvpx), and what crosses the
wire is the declared frame body."""

from __future__ import annotations

import time

import pytest

from roslink_mqtt.protocol.errors import ProtocolError
from roslink_mqtt.protocol.video import VideoFrame
from roslink_mqtt.video.decoder import VideoDecoder
from roslink_mqtt.video.encoder import VideoEncoder, avc_codec_string, frame_from_pixels
from roslink_mqtt.video.ladder import Rung, Target
from roslink_mqtt.video.scene import read_stamp, render

T0 = time.time()


def _frames(encoder: VideoEncoder, count: int, start: int = 0, keys: tuple[int, ...] = ()) -> list[VideoFrame]:
    out = []
    for i in range(start, start + count):
        stamp = T0 + i / 15
        image = frame_from_pixels(render(640, 480, x=i * 0.05, y=0.0, yaw=i * 0.02, stamp=stamp), "rgb8")
        frame = encoder.encode(image, stamp, key=i in keys)
        assert frame is not None  # no look-ahead: every frame comes out at once
        out.append(VideoFrame.from_bytes(frame.to_bytes()))  # as a viewer reads it off the wire
    return out


@pytest.mark.parametrize("codec", ["h264", "vp8"])
def test_the_sims_frames_round_trip_with_their_capture_time_readable(codec: str) -> None:
    encoder = VideoEncoder(codec)
    encoder.configure(Target(Rung(320, 240, 15), 200_000))
    frames = _frames(encoder, 20)
    assert frames[0].key and not any(f.key for f in frames[1:])  # keyframes only when asked for
    assert [f.seq for f in frames] == list(range(20))
    decoder = VideoDecoder()
    stamps = []
    for frame in frames:
        picture = decoder.decode(frame)
        assert picture is not None and (picture.width, picture.height) == (320, 240)
        stamps.append(read_stamp(picture.to_ndarray(format="rgb24")))
    # the blocks survive 200 kbit/s at 320×240: the picture says when it was captured, to the millisecond
    assert sum(s is not None and abs(s - f.stamp) < 0.002 for s, f in zip(stamps, frames, strict=True)) >= 18
    assert 200_000 * 0.3 < sum(len(f.data) * 8 for f in frames) / (20 / 15) < 200_000 * 2


def test_h264_frames_carry_their_parameter_sets_and_codec_string() -> None:
    encoder = VideoEncoder("h264")
    encoder.configure(Target(Rung(320, 240, 15), 150_000))
    first, second, third = _frames(encoder, 3, keys=(2,))
    assert first.key and third.key and not second.key
    assert first.profile == avc_codec_string(first.data) == third.profile
    assert first.profile.startswith("avc1.42")  # baseline: every WebCodecs decoder takes it
    assert avc_codec_string(second.data) is None  # a P-frame has no SPS
    # a decoder that starts at the second keyframe (a viewer who joined late) shows it
    assert VideoDecoder().decode(third) is not None


def test_a_gap_is_skipped_until_the_next_keyframe() -> None:
    encoder = VideoEncoder("h264")
    encoder.configure(Target(Rung(320, 240, 15), 150_000))
    frames = _frames(encoder, 8, keys=(6,))
    decoder = VideoDecoder()
    assert decoder.decode(frames[1]) is None and decoder.waiting_for_key  # no keyframe yet
    assert decoder.decode(frames[0]) is not None and not decoder.waiting_for_key
    assert decoder.decode(frames[1]) is not None
    # frames 2 and 3 never arrived
    assert decoder.decode(frames[4]) is None and decoder.decode(frames[5]) is None and decoder.waiting_for_key
    assert decoder.decode(frames[6]) is not None and decoder.decode(frames[7]) is not None
    assert (decoder.decoded, decoder.skipped) == (4, 3)


def test_a_new_target_is_a_new_encoder_that_starts_with_a_keyframe() -> None:
    encoder = VideoEncoder("h264")
    encoder.configure(Target(Rung(640, 480, 30), 800_000))
    before = _frames(encoder, 3)
    encoder.configure(Target(Rung(320, 240, 15), 150_000))
    after = _frames(encoder, 3, start=3)
    assert [f.key for f in before + after] == [True, False, False, True, False, False]
    assert (before[0].width, after[0].width) == (640, 320) and encoder.encoders_opened == 2
    assert [f.seq for f in before + after] == list(range(6))  # one stream: numbers go on
    decoder = VideoDecoder()
    pictures = [decoder.decode(f) for f in before + after]
    assert [p.width if p else None for p in pictures] == [640, 640, 640, 320, 320, 320]


def test_an_image_encoding_the_encoder_does_not_take_is_refused_by_name() -> None:
    import numpy as np

    with pytest.raises(ValueError, match="'16UC1'"):
        frame_from_pixels(np.zeros((4, 4), np.uint16), "16UC1")
    with pytest.raises(ValueError, match="h265"):
        VideoEncoder("h265")


def test_a_frame_header_is_read_leniently_and_a_broken_payload_is_refused() -> None:
    frame = VideoFrame("h264", True, 7, T0, 320, 240, "avc1.42c01f", b"\x00\x00\x01\x67", kbit_s=150.0)
    wire = frame.to_bytes()
    assert wire.startswith(b'{"codec":"h264","key":true,"seq":7,')
    assert VideoFrame.from_bytes(wire) == frame
    newer = b'{"codec":"h264","key":false,"seq":8,"stamp":1,"width":2,"height":2,"profile":"p","hdr":1}\nxx'
    assert VideoFrame.from_bytes(newer).data == b"xx"  # a field a newer bridge adds is ignored
    with pytest.raises(ProtocolError, match="header line"):
        VideoFrame.from_bytes(b'{"codec":"h264"}')
    with pytest.raises(ProtocolError, match="empty"):
        VideoFrame.from_bytes(wire.split(b"\n")[0] + b"\n")
    with pytest.raises(ProtocolError, match="codec"):
        VideoFrame.from_bytes(wire.replace(b'"h264"', b'"mjpeg"'))


def test_the_stamp_blocks_reject_a_picture_that_is_not_the_sims() -> None:
    import numpy as np

    assert read_stamp(np.full((240, 320, 3), 128, np.uint8)) is None
    stamp = T0 + 0.123
    assert read_stamp(render(160, 120, 0, 0, 0, stamp)) == pytest.approx(stamp, abs=0.001)


@pytest.mark.parametrize("suffix", [".mp4", ".mkv"])
def test_a_clip_is_saved_as_it_came_and_plays_back(tmp_path, suffix: str) -> None:
    from roslink_mqtt.video.clip import Clip

    encoder = VideoEncoder("h264")
    encoder.configure(Target(Rung(320, 240, 15), 200_000))
    frames = _frames(encoder, 12, keys=(8,))
    clip = Clip(tmp_path / f"clip{suffix}")
    assert not clip.add(frames[1])  # no keyframe yet: not saved
    for frame in frames[:4] + frames[6:]:  # frames 4 and 5 lost: 6 and 7 cannot be shown, 8 is a keyframe
        clip.add(frame)
    clip.close()
    assert (clip.frames, clip.skipped) == (8, 3)
    import av

    with av.open(str(clip.path)) as played:
        pictures = list(played.decode(video=0))
    assert len(pictures) == 8 and (pictures[0].width, pictures[0].height) == (320, 240)


def test_a_clip_of_another_kind_of_file_is_refused() -> None:
    from roslink_mqtt.video.clip import Clip

    with pytest.raises(ValueError, match=r"\.mp4, \.mkv or \.webm"):
        Clip("clip.avi")
