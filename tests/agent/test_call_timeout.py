"""A MAVSDK call's timeout counts only time the agent process ran (`Autopilot._call`): a process frozen during a
call (SIGSTOP, starvation) must not find it timed out on waking. Found in a mission: agent 3, frozen 10 s while its
offboard setpoint call was out, woke to "no answer from the autopilot within 5 s" and landed its drone."""

from __future__ import annotations

import asyncio
import time

import pytest

from swarm.agent.autopilot import Autopilot, FlightError
from swarm.config import GeoOrigin


def _autopilot(timeout_s: float) -> Autopilot:
    return Autopilot("udpin://127.0.0.1:9", GeoOrigin(), command_timeout_s=timeout_s)  # never connected


def test_a_call_answered_after_the_process_was_frozen_is_not_a_timeout() -> None:
    async def main() -> int:
        answered = asyncio.Event()

        async def slow() -> int:
            await answered.wait()
            return 42

        loop = asyncio.get_running_loop()
        loop.call_later(0.1, time.sleep, 2.0)  # the loop does not run for 2 s, twice the timeout: a freeze
        loop.call_later(2.3, answered.set)  # the answer comes 0.2 s after waking
        return await _autopilot(1.0)._call("slow", slow)

    assert asyncio.run(main()) == 42


def test_a_call_that_never_answers_times_out_after_its_timeout_of_running_time() -> None:
    async def main() -> float:
        async def never() -> None:
            await asyncio.Event().wait()

        started = time.monotonic()
        with pytest.raises(FlightError, match="no answer from the autopilot within 0.6 s"):
            await _autopilot(0.6)._call("never", never)
        return time.monotonic() - started

    assert 0.55 < asyncio.run(main()) < 1.5
