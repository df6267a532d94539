"""The broker's password checks (roslink_mqtt/broker/hashing.py): one at a time whatever arrives, in a thread so
the event loop runs meanwhile, and refused at once beyond the bounded wait. The checks here sleep instead of
hashing (what matters is how many run together and how long the queue is); no sockets."""

from __future__ import annotations

import asyncio
import threading
import time

from roslink_mqtt.broker.hashing import HashPool
from roslink_mqtt.config.passwords import VerifiedLogins, hash_password


def test_checks_run_one_at_a_time_and_the_loop_stays_free() -> None:
    pool = HashPool(max_wait=10.0)
    running, most = 0, 0
    lock = threading.Lock()

    def check() -> bool:
        nonlocal running, most
        with lock:
            running += 1
            most = max(most, running)
        time.sleep(0.02)
        with lock:
            running -= 1
        return True

    async def scenario() -> tuple[list[bool], int]:
        ticks = 0

        async def ticker() -> None:  # the event loop's other work (robots' traffic) goes on meanwhile
            nonlocal ticks
            while True:
                ticks += 1
                await asyncio.sleep(0.005)

        task = asyncio.create_task(ticker())
        results = await asyncio.gather(*(pool.run(check) for _ in range(8)))
        task.cancel()
        return list(results), ticks

    results, ticks = asyncio.run(scenario())
    assert results == [True] * 8 and most == 1 and pool.done == 8 and pool.waiting == 0
    assert ticks >= 10  # 8 × 20 ms of checks: the loop ran all along
    assert 0.01 < pool.cost < 0.1  # learnt from the checks (started at 0.1 s)


def test_beyond_the_bounded_wait_a_check_is_refused_at_once() -> None:
    pool = HashPool(max_wait=0.25)
    pool.cost = 0.1
    release = threading.Event()

    async def scenario() -> list[bool]:
        queued = [asyncio.create_task(pool.run(release.wait)) for _ in range(3)]
        await asyncio.sleep(0.05)
        verdicts = [pool.busy()]  # 3 waiting × 0.1 s > 0.25 s
        release.set()
        await asyncio.gather(*queued)
        verdicts.append(pool.busy())  # none waiting
        return verdicts

    assert asyncio.run(scenario()) == [True, False]
    assert pool.refused == 1


def test_a_suspect_check_only_gets_an_idle_pool() -> None:
    pool = HashPool(max_wait=10.0)
    release = threading.Event()

    async def scenario() -> list[bool]:
        verdicts = [pool.busy(suspect=True)]  # idle: even a guesser's attempt is checked
        running = asyncio.create_task(pool.run(release.wait))
        await asyncio.sleep(0.05)
        verdicts += [pool.busy(suspect=True), pool.busy()]  # one running: the guesser waits outside, a user does not
        release.set()
        await running
        return verdicts

    assert asyncio.run(scenario()) == [False, True, False]


def test_a_verified_login_is_remembered_without_a_slow_check() -> None:
    stored = hash_password("secret-1", iterations=1000)
    logins = VerifiedLogins()
    assert not logins.remembered("secret-1", stored)  # never verified: the slow path must run
    assert logins.verify("secret-1", stored) and logins.slow == 1
    assert logins.remembered("secret-1", stored) and not logins.remembered("secret-2", stored)
    assert logins.slow == 1  # remembered() never hashes
