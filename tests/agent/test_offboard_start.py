"""Entering offboard after a freeze (`start_offboard`): MAVSDK drops the setpoint it streams when a heartbeat shows
the vehicle out of offboard more than 3 s after the last start, and a heartbeat between the agent's setpoint and its
start made the start fail with NO_SETPOINT_SET. Found in a mission: agent 3, frozen 10 s (its vehicle in HOLD, PX4's
offboard loss), woke to "offboard start refused: NO_SETPOINT_SET" and landed its drone."""

from __future__ import annotations

import asyncio

import pytest
from mavsdk.asyncio.plugins.offboard import OffboardError, OffboardResult
from mavsdk.plugins.offboard import PositionNedYaw

from swarm.agent.autopilot import OFFBOARD_START_ATTEMPTS, start_offboard

SETPOINT = PositionNedYaw(1.0, 2.0, -1.5, 90.0)


class _Offboard:
    """MAVSDK's offboard plugin as `start_offboard` uses it: each start refused with the next of `refusals`."""

    def __init__(self, refusals: list[OffboardResult]) -> None:
        self.refusals = refusals
        self.calls: list[str] = []

    async def start(self) -> None:
        self.calls.append("start")
        if self.refusals:
            raise OffboardError(self.refusals.pop(0), "start()")

    async def set_position_ned(self, setpoint: PositionNedYaw) -> None:
        assert setpoint is SETPOINT
        self.calls.append("setpoint")


def test_a_start_refused_for_a_dropped_setpoint_sets_it_again_and_starts() -> None:
    offboard = _Offboard([OffboardResult.NO_SETPOINT_SET])
    asyncio.run(start_offboard(offboard, SETPOINT))  # type: ignore[arg-type]  # the two calls it makes
    assert offboard.calls == ["start", "setpoint", "start"]


def test_any_other_refusal_and_a_setpoint_dropped_every_time_are_raised() -> None:
    denied = _Offboard([OffboardResult.COMMAND_DENIED])
    with pytest.raises(OffboardError):
        asyncio.run(start_offboard(denied, SETPOINT))  # type: ignore[arg-type]
    assert denied.calls == ["start"]
    dropped = _Offboard([OffboardResult.NO_SETPOINT_SET] * OFFBOARD_START_ATTEMPTS)
    with pytest.raises(OffboardError):
        asyncio.run(start_offboard(dropped, SETPOINT))  # type: ignore[arg-type]
    assert dropped.calls.count("start") == OFFBOARD_START_ATTEMPTS
