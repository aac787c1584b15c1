"""A loop that its own clock ends (a look, a yield, a wait) ends early when the process wakes late, and the flight
goes on: on a loaded machine an agent can be starved for a couple of seconds (a 5-drone hall mission logged
stalls of 2-6 s), and that is not a flight error. Telemetry heard missing is another matter (`test_failsafe.py`)."""

from __future__ import annotations

import asyncio
import time
from typing import Any

from swarm.agent.flight import Flight
from swarm.config import Vec3, load_config
from tests.agent.fake_autopilot import FakeAutopilot

STARVED_S = 1.6  # past the look's end plus the 1 s that was its deadline


def test_a_look_the_process_wakes_late_in_ends_and_the_flight_goes_on() -> None:
    ap = FakeAutopilot(in_air=True)
    ap.home_world = (0.0, 0.0, 0.0)
    events: list[str] = []
    flight = Flight(ap, load_config().agent, lambda event, **fields: events.append(event))  # type: ignore[arg-type]
    set_setpoint = ap.set_setpoint
    starved: list[float] = []

    async def starving(target: Vec3, yaw_enu_deg: float, *rest: Any) -> None:
        await set_setpoint(target, yaw_enu_deg)
        if not starved:
            starved.append(STARVED_S)
            time.sleep(STARVED_S)  # the event loop does not run: what a starved process sees

    ap.set_setpoint = starving  # type: ignore[method-assign]
    started = time.monotonic()
    asyncio.run(flight.face((3.0, 0.0, 1.5), 0.5, asyncio.Event()))  # raised FlightError before
    assert starved == [STARVED_S]
    assert time.monotonic() - started < STARVED_S + 1.0  # the look ended at the first wake-up after its end
    assert ap.visited and all(p == (0.0, 0.0, 1.5) for p in ap.visited)  # it held where it was, looking
