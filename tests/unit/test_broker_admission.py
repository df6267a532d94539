"""Logins waiting for a place among those being checked (roslink_mqtt/broker/admission.py): woken in turn, never
polled — a fleet reconnecting at once from one address costs the event loop one wake-up per answered attempt."""

from __future__ import annotations

import asyncio
import time

import pytest

from roslink_mqtt.broker.admission import Admission
from roslink_mqtt.broker.ratelimit import LoginThrottle

pytestmark = pytest.mark.unit


class CountingThrottle(LoginThrottle):
    """A real throttle that counts the tries and the most attempts checked at once."""

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.tries, self.checking, self.most = 0, 0, 0

    def try_begin(self, address: str, login: str):
        self.tries += 1
        slot = super().try_begin(address, login)
        if slot is not None:
            self.checking += 1
            self.most = max(self.most, self.checking)
        return slot

    def end(self, admitted) -> None:
        self.checking -= 1
        super().end(admitted)


def test_a_fleet_reconnecting_from_one_address_is_checked_a_few_at_a_time_and_woken_once_each() -> None:
    """1,000 robots and 1,000 operators behind one NAT, all at once (a broker restart), each check 1 ms: everyone
    gets in, at most five are checked at once, and each attempt is tried about once or twice — polled every 5 ms,
    as before, it was tried ~80 times (the 2,000 waiting woke the loop 400,000 times a second)."""
    throttle, admission = CountingThrottle(max_wait=30.0), Admission()
    admitted: list[str] = []

    async def login(n: int) -> None:
        slot = await admission.begin(throttle, "10.0.0.1", f"login-{n}")
        assert slot is not None, n
        try:
            await asyncio.sleep(0.001)  # the password check
            admitted.append(f"login-{n}")
        finally:
            admission.end(throttle, slot)

    async def herd() -> float:
        started = time.monotonic()
        await asyncio.gather(*(login(n) for n in range(2000)))
        return time.monotonic() - started

    took = asyncio.run(herd())
    assert len(admitted) == 2000 and throttle.most == 5, throttle.most
    assert throttle.tries <= 3 * 2000, f"{throttle.tries} tries for 2,000 logins: the waiters poll"
    assert admission.waiting() == 0
    print(f"2,000 logins from one address in {took:.2f} s, {throttle.tries} tries")


def test_the_oldest_waiter_goes_first() -> None:
    throttle, admission = LoginThrottle(free_failures=1, max_wait=5.0), Admission()
    order: list[int] = []

    async def run() -> None:
        first = await admission.begin(throttle, "gw", "holder")
        assert first is not None

        async def wait(n: int) -> None:
            slot = await admission.begin(throttle, "gw", f"u{n}")
            assert slot is not None
            order.append(n)
            admission.end(throttle, slot)

        waiters = [asyncio.create_task(wait(n)) for n in range(4)]
        await asyncio.sleep(0.01)
        assert order == [] and admission.waiting() == 4
        admission.end(throttle, first)
        await asyncio.gather(*waiters)

    asyncio.run(run())
    assert order == [0, 1, 2, 3]


def test_nobody_freeing_a_place_means_refused_after_max_wait() -> None:
    throttle, admission = LoginThrottle(free_failures=1, max_wait=0.05), Admission()

    async def run() -> object:
        assert await admission.begin(throttle, "gw", "holder") is not None
        started = time.monotonic()
        slot = await admission.begin(throttle, "gw", "late")
        return slot, time.monotonic() - started

    slot, took = asyncio.run(run())
    assert slot is None and 0.04 < took < 1.0


def test_a_waiter_that_is_gone_does_not_swallow_a_place() -> None:
    """A login cancelled while it waits (its connection closed, the broker stopping) leaves the next one its turn."""
    throttle, admission = LoginThrottle(free_failures=1, max_wait=5.0), Admission()

    async def run() -> bool:
        holder = await admission.begin(throttle, "gw", "holder")
        assert holder is not None
        gone = asyncio.create_task(admission.begin(throttle, "gw", "gone"))
        next_one = asyncio.create_task(admission.begin(throttle, "gw", "next"))
        await asyncio.sleep(0.01)
        gone.cancel()
        await asyncio.sleep(0.01)
        admission.end(throttle, holder)
        slot = await asyncio.wait_for(next_one, 1.0)
        return slot is not None

    assert asyncio.run(run())


def test_a_place_the_woken_cannot_use_goes_to_the_next_in_line() -> None:
    """One at a time per address and per login: x holds (A, l1), p holds (B, l2); z = (A, l2) waits for A and l2,
    y = (A, l3) for A, after z. x ends: z is woken for A but still waits for l2, so A goes on to y at once
    (not after y's max_wait)."""
    throttle, admission = LoginThrottle(free_failures=1, max_wait=5.0), Admission()

    async def run() -> float:
        x = await admission.begin(throttle, "A", "l1")
        p = await admission.begin(throttle, "B", "l2")
        assert x is not None and p is not None
        z = asyncio.create_task(admission.begin(throttle, "A", "l2"))
        await asyncio.sleep(0.01)
        y = asyncio.create_task(admission.begin(throttle, "A", "l3"))
        await asyncio.sleep(0.01)
        started = time.monotonic()
        admission.end(throttle, x)
        slot = await asyncio.wait_for(y, 2.0)
        assert slot is not None and not z.done()
        took = time.monotonic() - started
        admission.end(throttle, slot)
        admission.end(throttle, p)
        z_slot = await asyncio.wait_for(z, 2.0)  # and z, once l2 and A are both free
        assert z_slot is not None
        return took

    assert asyncio.run(run()) < 0.5


def test_a_place_freed_for_a_login_that_needs_none_goes_on() -> None:
    """One at a time per address: alice's first login holds the address's place, a second alice and then bob wait
    for it. The first succeeds, which makes (address, alice) known good: the second alice, woken first, needs no
    place any more, and must hand the one it was woken for to bob (who waited until his max_wait: the test's
    fleet of six logins six times over, once in a clean-clone run)."""
    throttle, admission = LoginThrottle(free_failures=1, max_wait=5.0), Admission()

    async def run() -> float:
        first = await admission.begin(throttle, "gw", "alice")
        assert first is not None
        again = asyncio.create_task(admission.begin(throttle, "gw", "alice"))
        await asyncio.sleep(0.01)
        bob = asyncio.create_task(admission.begin(throttle, "gw", "bob"))
        await asyncio.sleep(0.01)
        started = time.monotonic()
        throttle.succeeded("gw", "alice")
        admission.end(throttle, first)
        assert await asyncio.wait_for(again, 1.0) == ()  # known good: checked without a place
        slot = await asyncio.wait_for(bob, 2.0)
        assert slot is not None
        return time.monotonic() - started

    assert asyncio.run(run()) < 0.5
