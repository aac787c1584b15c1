"""Before arming, a drone that keeps apart waits to hear the rest of its crew (`Flight._wait_for_crew`): a fake
autopilot, and a crew heard through the `peers_heard` callable as the agent's peer table would report it."""

from __future__ import annotations

import asyncio
import time
from typing import Any

import pytest

from swarm.agent.flight import Flight
from swarm.config import load_config
from tests.agent.fake_autopilot import FakeAutopilot

pytestmark = pytest.mark.unit


async def _idle_mission(flight: Flight, stop: asyncio.Event) -> None:
    return None


class Crew:
    """Peers heard one by one, each `every_s` after the flight first asks (None: never)."""

    def __init__(self, peers: list[int], every_s: float | None) -> None:
        self.peers, self.every_s = peers, every_s
        self.first_asked: float | None = None

    def heard(self) -> set[int]:
        now = time.monotonic()
        self.first_asked = self.first_asked if self.first_asked is not None else now
        if self.every_s is None:
            return set()
        count = int((now - self.first_asked) / self.every_s)
        return set(self.peers[:count])


def _fly(
    crew: Crew, ap: FakeAutopilot | None = None, *, separation_m: float = 1.2, crew_size: int = 3, **settings: Any
) -> tuple[list[tuple[str, dict[str, Any]]], set[int] | None]:
    """The flight's log, and the peers it had heard when it armed (None: it never armed)."""
    ap = ap or FakeAutopilot()
    events: list[tuple[str, dict[str, Any]]] = []
    at_arming: list[set[int]] = []
    ap.on_command["arm_and_takeoff"] = lambda: at_arming.append(crew.heard())
    agent = load_config().agent.model_copy(update=settings)
    flight = Flight(
        ap,  # type: ignore[arg-type]
        agent,
        lambda event, **fields: events.append((event, fields)),
        separation_m=separation_m,
        crew_size=crew_size,
        peers_heard=crew.heard,
    )
    asyncio.run(flight.run(_idle_mission, asyncio.Event()))
    return events, (at_arming[0] if at_arming else None)


def _crew_event(events: list[tuple[str, dict[str, Any]]]) -> dict[str, Any]:
    (fields,) = [f for e, f in events if e == "crew"]
    return fields


def test_a_drone_arms_only_once_it_has_heard_every_other_drone() -> None:
    events, at_arming = _fly(Crew([2, 3], every_s=0.3), crew_wait_s=10.0)
    assert at_arming == {2, 3}
    crew = _crew_event(events)
    assert crew["heard"] == [2, 3] and crew["complete"] is True
    assert 0.5 <= crew["waited_s"] < 5.0  # the second peer came 0.6 s after the first look, not the whole wait


def test_a_drone_that_never_hears_a_peer_takes_off_after_the_wait_and_says_whom_it_missed() -> None:
    events, at_arming = _fly(Crew([2, 3], every_s=None), crew_wait_s=0.4)
    assert at_arming == set()
    crew = _crew_event(events)
    assert crew["heard"] == [] and crew["expected"] == 2 and crew["complete"] is False
    assert crew["waited_s"] >= 0.4


@pytest.mark.parametrize("why", ["alone", "no separation", "wait off", "already in the air"])
def test_no_wait_when_there_is_nobody_to_keep_clear_of_or_the_drone_flies_already(why: str) -> None:
    crew = Crew([2, 3], every_s=None)
    if why == "alone":
        events, _ = _fly(crew, crew_size=1, crew_wait_s=30.0)
    elif why == "no separation":
        events, _ = _fly(crew, separation_m=0.0, crew_wait_s=30.0)
    elif why == "wait off":
        events, _ = _fly(crew, crew_wait_s=0.0)
    else:
        events, _ = _fly(crew, FakeAutopilot(in_air=True), crew_wait_s=30.0)
        assert "resumed_in_air" in [e for e, _ in events]
    assert "crew" not in [e for e, _ in events]
    assert ("phase", {"phase": "landed"}) in events  # flown through without waiting the 30 s
