"""The one-bridge claim as pure logic: which of two claims keeps the robot, what a starting bridge decides from the
heartbeats it hears, and what a running bridge does when another one shows up. The real processes are in
tests/integration/test_one_bridge.py."""

from __future__ import annotations

import pytest

from roslink_mqtt.bridge.core.claim import (
    Claim,
    ClaimWatch,
    Verdict,
    announcement,
    check_claim,
    read_announcement,
    read_heartbeat,
    start_wait,
    winner,
)
from roslink_mqtt.protocol import Envelope, MessageId, SystemStatus, encode

OLD = Claim("aaaa", "robot-pc", 100, 1000.0)
NEW = Claim("bbbb", "laptop", 200, 2000.0)
NEW_TAKE_OVER = Claim("cccc", "laptop", 300, 3000.0, take_over=True)


def beat(claim: Claim, status: SystemStatus = SystemStatus.ACTIVE) -> bytes:
    return encode(Envelope(MessageId.HEARTBEAT, {"type": 1, "name": "turtle1", "system_status": int(status),
                                                  "owner_id": "", "mode": 0, "session": 1, **claim.fields()}, 1, 1))


def test_the_older_claim_wins_unless_the_newer_takes_over() -> None:
    assert winner(OLD, NEW) is OLD and winner(NEW, OLD) is OLD
    assert winner(OLD, NEW_TAKE_OVER) is NEW_TAKE_OVER and winner(NEW_TAKE_OVER, OLD) is NEW_TAKE_OVER
    # an old take-over claim does not make a newer plain one win
    assert winner(NEW_TAKE_OVER, Claim("dddd", "x", 1, 4000.0)) is NEW_TAKE_OVER
    # same second: the instance decides, the same way on both sides
    a, b = Claim("a1", "h", 1, 5.0), Claim("b1", "h", 2, 5.0)
    assert winner(a, b) is winner(b, a) is a


def test_a_heartbeat_carries_its_claim_and_old_ones_read_as_oldest() -> None:
    status, claim = read_heartbeat(beat(NEW))
    assert status == SystemStatus.ACTIVE and claim == NEW
    legacy = encode(Envelope(MessageId.HEARTBEAT, {"type": 1, "name": "turtle1", "system_status": 4, "owner_id": "",
                                                   "mode": 0}, 1, 1))
    assert read_heartbeat(legacy)[1].since == 0.0
    assert read_heartbeat(b"") is None and read_heartbeat(b"{not json") is None
    assert "on robot-pc (pid 100) since" in OLD.describe()


class FakeBroker:
    """The start check's connection: delivers scripted heartbeats; ``live`` plays a live bridge, which answers each
    announcement at once (in the publishing thread: no timer to fall behind on a busy machine, which made the
    stubborn case read as "stood down" once in CI) or, with ``stands_down``, says offline to a take-over."""

    def __init__(self, retained: bytes | None = None, live: Claim | None = None, stands_down: bool = True) -> None:
        self.retained, self.live, self.stands_down = retained, live, stands_down
        self.published: list[bytes] = []

    def connect(self, on_heartbeat):
        if self.retained is not None:
            on_heartbeat(self.retained, True)

        def publish(_robot: str, payload: bytes) -> None:
            self.published.append(payload)
            if self.live is None:
                return
            claim = read_announcement(payload)
            if claim.take_over and self.stands_down:
                gone, self.live = self.live, None
                on_heartbeat(beat(gone, SystemStatus.OFFLINE), False)
            else:
                on_heartbeat(beat(self.live), False)
        return publish, 0.001


def check(broker: FakeBroker, me: Claim, period: float = 0.1):
    return check_claim(broker.connect, "turtle1", me, period, announce=announcement(me),
                       handover_timeout=0.2)


def test_start_check_verdicts() -> None:
    assert check(FakeBroker(), NEW).verdict is Verdict.START  # nothing there
    assert check(FakeBroker(beat(OLD, SystemStatus.OFFLINE)), NEW).verdict is Verdict.START  # went away cleanly
    refused = check(FakeBroker(beat(OLD), live=OLD), NEW)
    assert refused.verdict is Verdict.REFUSE and refused.other == OLD
    assert "already has a live bridge on robot-pc (pid 100)" in refused.refusal("turtle1")
    silent = check(FakeBroker(beat(OLD)), NEW)  # retained online, nobody answers: died without a will
    assert silent.verdict is Verdict.REPLACE and silent.other == OLD and "without a last-will" in silent.note
    took = check(FakeBroker(beat(OLD), live=OLD), NEW_TAKE_OVER)
    assert took.verdict is Verdict.REPLACE and took.other == OLD and took.note.startswith("took over")
    # heard at the announcement, then silent past the hand-over timeout (0.2 s) but well within 1.5 periods
    stubborn = check(FakeBroker(beat(OLD), live=OLD, stands_down=False), NEW_TAKE_OVER, period=0.5)
    assert stubborn.verdict is Verdict.REPLACE and "did not stand down" in stubborn.note
    assert check_claim(lambda _cb: None, "turtle1", NEW, 1.0, announce=b"").verdict is Verdict.START  # no broker


def test_running_bridge_yields_to_an_older_or_take_over_claim_and_answers_a_starting_one() -> None:
    fenced: list[tuple[str, Claim]] = []
    answers: list[int] = []
    watch = ClaimWatch(NEW, lambda why, rival: fenced.append((why, rival)), lambda: answers.append(1))
    watch.on_heartbeat("turtle1", beat(NEW), False)  # its own
    watch.on_heartbeat("turtle1", beat(OLD), True)  # retained: history, not a live bridge
    watch.on_announcement("turtle1", announcement(Claim("zzzz", "h", 1, 9000.0)), False)
    assert not fenced and answers == [1]  # a newer bridge starting: told the robot is taken
    watch.on_announcement("turtle1", b"not a claim", False)
    assert answers == [1]
    watch.on_heartbeat("turtle1", beat(OLD, SystemStatus.OFFLINE), False)  # an offline one claims nothing
    assert not fenced
    watch.on_heartbeat("turtle1", beat(OLD), False)
    assert fenced and fenced[0][1] == OLD and "started earlier" in fenced[0][0]
    assert watch.fenced is not None
    watch.on_heartbeat("turtle1", beat(NEW_TAKE_OVER), False)  # once fenced, nothing more
    assert len(fenced) == 1

    old = ClaimWatch(OLD, lambda why, rival: fenced.append((why, rival)), lambda: None)
    old.on_announcement("turtle1", announcement(NEW_TAKE_OVER), False)
    assert fenced[-1][1] == NEW_TAKE_OVER and fenced[-1][0].startswith("taken over by the bridge on laptop")


def test_the_start_wait_follows_the_round_trip() -> None:
    assert start_wait(0.001, 1.0) == 0.1  # loopback: the floor
    assert start_wait(0.15, 1.0) == pytest.approx(0.6)  # a slow link: four round trips
    assert start_wait(2.0, 1.0) == 1.2  # never longer than 1.2 heartbeat periods
