"""The video rate controller: a ladder of rungs, a bitrate that follows the stream's share, frames skipped."""

from __future__ import annotations

import pytest

from roslink_mqtt.video.ladder import MIN_GAP, PROBE_UP, UP_AFTER, Ladder, RateController, Rung

LADDER = Ladder.for_camera(640, 480, 30)


def test_the_default_ladder_goes_down_by_size_and_frame_rate() -> None:
    assert [str(r) for r in LADDER.rungs] == ["640×480@30", "640×480@20", "480×360@20", "320×240@15", "320×240@10",
                                              "160×120@10"]
    assert str(LADDER.rung_for(10e6)) == "640×480@30"
    assert str(LADDER.rung_for(500_000)) == "640×480@20"  # what 1 Mbit/s leaves: the whole picture, fewer frames
    assert LADDER.rung_for(200_000).width == 320  # 256 kbit/s leaves about this to video: ≥ 10 fps at 320×240
    assert str(LADDER.rung_for(50_000)) == "320×240@10"
    assert LADDER.rung_for(1_000).width == 160  # below every rung's worth: the smallest


@pytest.mark.parametrize("fps, rungs", [
    (10, ["640×480@10", "480×360@10", "320×240@10", "160×120@10"]),
    (15, ["640×480@15", "480×360@15", "320×240@15", "320×240@10", "160×120@10"]),
])
def test_a_slow_camera_gets_no_rung_twice(fps: float, rungs: list[str]) -> None:
    assert [str(r) for r in Ladder.for_camera(640, 480, fps).rungs] == rungs


@pytest.mark.parametrize("rungs, why", [
    ((), "at least one rung"),
    ((Rung(160, 120, 10), Rung(640, 480, 30)), "largest"),
])
def test_a_ladder_that_makes_no_sense_is_refused(rungs: tuple[Rung, ...], why: str) -> None:
    with pytest.raises(ValueError, match=why):
        Ladder(rungs, 50_000, 1e6)


@pytest.mark.parametrize("width, height, fps", [(15, 16, 10), (641, 480, 30), (640, 480, 0), (640, 480, 500)])
def test_a_rung_that_no_encoder_takes_is_refused(width: int, height: int, fps: float) -> None:
    with pytest.raises(ValueError):
        Rung(width, height, fps)


def test_a_fall_of_the_share_lowers_the_bitrate_at_once() -> None:
    control = RateController(LADDER, 1_000_000)
    assert control.target.rung.width == 640
    new = control.update(200_000, now=10.0)
    assert new is not None and new.bitrate == pytest.approx(150_000) and new.rung.width == 320
    assert control.update(190_000, now=10.1) is None  # within the share's wobble: no new encoder


def test_room_raises_the_bitrate_only_after_it_lasts() -> None:
    control = RateController(LADDER, 200_000)
    start = control.target.bitrate
    assert control.update(1_000_000, now=0.0) is None
    assert control.update(1_000_000, now=UP_AFTER / 2) is None
    assert control.update(180_000, now=UP_AFTER * 0.75) is None  # the room went: start again
    assert control.update(1_000_000, now=UP_AFTER) is None
    new = control.update(1_000_000, now=2 * UP_AFTER + 0.01)
    assert new is not None and new.bitrate == pytest.approx(700_000) and new.bitrate > start


def test_new_encoders_are_at_least_min_gap_apart() -> None:
    control = RateController(LADDER, 1_000_000)
    assert control.update(300_000, now=0.0) is not None
    assert control.update(100_000, now=MIN_GAP / 2) is None
    assert control.update(100_000, now=MIN_GAP + 0.01) is not None


def test_the_bitrate_stays_within_the_ladder_bounds() -> None:
    ladder = Ladder.for_camera(640, 480, 30, min_bitrate=80_000, max_bitrate=500_000)
    control = RateController(ladder, 10_000_000)
    assert control.target.bitrate == 500_000
    new = control.update(1_000, now=1.0)
    assert new is not None and new.bitrate == 80_000
    assert control.update(500, now=5.0) is None  # already at the floor


def test_frames_are_encoded_at_the_rung_rate_and_never_faster() -> None:
    control = RateController(Ladder((Rung(320, 240, 10),), 50_000, 1e6), 200_000)
    camera = [i / 30 for i in range(90)]  # 30 Hz for 3 s
    encoded = [t for t in camera if control.frame_due(t)]
    assert 28 <= len(encoded) <= 31
    assert min(b - a for a, b in zip(encoded, encoded[1:], strict=False)) >= 0.8 / 10


@pytest.mark.parametrize(("camera_hz", "fps", "expected"), [(30, 20, 20), (30, 15, 15), (30, 30, 30), (25, 20, 20),
                                                             (10, 20, 10)])
def test_a_rung_rate_below_the_camera_rate_is_kept_on_average(camera_hz: float, fps: float, expected: float) -> None:
    control = RateController(Ladder((Rung(320, 240, fps),), 50_000, 1e6), 200_000)
    camera = [i / camera_hz for i in range(int(3 * camera_hz))]
    encoded = [t for t in camera if control.frame_due(t)]
    assert len(encoded) == pytest.approx(3 * expected, abs=1)  # 20 of 30 Hz, not every second frame (15)


def test_a_late_frame_starts_the_schedule_again_without_a_burst() -> None:
    control = RateController(Ladder((Rung(320, 240, 10),), 50_000, 1e6), 200_000)
    assert control.frame_due(0.0)
    assert control.frame_due(1.0)  # a second without pictures
    assert not control.frame_due(1.033) and not control.frame_due(1.066)  # no catching up on the missed ones
    assert control.frame_due(1.1)


def test_a_link_with_room_to_spare_is_probed_upwards_and_never_a_reason_to_go_down() -> None:
    control = RateController(LADDER, 200_000)  # 150 kbit/s
    # the share is what the uplink saw used, plus a margin: below the bitrate, but the link was never full
    assert control.update(160_000, now=0.0, headroom=True) is None
    new = control.update(160_000, now=UP_AFTER, headroom=True)
    assert new is not None and new.bitrate == pytest.approx(225_000)  # 1.5 × 150 kbit/s
    assert control.update(100_000, now=UP_AFTER + MIN_GAP + 0.1) is not None  # full now: down at once


def test_probing_never_aims_past_half_again_the_share() -> None:
    control = RateController(LADDER, 200_000)
    start = control.target.bitrate  # 150 kbit/s (uncapped, five steps would have aimed at 1.1 Mbit/s)
    for step in range(1, 6):  # a quiet scene: the share stays what the uplink saw used, the link never full
        control.update(start, now=step * (UP_AFTER + MIN_GAP), headroom=True)
        control.update(start, now=step * (UP_AFTER + MIN_GAP) + UP_AFTER, headroom=True)
    assert control.target.bitrate <= PROBE_UP * start
