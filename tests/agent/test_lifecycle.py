"""The agent's lifecycle: every transition of the phase table is allowed, tested and taken by the flight code on
the path that should take it (a fake autopilot, no processes), and nothing else is allowed."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from itertools import pairwise, product
from typing import Any

import pytest

from swarm.agent.autopilot import FlightError
from swarm.agent.flight import Flight
from swarm.agent.lifecycle import (
    ALLOWED,
    FINAL_PHASES,
    STAGES_ALLOWED,
    IllegalTransition,
    Stage,
    next_stage,
    transition,
)
from swarm.bus.phase import Phase
from swarm.config import load_config
from tests.agent.fake_autopilot import FakeAutopilot

pytestmark = pytest.mark.unit

P = Phase
# Every transition the table allows, with the flight path that takes it (a scenario below).
TESTED_TRANSITIONS: dict[tuple[Phase, Phase], str] = {
    (P.CONNECTING, P.READY): "normal",
    (P.CONNECTING, P.FAILED): "no autopilot",
    (P.READY, P.TAKEOFF): "normal",
    (P.READY, P.LANDED): "stop before take-off",
    (P.READY, P.FAILED): "error on the ground",
    (P.TAKEOFF, P.FLYING): "normal",
    (P.TAKEOFF, P.LANDING): "stop while climbing",
    (P.TAKEOFF, P.FAILSAFE): "telemetry lost while climbing",
    (P.TAKEOFF, P.FAILED): "arming refused",
    (P.FLYING, P.HOVERING): "normal",
    (P.FLYING, P.RETURNING): "battery low on the mission",
    (P.FLYING, P.LANDING): "no hover",
    (P.FLYING, P.FAILSAFE): "telemetry lost on the mission",
    (P.HOVERING, P.RETURNING): "battery low while hovering",
    (P.HOVERING, P.LANDING): "normal",
    (P.HOVERING, P.FAILSAFE): "telemetry lost while hovering",
    (P.RETURNING, P.LANDING): "battery low on the mission",
    (P.RETURNING, P.FAILSAFE): "telemetry lost on the way home",
    (P.LANDING, P.LANDED): "normal",
    (P.LANDING, P.FAILED): "land refused",
}


def _allowed_pairs() -> set[tuple[Phase, Phase]]:
    return {(a, b) for a, following in ALLOWED.items() for b in following}


@pytest.mark.parametrize("current, wanted", list(TESTED_TRANSITIONS), ids=lambda p: str(p))
def test_the_lifecycle_allows_the_transition(current: Phase, wanted: Phase) -> None:
    assert transition(current, wanted) == wanted


def test_every_allowed_transition_is_tested_and_no_other() -> None:
    assert _allowed_pairs() == set(TESTED_TRANSITIONS)


def test_every_flight_phase_is_in_the_table_and_mapping_is_not() -> None:
    assert set(ALLOWED) == set(Phase) - {Phase.MAPPING}
    assert FINAL_PHASES == {Phase.LANDED, Phase.FAILSAFE, Phase.FAILED}


ILLEGAL = sorted((a, b) for a, b in product(ALLOWED, Phase) if a != b and (a, b) not in TESTED_TRANSITIONS)


@pytest.mark.parametrize("current, wanted", ILLEGAL, ids=lambda p: str(p))
def test_any_other_transition_is_refused(current: Phase, wanted: Phase) -> None:
    with pytest.raises(IllegalTransition):
        transition(current, wanted)


def test_staying_in_a_phase_is_no_transition() -> None:
    assert all(transition(p, p) == p for p in ALLOWED)


# -- the flight takes them -----------------------------------------------------------------------------------


async def _idle_mission(flight: Flight, stop: asyncio.Event) -> None:
    return None


async def _silent_mission(flight: Flight, stop: asyncio.Event) -> None:
    flight.ap.go_silent()  # type: ignore[attr-defined]
    await flight.face((1.0, 0.0, 1.5), 1.0, stop)


def _fly(
    ap: FakeAutopilot,
    *,
    stop: asyncio.Event | None = None,
    mission: Any = _idle_mission,
    prepare: Callable[[Flight], None] = lambda flight: None,
    homeward: Any = None,
    **settings: Any,
) -> tuple[list[Phase], Phase, list[str]]:
    """Fly with `ap`; the phases the flight went through (from its log), the final one and every log event."""
    events: list[tuple[str, dict[str, Any]]] = []
    agent = load_config().agent.model_copy(update=settings)
    flight = Flight(ap, agent, lambda event, **fields: events.append((event, fields)))  # type: ignore[arg-type]
    prepare(flight)
    final = asyncio.run(flight.run(mission, stop or asyncio.Event(), homeward))
    phases = [Phase.CONNECTING, *(Phase(f["phase"]) for e, f in events if e == "phase")]
    return phases, final, [e for e, _ in events]


def _stopped() -> asyncio.Event:
    stop = asyncio.Event()
    stop.set()
    return stop


def _scenario_normal() -> Any:
    return _fly(FakeAutopilot(), hover_s=0.15)


def _scenario_no_hover() -> Any:
    return _fly(FakeAutopilot())


def _scenario_no_autopilot() -> Any:
    return _fly(FakeAutopilot(refuse=frozenset({"connect"})))


def _scenario_stop_before_take_off() -> Any:
    return _fly(FakeAutopilot(), stop=_stopped(), start_delay_s=0.3)


def _scenario_error_on_the_ground() -> Any:
    async def wait_timed_out(seconds: float, stop: asyncio.Event) -> None:
        raise FlightError("timed out flying to the end of a wait")  # what a stall past the wait's deadline raises

    return _fly(FakeAutopilot(), start_delay_s=0.5, prepare=lambda flight: setattr(flight, "_wait", wait_timed_out))


def _scenario_stop_while_climbing() -> Any:
    stop = asyncio.Event()
    ap = FakeAutopilot(climbs=False)
    ap.on_command["arm_and_takeoff"] = stop.set
    return _fly(ap, stop=stop)


def _scenario_telemetry_lost_while_climbing() -> Any:
    ap = FakeAutopilot(climbs=False)
    ap.on_command["arm_and_takeoff"] = ap.go_silent
    return _fly(ap)


def _scenario_arming_refused() -> Any:
    return _fly(FakeAutopilot(refuse=frozenset({"arm_and_takeoff"})))


def _scenario_telemetry_lost_on_the_mission() -> Any:
    return _fly(FakeAutopilot(), mission=_silent_mission)


def _scenario_telemetry_lost_while_hovering() -> Any:
    ap = FakeAutopilot()

    async def mission(flight: Flight, stop: asyncio.Event) -> None:
        asyncio.get_running_loop().call_later(0.2, ap.go_silent)

    return _fly(ap, mission=mission, hover_s=2.0)


async def _low_battery_mission(flight: Flight, stop: asyncio.Event) -> None:
    flight.ap.telemetry.battery = 0.05  # below agent.battery_home_fraction: the next check ends the mission
    await flight.face((1.0, 0.0, 1.5), 1.0, stop)


def _scenario_battery_low_on_the_mission() -> Any:
    return _fly(FakeAutopilot(), mission=_low_battery_mission)


def _scenario_battery_low_while_hovering() -> Any:
    ap = FakeAutopilot()

    async def mission(flight: Flight, stop: asyncio.Event) -> None:
        asyncio.get_running_loop().call_later(0.2, setattr, ap.telemetry, "battery", 0.05)

    return _fly(ap, mission=mission, hover_s=2.0)


def _scenario_telemetry_lost_on_the_way_home() -> Any:
    return _fly(FakeAutopilot(), mission=_low_battery_mission, homeward=_silent_mission)


def _scenario_land_refused() -> Any:
    return _fly(FakeAutopilot(refuse=frozenset({"land"})))


def _scenario_resumed_in_the_air() -> Any:
    return _fly(FakeAutopilot(in_air=True))


def _scenario_taken_over_while_hovering() -> Any:
    ap = FakeAutopilot()

    async def mission(flight: Flight, stop: asyncio.Event) -> None:
        asyncio.get_running_loop().call_later(0.2, ap.take_over, "LAND")

    return _fly(ap, mission=mission, hover_s=2.0)


UP_AND_DOWN = [P.CONNECTING, P.READY, P.TAKEOFF, P.FLYING, P.LANDING, P.LANDED]
SCENARIOS: dict[str, tuple[Callable[[], Any], list[Phase]]] = {
    "normal": (_scenario_normal, [P.CONNECTING, P.READY, P.TAKEOFF, P.FLYING, P.HOVERING, P.LANDING, P.LANDED]),
    "no hover": (_scenario_no_hover, UP_AND_DOWN),
    "no autopilot": (_scenario_no_autopilot, [P.CONNECTING, P.FAILED]),
    "stop before take-off": (_scenario_stop_before_take_off, [P.CONNECTING, P.READY, P.LANDED]),
    "error on the ground": (_scenario_error_on_the_ground, [P.CONNECTING, P.READY, P.FAILED]),
    "stop while climbing": (_scenario_stop_while_climbing, [P.CONNECTING, P.READY, P.TAKEOFF, P.LANDING, P.LANDED]),
    "telemetry lost while climbing": (
        _scenario_telemetry_lost_while_climbing,
        [P.CONNECTING, P.READY, P.TAKEOFF, P.FAILSAFE],
    ),
    "arming refused": (_scenario_arming_refused, [P.CONNECTING, P.READY, P.TAKEOFF, P.FAILED]),
    "telemetry lost on the mission": (
        _scenario_telemetry_lost_on_the_mission,
        [P.CONNECTING, P.READY, P.TAKEOFF, P.FLYING, P.FAILSAFE],
    ),
    "telemetry lost while hovering": (
        _scenario_telemetry_lost_while_hovering,
        [P.CONNECTING, P.READY, P.TAKEOFF, P.FLYING, P.HOVERING, P.FAILSAFE],
    ),
    "battery low on the mission": (
        _scenario_battery_low_on_the_mission,
        [P.CONNECTING, P.READY, P.TAKEOFF, P.FLYING, P.RETURNING, P.LANDING, P.LANDED],
    ),
    "battery low while hovering": (
        _scenario_battery_low_while_hovering,
        [P.CONNECTING, P.READY, P.TAKEOFF, P.FLYING, P.HOVERING, P.RETURNING, P.LANDING, P.LANDED],
    ),
    "telemetry lost on the way home": (
        _scenario_telemetry_lost_on_the_way_home,
        [P.CONNECTING, P.READY, P.TAKEOFF, P.FLYING, P.RETURNING, P.FAILSAFE],
    ),
    "land refused": (_scenario_land_refused, [P.CONNECTING, P.READY, P.TAKEOFF, P.FLYING, P.LANDING, P.FAILED]),
    "resumed in the air": (_scenario_resumed_in_the_air, UP_AND_DOWN),
    "taken over while hovering": (
        _scenario_taken_over_while_hovering,
        [P.CONNECTING, P.READY, P.TAKEOFF, P.FLYING, P.HOVERING, P.FAILSAFE],
    ),
}


@pytest.mark.parametrize("name", list(SCENARIOS))
def test_the_flight_goes_through_the_phases_of_its_path_each_allowed(name: str) -> None:
    scenario, expected = SCENARIOS[name]
    phases, final, events = scenario()
    assert phases == expected
    assert final == expected[-1] and final in FINAL_PHASES
    assert "illegal_transition" not in events
    for current, wanted in pairwise(phases):
        assert transition(current, wanted) == wanted


def test_every_tested_transition_names_a_scenario_that_takes_it() -> None:
    taken = {pair for _, expected in SCENARIOS.values() for pair in pairwise(expected)}
    assert taken == set(TESTED_TRANSITIONS)
    for pair, name in TESTED_TRANSITIONS.items():
        assert pair in set(pairwise(SCENARIOS[name][1])), (pair, name)


def test_a_drone_resumed_in_the_air_is_not_armed_again() -> None:
    ap = FakeAutopilot(in_air=True)
    _, final, events = _fly(ap)
    assert "resumed_in_air" in events and "arm_and_takeoff" not in ap.commands and final == Phase.LANDED


def test_an_illegal_transition_is_logged_and_taken_all_the_same() -> None:
    events: list[tuple[str, dict[str, Any]]] = []
    flight = Flight(FakeAutopilot(), load_config().agent, lambda e, **f: events.append((e, f)))  # type: ignore[arg-type]
    flight._set_phase(Phase.LANDING)  # connecting -> landing: a bug, but the way down is never refused
    assert flight.phase == Phase.LANDING
    assert events[0][0] == "illegal_transition" and events[0][1]["wanted"] == "landing"
    assert events[-1] == ("phase", {"phase": "landing"})


# -- process stages ------------------------------------------------------------------------------------------

TESTED_STAGES = {
    (Stage.FLIGHT, Stage.LINGERING): "a normal landing with map sharing",
    (Stage.FLIGHT, Stage.EXITING): "a stop request, or no map sharing",
    (Stage.LINGERING, Stage.EXITING): "the swarm holds one map, or the linger timed out",
}


@pytest.mark.parametrize("current, wanted", list(TESTED_STAGES), ids=lambda s: str(s))
def test_the_process_may_go_on_to_the_stage(current: Stage, wanted: Stage) -> None:
    assert next_stage(current, wanted) == wanted


def test_every_stage_transition_is_tested_and_no_other() -> None:
    assert {(a, b) for a, following in STAGES_ALLOWED.items() for b in following} == set(TESTED_STAGES)


@pytest.mark.parametrize(
    "current, wanted", [(a, b) for a, b in product(Stage, Stage) if (a, b) not in TESTED_STAGES], ids=str
)
def test_the_process_never_goes_back_a_stage(current: Stage, wanted: Stage) -> None:
    with pytest.raises(IllegalTransition):
        next_stage(current, wanted)
