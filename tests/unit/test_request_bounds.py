"""Pure logic of the per-user bounds: requests in flight, refusal reports, the broker's PUBLISH pacing."""

from __future__ import annotations

import pytest

from roslink_mqtt.bridge.core.budget import RequestBudget
from roslink_mqtt.bridge.core.refusals import RefusalReports
from roslink_mqtt.broker.guard import Pacer


def test_a_user_over_the_bound_is_refused_until_a_request_is_answered() -> None:
    budget = RequestBudget(2)
    assert budget.acquire("bob") and budget.acquire("bob")
    assert not budget.acquire("bob")
    assert budget.acquire("alice")  # one user's flood takes nothing from another
    budget.release("bob")
    assert budget.in_flight("bob") == 1
    assert budget.acquire("bob")
    why = budget.refusal("bob")
    assert "bridge.max_requests_per_user" in why and "2" in why and "\n" not in why


def test_a_budget_needs_room_for_one_request() -> None:
    with pytest.raises(ValueError, match="max_requests_per_user"):
        RequestBudget(0)


def test_refusal_reports_are_held_back_over_the_rate_and_counted_in_the_next_one() -> None:
    reports = RefusalReports(rate=10, burst=3)
    said = [reports.admit("bob", "t", f"bad {i}", now=0.0) for i in range(10)]
    assert said[:3] == ["bad 0", "bad 1", "bad 2"] and said[3:] == [None] * 7
    assert reports.admit("alice", "t", "hers", now=0.0) == "hers"  # per user
    later = reports.admit("bob", "t", "bad 10", now=0.1)  # one token back
    assert later is not None and later.startswith("bad 10 [7 more of your inputs were refused")


def test_a_flood_that_stops_is_still_summarised_by_the_supervision_tick() -> None:
    reports = RefusalReports(rate=10, burst=1)
    assert reports.admit("bob", "roslink/r/from/bob/param/n", "first", now=0.0) == "first"
    for i in range(5):
        assert reports.admit("bob", "roslink/r/from/bob/param/n", f"r{i}", now=0.0) is None
    assert reports.summaries(now=0.0) == []  # no token yet
    (user, topic, reason), = reports.summaries(now=0.2)
    assert (user, topic) == ("bob", "roslink/r/from/bob/param/n")
    assert reason.startswith("r4 [5 more of your inputs were refused") and "this was the last" in reason
    assert reports.summaries(now=5.0) == []  # said once; an idle, refilled user is forgotten
    assert reports._buckets == {}


def test_the_pacer_lets_a_burst_through_then_holds_the_rate() -> None:
    pacer = Pacer(rate=100, burst=5)
    pacer.at = 0.0
    assert [pacer.wait_for(1, 0.0) for _ in range(5)] == [0.0] * 5
    wait = pacer.wait_for(1, 0.0)
    assert wait == pytest.approx(0.01)  # one packet's worth at 100/s
    # the debt is paid by waiting, never carried: after the wait the next packet costs one period again
    assert pacer.wait_for(1, wait) == pytest.approx(0.01)
    assert pacer.wait_for(1, 10.0) == 0.0  # a quiet spell refills the burst, no more


def test_a_pacer_needs_a_rate_and_a_burst() -> None:
    with pytest.raises(ValueError):
        Pacer(0, 10)
    with pytest.raises(ValueError):
        Pacer(10, 0)


def test_the_bridge_never_publishes_what_the_broker_would_disconnect_it_for(caplog) -> None:
    """Over the broker's max_payload a message is dropped and logged once per topic (sent, both brokers close
    the connection, and the robot loses its link once per message)."""
    from roslink_mqtt.bridge.core.link import MqttLink
    from roslink_mqtt.mqtt import parse_broker_url

    link = MqttLink(client_id="t", username="turtle1", password="x", url=parse_broker_url("mqtt://127.0.0.1:9"),
                    keepalive=5, will=None, subscriptions=list, on_message=lambda *a: None, max_payload=1000)
    link.connected.set()  # as if connected: only the size may stop it
    published = []
    link.client.publish = lambda *a, **k: published.append(a)
    with caplog.at_level("WARNING"):
        assert link.publish("roslink/turtle1/state/map", b"x" * 1001) is None
        assert link.publish("roslink/turtle1/state/map", b"x" * 5000) is None
        link.publish("roslink/turtle1/state/map", b"x" * 1000)
    assert len(published) == 1
    warned = [r.getMessage() for r in caplog.records if "max_payload" in r.getMessage()]
    assert len(warned) == 1 and "1001 bytes > the broker's max_payload 1000" in warned[0]
