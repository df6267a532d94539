"""One camera sent as video: the newest picture, watchers, rate control and the encoder, on a thread of its own.
ROS-free: the ROS side hands in pictures (:meth:`VideoStreamer.offer`) and says when a client leaves.

Why a thread of its own: encoding a 640×480 frame takes milliseconds of CPU, and the ROS executor (which runs the
failsafe's timers) and paho's network thread (which carries stops) must never wait for it. The ROS callback only
keeps the newest picture (latest wins, converted later, here); this thread takes it when the stream's lane has
room, so a picture that could not leave in time is never encoded, never sent, and never referenced by the next.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import av

from ..config import VideoStream
from ..protocol.video import VideoFrame
from .encoder import VideoEncoder
from .ladder import Ladder, RateController, Rung
from .watchers import Watchers

log = logging.getLogger("roslink_mqtt.video")

IDLE_WAIT = 0.5  # s the thread sleeps when no picture comes (it still ends lapsed watches)
ROOM_POLL = 0.01  # s between looks at the lane while a picture waits for room (each look takes the uplink's lock)
ROOM_WAIT = 0.2  # s a picture waits for room at most (a newer one takes its place sooner)
STATS_PERIOD = 2.0  # s between the stream's counters in the log (DEBUG)
START_SHARE = 250_000.0  # bits/s assumed before the uplink says more (a thin link's worth: grows within seconds)


class VideoLane(Protocol):
    """Where encoded frames go: the uplink's lane of this stream."""

    def room(self) -> bool:
        """The last frame has left the robot's hands and the link takes another now."""
        ...

    def share(self, wants: float) -> tuple[float, bool]:
        """Bytes/s the stream may use (what control, motion and state leave), and whether the link had room to
        spare lately (its capacity not yet found: the stream may probe upwards); ``wants``: the bytes/s its encoder
        aims at now (the uplink counts it as the stream's need when it shares the link with other lanes)."""
        ...

    def send(self, payload: bytes) -> bool:
        """Hand a frame over; False when it could not be (the connection is down)."""
        ...


@dataclass(slots=True)
class Picture:
    """The newest picture from the camera: its capture time and how to turn it into a PyAV frame (later, here)."""

    stamp: float  # s since the epoch
    convert: Callable[[], av.VideoFrame]


@dataclass(slots=True)
class StreamStats:
    pictures: int = 0  # offered by the camera
    encoded: int = 0
    sent: int = 0
    keyframes: int = 0
    skipped_busy: int = 0  # the lane had no room: not encoded
    failed: int = 0  # a picture that could not be converted or encoded
    bytes_sent: int = 0


