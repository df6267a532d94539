"""The streamer (roslink_mqtt/video/streamer.py) with real PyAV and a lane of the test's own: one encoder whatever
the number of watchers, a picture encoded only when the lane has room (never a queue of old video), a keyframe
for a viewer who joins and after a frame the viewers never got, nothing encoded for nobody."""

from __future__ import annotations

import threading
import time

import pytest

from roslink_mqtt.config import VideoStream
from roslink_mqtt.protocol.video import VideoFrame
from roslink_mqtt.video.decoder import VideoDecoder
from roslink_mqtt.video.encoder import frame_from_pixels
from roslink_mqtt.video.scene import read_stamp, render
from roslink_mqtt.video.streamer import ROOM_WAIT, Picture, VideoStreamer
from roslink_mqtt.video.watchers import Watchers
from tests.support.waits import never, wait_until

pytestmark = pytest.mark.unit

LEASE = 2.5  # s: short, so a lapse is seen soon; long enough for a busy machine to renew in time
SETTINGS = VideoStream("camera", "camera/image_raw", "sensor_msgs/msg/Image", ladder=((320, 240, 30.0),))


class Lane:
    def __init__(self) -> None:
        self.frames: list[VideoFrame] = []
        self.full = threading.Event()
        self.down = threading.Event()

    def room(self) -> bool:
        return not self.full.is_set()

    def share(self, wants: float) -> tuple[float, bool]:
        return 31_250.0, False  # 250 kbit/s: the controller starts there and has no reason to change

    def send(self, payload: bytes) -> bool:
        if self.down.is_set():
            return False
        self.frames.append(VideoFrame.from_bytes(payload))
        return True


class Camera:
    """Pictures at ``rate`` on a thread, as a ROS callback would offer them."""

    def __init__(self, streamer: VideoStreamer, rate: float = 30.0) -> None:
        self.streamer, self.rate = streamer, rate
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        i = 0
        while not self._stop.wait(1.0 / self.rate):
            stamp = time.time()
            pixels = render(320, 240, i * 0.02, 0.0, 0.0, stamp)
            self.streamer.offer(Picture(stamp, lambda p=pixels: frame_from_pixels(p, "rgb8")))
            i += 1

    def stop(self) -> None:
        self._stop.set()
        self.thread.join()


def _until(what: str, check, timeout: float = 10.0, renew: Watchers | None = None,
           clients: tuple[tuple[str, str], ...] = ()) -> None:
    """Wait for ``check``; meanwhile ``clients`` renew their watches (as a viewer's program does)."""
    def renewing_check() -> bool:
        if check():
            return True
        for user, client in clients:
            assert renew is not None
            renew.watch(user, client, time.monotonic())
        return False
    wait_until(what, renewing_check, timeout=timeout, period=0.01)


@pytest.fixture
def rig():
    lane, watched = Lane(), []
    watchers = Watchers(lambda user, client: False, lease=LEASE)
    streamer = VideoStreamer(SETTINGS, lane, watchers, on_watched=watched.append)
    streamer.start()
    camera = Camera(streamer)
    yield lane, watchers, streamer, watched
    camera.stop()
    streamer.stop()


def test_nothing_is_encoded_for_nobody_and_a_joining_viewer_starts_at_a_keyframe(rig) -> None:
    lane, watchers, streamer, watched = rig
    never("a frame encoded or a camera watched for nobody",
          lambda: lane.frames or streamer.stats.encoded or watched, seconds=0.3)
    watchers.watch("bob", "bob-web", time.monotonic())
    streamer.wake()
    _until("ten frames", lambda: len(lane.frames) >= 10)
    assert watched == [True] and lane.frames[0].key and lane.frames[0].seq == 0
    decoder = VideoDecoder()
    pictures = [decoder.decode(f) for f in lane.frames[:10]]
    assert all(p is not None for p in pictures)
    stamps = [read_stamp(p.to_ndarray(format="rgb24")) for p in pictures if p is not None]
    assert sum(s is not None and abs(s - f.stamp) < 0.002 for s, f in zip(stamps, lane.frames, strict=False)) >= 8
    # the lease lapses (LEASE here): the stream goes idle, the camera's subscription may go
    _until("the stream to go idle", lambda: watched == [True, False], timeout=LEASE + 5.0)
    sent = len(lane.frames)
    never("a frame sent to an idle stream", lambda: len(lane.frames) != sent, seconds=0.3)


