"""The access matrix's expectation table agrees with its oracle written from broker/README.md (both by hand)."""

from __future__ import annotations

from tests.support.acl_matrix import CLASSES, EXPECTED, PRINCIPALS, SELF, may_read, may_write, topic_of
from tests.support.procs import DEMO_PASSWORDS


def test_expectation_table_agrees_with_design_oracle() -> None:
    for p in PRINCIPALS:
        me = SELF[p]
        login = p if p in DEMO_PASSWORDS else "-refused-"
        for cls in CLASSES:
            exp = EXPECTED[p].get(cls, "")
            assert ("r" in exp) == may_read(login, topic_of(cls, me)), (p, cls)
            assert ("w" in exp) == may_write(login, topic_of(cls, me, publish=True)), (p, cls)


def test_the_oracle_reads_topics_itself() -> None:
    """It must be able to say no: other users' replies, other robots, topics outside the tree."""
    assert may_read("alice", "roslink/turtle1/to/alice/reply/reset")
    assert not may_read("alice", "roslink/turtle1/to/bob/reply/reset")
    assert not may_read("alice", "roslink/turtle2/state/pose")
    assert not may_read("alice", "elsewhere/turtle1/state/pose")
    assert may_write("bob", "roslink/turtle1/from/bob/call/status")
    assert not may_write("bob", "roslink/turtle1/from/bob/call/reset")
    assert not may_write("turtle1", "roslink/turtle2/heartbeat")