class VideoStreamer:
    """Encodes ``settings``' camera while someone watches, at what the lane's share allows."""

    def __init__(self, settings: VideoStream, lane: VideoLane, watchers: Watchers,
                 on_watched: Callable[[bool], None] = lambda watched: None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        """``on_watched(True)`` when the first watcher comes (subscribe to the camera), ``(False)`` when the last
        goes (unsubscribe: nothing is rendered, converted or encoded for nobody)."""
        self.settings, self.lane, self.watchers = settings, lane, watchers
        self.on_watched, self.clock = on_watched, clock
        self.encoder = VideoEncoder(settings.codec)
        self.controller: RateController | None = None  # made from the first picture's size (a default ladder)
        self.stats = StreamStats()
        self._picture: Picture | None = None
        self._cond = threading.Condition()
        self._stopped = False
        self._watched = False
        self._resend_key = False  # a frame was lost on the way: the next one must be a keyframe
        self._logged = float("-inf")  # when the stats were last logged (DEBUG)
        self._thread = threading.Thread(target=self._run, name=f"video-{settings.name}", daemon=True)

    # -- from other threads -------------------------------------------------------------------------------------
    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        """End the thread (any time: a bridge whose login was refused stops before it started anything)."""
        with self._cond:
            self._stopped = True
            self._cond.notify()
        if self._thread.ident is not None:
            self._thread.join(timeout=2.0)

    def offer(self, picture: Picture) -> None:
        """The camera's newest picture (the ROS callback's thread): it replaces one not yet taken."""
        with self._cond:
            self.stats.pictures += 1
            self._picture = picture
            self._cond.notify()

    def wake(self) -> None:
        """A watch began or ended: look now."""
        with self._cond:
            self._cond.notify()

    # -- the stream's thread ------------------------------------------------------------------------------------
    def _run(self) -> None:
        while True:
            with self._cond:
                if self._stopped:
                    break
                if self._picture is None:
                    self._cond.wait(IDLE_WAIT)
                picture, self._picture = self._picture, None
            try:
                self._step(picture)
            except Exception:  # a bug here must not end the stream for good
                log.exception("video stream %s", self.settings.name)
                self.stats.failed += 1
        self._set_watched(False)

    def _set_watched(self, watched: bool) -> None:
        if watched != self._watched:
            self._watched = watched
            if not watched:
                self.encoder.close()
                self._picture = None
            log.info("video %s: %s", self.settings.name, "watched: encoding" if watched else "nobody watches: idle")
            self.on_watched(watched)

    def _step(self, picture: Picture | None) -> None:
        now = self.clock()
        if now - self._logged >= STATS_PERIOD and log.isEnabledFor(logging.DEBUG):
            self._logged = now
            log.debug("video %s: %s", self.settings.name, self.stats)
        self._set_watched(self.watchers.expire(now) > 0)
        if picture is None or not self._watched:
            return
        if not self._wait_for_room(picture):
            return
        image = picture.convert()
        controller = self._control(image, now)
        if not controller.frame_due(now):
            return
        key = self.watchers.take_key(now) or self._resend_key
        frame = self.encoder.encode(image, picture.stamp, key=key)
        self.stats.encoded += 1
        if frame is None:
            return
        self._hand_over(frame)

    def _wait_for_room(self, picture: Picture) -> bool:
        """Whether the lane has room for this picture's frame: it waits for room until a newer picture comes (which
        then takes its place: a picture is never encoded behind a newer one) or for ROOM_WAIT at most. Why wait at
        all: the room opens between two pictures, and a stream that looked only when a picture came lost every
        opening to the streams that always have a message waiting (a thin link's scan took the room, the camera got
        one picture in two)."""
        give_up = self.clock() + ROOM_WAIT
        while not self.lane.room():
            with self._cond:
                if self._stopped or self._picture is not None or self.clock() >= give_up:
                    self.stats.skipped_busy += 1
                    return False
                self._cond.wait(ROOM_POLL)
        return True

    def _control(self, image: av.VideoFrame, now: float) -> RateController:
        controller = self.controller
        share, headroom = self.lane.share(controller.target.bitrate / 8 if controller is not None else 0.0)
        if controller is None:
            s = self.settings
            ladder = Ladder(tuple(Rung(w, h, f) for w, h, f in s.ladder), s.min_kbit_s * 1000, s.max_kbit_s * 1000) \
                if s.ladder else Ladder.for_camera(image.width, image.height, s.fps, s.min_kbit_s * 1000,
                                                   s.max_kbit_s * 1000)
            controller = self.controller = RateController(ladder, min(START_SHARE, share * 8))
            self.encoder.configure(controller.target)
        target = controller.update(share * 8, now, headroom=headroom)
        if target is not None:
            log.info("video %s: %s at %.0f kbit/s (share %.0f kbit/s)", self.settings.name, target.rung,
                     target.bitrate / 1000, share * 8 / 1000)
            self.encoder.configure(target)
        return controller

    def _hand_over(self, frame: VideoFrame) -> None:
        payload = frame.to_bytes()
        if self.lane.send(payload):
            self.stats.sent += 1
            self.stats.bytes_sent += len(payload)
            self.stats.keyframes += frame.key
            self._resend_key = False
        else:
            self._resend_key = True  # a frame the viewers never get: the next one must not need it