def test_ten_viewers_cost_one_encoder(rig) -> None:
    lane, watchers, streamer, _watched = rig
    viewers = tuple((f"viewer{i}", f"v{i}") for i in range(10))
    for user, client in viewers:
        watchers.watch(user, client, time.monotonic())
    streamer.wake()
    _until("thirty frames", lambda: len(lane.frames) >= 30, renew=watchers, clients=viewers)
    assert streamer.encoder.encoders_opened == 1
    assert [f.seq for f in lane.frames[:30]] == list(range(30))  # one stream, no gaps
    # ten joins asked for keyframes, but at most one a second comes (the first frame is one anyway)
    assert sum(f.key for f in lane.frames[:30]) <= 2


def test_a_full_lane_skips_pictures_before_encoding_and_a_lost_frame_brings_a_keyframe(rig) -> None:
    lane, watchers, streamer, _watched = rig
    alice = (("alice", "alice-web"),)
    watchers.watch("alice", "alice-web", time.monotonic())
    streamer.wake()
    _until("five frames", lambda: len(lane.frames) >= 5, renew=watchers, clients=alice)
    lane.full.set()
    encoded = streamer.stats.encoded
    never("a frame encoded while the lane is full", lambda: streamer.stats.encoded != encoded, seconds=0.3)
    assert streamer.stats.skipped_busy > 0  # never a queue of old video
    lane.full.clear()
    _until("more frames", lambda: len(lane.frames) >= 10, renew=watchers, clients=alice)
    seqs = [f.seq for f in lane.frames]
    assert seqs == list(range(len(seqs)))  # skipped pictures are no gap: they were never encoded
    lane.down.set()  # the connection went: a frame is lost on the way
    _until("a lost frame", lambda: streamer.stats.encoded > streamer.stats.sent, renew=watchers, clients=alice)
    before = len(lane.frames)
    lane.down.clear()
    _until("a frame after the loss", lambda: len(lane.frames) > before, renew=watchers, clients=alice)
    first_after = lane.frames[before]
    assert first_after.key and first_after.seq > lane.frames[before - 1].seq + 1


def test_a_streamer_never_started_stops_cleanly() -> None:
    """A bridge whose login was refused stops before it started its streamers (it must still exit with its code)."""
    streamer = VideoStreamer(SETTINGS, Lane(), Watchers(lambda user, client: False))
    streamer.stop()
    streamer.start()  # (never after a stop, but harmless)
    streamer.stop()


class OpensLater(Lane):
    """A lane whose room opens after ``looks`` looks (a frame ahead of it leaves between two pictures)."""

    def __init__(self, looks: int) -> None:
        super().__init__()
        self.looks = looks

    def room(self) -> bool:
        self.looks -= 1
        return self.looks < 0


def _picture() -> Picture:
    pixels = render(320, 240, 0.0, 0.0, 0.0, time.time())
    return Picture(time.time(), lambda: frame_from_pixels(pixels, "rgb8"))


def test_a_picture_waits_for_room_that_opens_before_the_next_picture() -> None:
    streamer = VideoStreamer(SETTINGS, OpensLater(3), Watchers(lambda user, client: False, lease=LEASE),
                             clock=lambda: 0.0)  # (its clock stands still: a busy machine's slow looks never give up)
    assert streamer._wait_for_room(_picture())  # the room opened 3 looks later: this picture goes
    assert streamer.stats.skipped_busy == 0


def test_a_newer_picture_takes_the_place_of_one_waiting_for_room() -> None:
    streamer = VideoStreamer(SETTINGS, OpensLater(10_000), Watchers(lambda user, client: False, lease=LEASE))
    newer = threading.Timer(0.05, streamer.offer, args=(_picture(),))
    newer.start()
    began = time.monotonic()
    assert not streamer._wait_for_room(_picture())  # never encoded behind a newer one: the newer one goes next
    newer.join()
    assert streamer.stats.skipped_busy == 1 and streamer._picture is not None
    assert time.monotonic() - began < ROOM_WAIT + 0.5  # it stopped waiting for the newer one (generous: a busy machine)
