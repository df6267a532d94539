"""Sequence-number tracking with wrap-around."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from roslink_mqtt.protocol import SequenceTracker, Verdict


def test_new_duplicate_stale() -> None:
    t = SequenceTracker(window=100)
    assert t.check("alice", 10) is Verdict.NEW
    assert t.check("alice", 11) is Verdict.NEW
    assert t.check("alice", 11) is Verdict.DUPLICATE
    assert t.check("alice", 5) is Verdict.STALE
    assert t.check("alice", 30) is Verdict.NEW  # gaps are fine (lost messages)
    assert t.check("bob", 5) is Verdict.NEW  # senders are independent


def test_wrap_around_is_newer() -> None:
    t = SequenceTracker()
    assert t.check("a", 2**32 - 2) is Verdict.NEW
    assert t.check("a", 2**32 - 1) is Verdict.NEW
    assert t.check("a", 0) is Verdict.NEW
    assert t.check("a", 1) is Verdict.NEW
    assert t.check("a", 2**32 - 1) is Verdict.STALE


def test_restarted_sender_is_accepted() -> None:
    t = SequenceTracker(window=1024)
    t.check("a", 50_000)
    assert t.check("a", 0) is Verdict.RESTART
    assert t.check("a", 1) is Verdict.NEW
    assert t.check("a", 0) is Verdict.STALE


def test_forget() -> None:
    t = SequenceTracker()
    t.check("a", 9)
    t.forget("a")
    assert len(t) == 0 and t.check("a", 9) is Verdict.NEW


@given(st.integers(0, 2**32 - 1), st.lists(st.integers(1, 1000), min_size=1, max_size=50))
def test_increasing_stream_always_accepted_and_recent_replays_never(start: int, steps: list[int]) -> None:
    t = SequenceTracker(window=1024)
    seq = start
    seen = []
    for step in steps:
        assert t.check("s", seq).accepted
        seen.append(seq)
        seq = (seq + step) % 2**32
    last = seen[-1]
    for old in seen:
        if (last - old) % 2**32 <= 1024:  # within the window: a replay, never a restart
            assert not t.check("s", old).accepted
