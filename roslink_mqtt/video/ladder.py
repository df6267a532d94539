"""How a video stream fits its share of the uplink: a ladder of sizes and frame rates, a bitrate, frames skipped.
ROS-free, I/O-free, no PyAV: unit-tested with made-up links.

Why it is shaped this way (measured with PyAV 18 here): neither libx264 nor libvpx takes a new bitrate on an open
encoder, so a new bitrate is a new encoder, and a new encoder starts with a keyframe (several times a P-frame's
size). So the controller has two knobs with different costs:

* **frames skipped before encoding** (free, at once): a camera frame is encoded only when the stream's lane has
  sent the last one and the frame rate allows; a frame never encoded never breaks the frames after it. libx264
  spends a fixed share of the bitrate per frame, so fewer frames also means fewer bits at once.
* **the bitrate and the rung** (a keyframe each time): down at once when the share falls below what the encoder
  aims at, up only after the share has had room for :data:`UP_AFTER` seconds, so a link that wobbles does not pay
  a keyframe every second.

The share is what control, motion and state leave of the uplink (the bridge's lane allowance), in bits/s.
"""

from __future__ import annotations

from dataclasses import dataclass

DOWN_AT = 0.9  # the share fell below this × the bitrate: down at once
DOWN_TO = 0.75  # … to this × the share (room for keyframes and the share's own wobble)
UP_AT = 1.4  # the share has stayed above this × the bitrate …
UP_AFTER = 2.0  # … for this many seconds: up
UP_TO = 0.7  # … to this × the share
PROBE_UP = 1.5  # the link's capacity is not known yet (it had room): up by this much, to find out
MIN_GAP = 0.5  # s between two new encoders, whichever the direction (each costs a keyframe)
BITS_PER_PIXEL = 0.06  # bits a pixel needs per frame for a picture worth watching (H.264 at low motion)


@dataclass(frozen=True, slots=True)
class Rung:
    """One size and frame rate the stream may be sent at."""

    width: int
    height: int
    fps: float

    def __post_init__(self) -> None:
        if self.width < 16 or self.height < 16 or self.width % 2 or self.height % 2:
            raise ValueError(f"a video size must be even and at least 16×16, got {self.width}×{self.height}")
        if not 0 < self.fps <= 120:
            raise ValueError(f"a video frame rate must be in (0, 120], got {self.fps}")

    @property
    def least_bitrate(self) -> float:
        """bits/s below which this rung's picture is not worth its size: the next rung down looks better."""
        return self.width * self.height * self.fps * BITS_PER_PIXEL

    def __str__(self) -> str:
        return f"{self.width}×{self.height}@{self.fps:g}"


@dataclass(frozen=True, slots=True)
class Ladder:
    """The rungs a stream may use, largest first, and its bitrate bounds (bits/s)."""

    rungs: tuple[Rung, ...]
    min_bitrate: float
    max_bitrate: float

    def __post_init__(self) -> None:
        if not self.rungs:
            raise ValueError("a video ladder needs at least one rung")
        if not 0 < self.min_bitrate <= self.max_bitrate:
            raise ValueError(f"video bitrate bounds must be 0 < min ≤ max, got {self.min_bitrate}..{self.max_bitrate}")
        pixels = [r.width * r.height * r.fps for r in self.rungs]
        if pixels != sorted(pixels, reverse=True):
            raise ValueError("a video ladder's rungs go from the largest (pixels a second) to the smallest")

    def rung_for(self, bitrate: float) -> Rung:
        """The largest rung this bitrate is worth (the smallest when none is)."""
        return next((r for r in self.rungs if r.least_bitrate <= bitrate), self.rungs[-1])

    @classmethod
    def for_camera(cls, width: int, height: int, fps: float, min_bitrate: float = 50_000.0,
                   max_bitrate: float = 2_000_000.0) -> Ladder:
        """The default ladder for a camera: its own size at its rate and at 20 fps, then ¾ at 20, ½ at 15 and 10,
        ¼ at 10 fps. Why the repeated sizes: a link that carries the full picture at 20 fps but not at 30 should
        keep the picture (an operator reads a scene by its detail) and lose frames, and 10 fps at half size is what a
        256 kbit/s uplink leaves a camera beside the robot's telemetry."""
        steps = ((1.0, fps), (1.0, 20.0), (0.75, 20.0), (0.5, 15.0), (0.5, 10.0), (0.25, 10.0))
        rungs: list[Rung] = []
        for scale, most in steps:
            w, h, rate = _even(width * scale), _even(height * scale), min(fps, most)
            if w >= 16 and h >= 16 and all((r.width, r.height, r.fps) != (w, h, rate) for r in rungs):
                rungs.append(Rung(w, h, rate))
        return cls(tuple(rungs), min_bitrate, max_bitrate)


