"""``async for`` over a subscription ends after close() (issue 14 defect).

Runs in-process without a broker: the subscription is fed through ``deliver``
as the network thread would, and closed from the loop itself and from another
thread, the two ways a program stops a stream.
"""

from __future__ import annotations

import asyncio
import threading

from roslink_mqtt.client.dispatch import CallbackQueue
from roslink_mqtt.client.subscriptions import StateSubscription


def _subscription() -> StateSubscription:
    return StateSubscription("r1", "custom", "roslink/r1/state/custom", None, CallbackQueue())


async def _consume(sub: StateSubscription, seen: list[object]) -> None:
    async for item in sub:
        seen.append(item)


def test_async_for_ends_when_closed_from_the_loop() -> None:
    async def main() -> list[object]:
        sub = _subscription()
        seen: list[object] = []
        task = asyncio.create_task(_consume(sub, seen))
        await asyncio.sleep(0.05)  # the loop is now waiting on an empty queue
        sub.deliver(sub.topic, b'{"x": 1}', False)
        await asyncio.sleep(0.05)
        sub.close()
        await asyncio.wait_for(task, 2.0)
        return seen

    assert asyncio.run(main()) == [{"x": 1}]


def test_async_for_ends_when_closed_from_another_thread() -> None:
    async def main() -> None:
        sub = _subscription()
        task = asyncio.create_task(_consume(sub, []))
        await asyncio.sleep(0.05)
        closer = threading.Thread(target=sub.close)
        closer.start()
        await asyncio.wait_for(task, 2.0)
        closer.join()

    asyncio.run(main())


def test_async_for_over_a_closed_subscription_yields_nothing() -> None:
    async def main() -> list[object]:
        sub = _subscription()
        sub.close()
        seen: list[object] = []
        await asyncio.wait_for(_consume(sub, seen), 2.0)
        return seen

    assert asyncio.run(main()) == []
