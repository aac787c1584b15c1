"""The agent's battery watch (swarm/agent/flight.py): below agent.battery_home_fraction the mission ends, the
drone flies back the way it came and lands; a battery that low on the ground is a refusal to take off. Against
the fake autopilot, no sockets."""

from __future__ import annotations

import asyncio
import math
from typing import Any

import pytest

from swarm.agent import flight as flight_module
from swarm.agent.flight import Flight, route_mission, way_back
from swarm.bus.phase import Phase
from swarm.config import ConfigError, Vec3, load_config
from tests.agent.fake_autopilot import FakeAutopilot

HOME: Vec3 = (0.0, 0.0, 0.0)
ROUTE: list[Vec3] = [(2.0, 0.0, 1.5), (2.0, 2.0, 1.5), (4.0, 2.0, 1.5), (4.0, 4.0, 1.5)]
ABOVE_HOME: Vec3 = (0.0, 0.0, 1.5)


def fly(ap: FakeAutopilot, **settings: Any) -> tuple[Phase, list[tuple[str, dict[str, Any]]]]:
    ap.home_world = HOME
    events: list[tuple[str, dict[str, Any]]] = []
    agent = load_config().agent.model_copy(update={"cruise_speed_m_s": 10.0, **settings})  # ticks are real 0.1 s
    flight = Flight(ap, agent, lambda event, **fields: events.append((event, fields)))  # type: ignore[arg-type]
    return asyncio.run(flight.run(route_mission(ROUTE), asyncio.Event())), events


def drain_at(ap: FakeAutopilot, waypoint: Vec3, fraction: float) -> None:
    """The battery reads `fraction` once the drone has been sent to `waypoint`."""
    set_setpoint = ap.set_setpoint

    async def draining(target: Vec3, yaw_enu_deg: float) -> None:
        await set_setpoint(target, yaw_enu_deg)
        if target == waypoint:
            ap.telemetry.battery = fraction

    ap.set_setpoint = draining  # type: ignore[method-assign]


def test_a_low_battery_ends_the_route_retraces_it_home_and_lands() -> None:
    ap = FakeAutopilot()
    drain_at(ap, ROUTE[1], 0.24)
    phase, events = fly(ap, battery_home_fraction=0.25)
    assert phase == Phase.LANDED
    [low] = [f for e, f in events if e == "battery_low"]
    assert low["fraction"] == 0.24 and low["threshold"] == 0.25 and low["airborne"]
    # seen at the next tick: the carrot (where the fake vehicle is at once) has taken one step at most
    assert math.dist(low["position"], ROUTE[1]) <= 10.0 * flight_module.SETPOINT_PERIOD_S + 1e-9
    # nothing beyond the waypoint where the battery ran low; then back through the waypoints reached, then home
    reached = ap.visited.index(ROUTE[1])
    assert ROUTE[2] not in ap.visited
    home_leg = ap.visited[reached + 1 :]
    assert home_leg[-1] == ABOVE_HOME and ROUTE[0] in home_leg
    assert home_leg.index(ROUTE[0]) < len(home_leg) - 1
    assert ap.commands[-1] == "land"


def test_the_battery_is_watched_in_the_hover_after_the_route_too() -> None:
    ap = FakeAutopilot()
    drain_at(ap, ROUTE[-1], 0.2)
    phase, events = fly(ap, hover_s=30.0)
    assert phase == Phase.LANDED  # not 30 s of hovering first
    assert [e for e, _ in events].count("battery_low") == 1
    assert ap.visited[-1] == ABOVE_HOME


def test_a_battery_above_the_threshold_flies_the_whole_route() -> None:
    ap = FakeAutopilot()
    drain_at(ap, ROUTE[1], 0.26)
    phase, events = fly(ap, battery_home_fraction=0.25)
    assert phase == Phase.LANDED and ap.visited[-1] == ROUTE[-1]
    assert "battery_low" not in [e for e, _ in events]


def test_a_battery_below_the_threshold_on_the_ground_refuses_to_take_off() -> None:
    ap = FakeAutopilot()
    ap.telemetry.battery = 0.2
    phase, events = fly(ap)
    assert phase == Phase.FAILED and "arm_and_takeoff" not in ap.commands
    [low] = [f for e, f in events if e == "battery_low"]
    assert low["airborne"] is False
    [error] = [f["reason"] for e, f in events if e == "flight_error"]
    assert error == "refusing to take off: battery 20% is below agent.battery_home_fraction 25%"


def test_without_battery_telemetry_the_drone_flies_unwatched(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(flight_module, "BATTERY_WAIT_S", 0.1)
    ap = FakeAutopilot()
    ap.telemetry.battery = math.nan
    phase, events = fly(ap)
    assert phase == Phase.LANDED and ap.visited[-1] == ROUTE[-1]
    assert [e for e, _ in events].count("no_battery_telemetry") == 1


@pytest.mark.parametrize("value", [0.0, 1.0, -0.1])
def test_the_home_fraction_is_a_fraction(value: float) -> None:
    with pytest.raises(ConfigError, match="battery_home_fraction"):
        load_config(overrides={"agent.battery_home_fraction": value})


def test_the_default_home_fraction_is_above_px4s_low_threshold() -> None:
    assert load_config().agent.battery_home_fraction == 0.25 > 0.15


def test_the_way_back_is_the_flown_path_reversed_with_its_loops_cut_out() -> None:
    h, a, b, c, d = (0.0, 0.0, 1.5), (4.0, 0.0, 1.5), (4.0, 3.0, 1.5), (8.0, 3.0, 1.5), (8.0, 0.0, 1.5)
    assert way_back([h, a, b, c], 0.3) == [c, b, a, h]
    assert way_back([h, a, b, c, b, c, b], 0.3) == [b, a, h]  # to and fro: from b straight on to a
    near_a = (4.2, 0.1, 1.5)
    assert way_back([h, a, b, c, d, near_a], 0.3) == [near_a, h]  # round the block and back near a: on to h
    assert way_back([h, a, h, b], 0.3) == [b, h]  # back over home: the loop through a is cut out
    assert way_back([h], 0.3) == [h] and way_back([], 0.3) == []
