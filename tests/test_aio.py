"""`wait_event`: waits with a timeout and never swallows a cancellation."""

import asyncio

import pytest

from swarm.aio import wait_event


async def test_returns_true_when_set_and_false_on_timeout() -> None:
    event = asyncio.Event()
    assert await wait_event(event, 0.01) is False
    asyncio.get_running_loop().call_later(0.01, event.set)
    assert await wait_event(event, 5.0) is True


async def test_a_cancel_arriving_as_the_event_is_set_is_not_swallowed() -> None:
    event = asyncio.Event()
    task = asyncio.create_task(wait_event(event, 10.0))
    await asyncio.sleep(0)  # the task is now waiting
    event.set()
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task