def _even(x: float) -> int:
    return int(x) // 2 * 2


@dataclass(frozen=True, slots=True)
class Target:
    """What the encoder should be: its rung and bitrate (a change of either is a new encoder and a keyframe)."""

    rung: Rung
    bitrate: float


class RateController:
    """The stream's target from its share of the uplink, and whether a camera frame is encoded now."""

    def __init__(self, ladder: Ladder, start_share: float) -> None:
        self.ladder = ladder
        self.target = self._target_for(start_share * DOWN_TO)
        self._changed_at: float | None = None
        self._room_since: float | None = None  # the share has had room for more since then
        self._next_frame: float | None = None  # when the next frame is due (the rung's schedule)
        self.share = start_share

    def _target_for(self, bitrate: float) -> Target:
        bitrate = min(self.ladder.max_bitrate, max(self.ladder.min_bitrate, bitrate))
        return Target(self.ladder.rung_for(bitrate), bitrate)

    def update(self, share: float, now: float, headroom: bool = False) -> Target | None:
        """Feed the stream's share (bits/s); a new :class:`Target` when the encoder must change, else None.

        ``headroom``: the link had room to spare lately, so its capacity is not known yet and the share is only
        what was used plus a margin: the stream does not go down for it, and after UP_AFTER seconds of it probes
        up by PROBE_UP (the uplink's meter then finds out whether the link carries that)."""
        self.share = share
        bitrate = self.target.bitrate
        if self._changed_at is not None and now - self._changed_at < MIN_GAP:
            return None
        if share < DOWN_AT * bitrate and bitrate > self.ladder.min_bitrate and not headroom:
            self._room_since = None
            return self._change(self._target_for(share * DOWN_TO), now)
        if (share > UP_AT * bitrate or headroom) and bitrate < self.ladder.max_bitrate:
            if self._room_since is None:
                self._room_since = now
            elif now - self._room_since >= UP_AFTER:
                self._room_since = None
                # probing: half again, but never past half again the share (a quiet scene's encoder sends far less
                # than it aims at, and each step up is a keyframe: it climbed to 2 Mbit/s on a 1 Mbit/s link)
                up = min(max(share * UP_TO, bitrate * PROBE_UP), share * PROBE_UP) if headroom else share * UP_TO
                if up <= bitrate:
                    return None  # (probing never steps down: the share says nothing while the link has room)
                return self._change(self._target_for(up), now)
        else:
            self._room_since = None
        return None

    def _change(self, target: Target, now: float) -> Target | None:
        if target == self.target:
            return None
        self.target, self._changed_at = target, now
        return target

    def frame_due(self, now: float) -> bool:
        """Whether a camera frame that arrives now is encoded (its rung's frame rate, never faster), and if so,
        count it. The caller asks only when the stream's lane has room for a frame."""
        period = 1.0 / self.target.rung.fps
        # A schedule, not a least gap: 20 fps from a 30 Hz camera is two frames of three (a least gap of a period
        # took every second frame: 15 fps). A frame up to a fifth of a period early counts (a camera's own timing
        # jitters); a late one starts the schedule again (no burst to catch up).
        due = self._next_frame
        if due is not None and now < due - 0.2 * period:
            return False
        # the next one a period after this one's slot, and never within half a period of this one (no burst)
        self._next_frame = now + period if due is None or now > due + period else max(due + period, now + 0.5 * period)
        return True
