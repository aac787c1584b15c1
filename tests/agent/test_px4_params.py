"""Which PX4 parameter values make an agent's death a climb (swarm/agent/px4_params.py), and what 'set' writes;
the Flight's use of them against the fake autopilot. No sockets."""

import asyncio

import pytest

from swarm.agent.flight import Flight
from swarm.agent.px4_params import safe_writes, unsafe
from swarm.bus.phase import Phase
from swarm.config import load_config
from tests.agent.fake_autopilot import FakeAutopilot

PX4_DEFAULTS = {
    "COM_OBL_RC_ACT": 0,
    "NAV_RCL_ACT": 2,
    "NAV_DLL_ACT": 0,
    "COM_RCL_EXCEPT": 0,
    "COM_RC_IN_MODE": 3,
    "COM_LOW_BAT_ACT": 0,
    "RTL_RETURN_ALT": 60.0,
    "COM_OF_LOSS_T": 1.0,
}


def params(**changes: float) -> dict[str, float]:
    return {**PX4_DEFAULTS, **changes}


def test_px4_defaults_return_through_the_rc_loss_action() -> None:
    [finding] = unsafe(params())
    assert finding.param == "NAV_RCL_ACT" and finding.value == 2
    assert "RTL_RETURN_ALT=60 m" in finding.reason and "COM_OBL_RC_ACT=0 (Position mode)" in finding.reason


@pytest.mark.parametrize(
    "changes",
    [
        {"COM_OBL_RC_ACT": 5},  # offboard loss holds
        {"COM_OBL_RC_ACT": 4},  # lands
        {"NAV_RCL_ACT": 1},  # the RC-loss action holds
        {"NAV_RCL_ACT": 3},  # lands
        {"COM_RCL_EXCEPT": 4},  # Offboard exempt from RC loss
        {"COM_RCL_EXCEPT": 7},
        {"COM_RC_IN_MODE": 4},  # no RC expected
    ],
)
def test_values_that_hold_or_land_are_safe(changes: dict[str, float]) -> None:
    assert unsafe(params(**changes)) == []


def test_return_on_offboard_loss_or_data_link_loss_is_unsafe() -> None:
    assert [f.param for f in unsafe(params(COM_OBL_RC_ACT=3))] == ["COM_OBL_RC_ACT"]
    assert [f.param for f in unsafe(params(COM_OBL_RC_ACT=5, NAV_DLL_ACT=2))] == ["NAV_DLL_ACT"]
    assert [f.param for f in unsafe(params(NAV_DLL_ACT=2))] == ["NAV_RCL_ACT", "NAV_DLL_ACT"]
    assert [f.param for f in unsafe(params(COM_OBL_RC_ACT=9, NAV_RCL_ACT=1))] == ["COM_OBL_RC_ACT"]


@pytest.mark.parametrize("act", [1, 3])  # Return at critical (3; 1 is PX4's deprecated Return at both)
def test_a_low_battery_action_that_returns_is_unsafe_and_set_writes_land(act: int) -> None:
    values = params(COM_OBL_RC_ACT=5, COM_LOW_BAT_ACT=act)
    [finding] = unsafe(values)
    assert (finding.param, finding.value) == ("COM_LOW_BAT_ACT", act)
    assert "critical battery" in finding.reason and "RTL_RETURN_ALT=60 m" in finding.reason
    assert safe_writes(values)["COM_LOW_BAT_ACT"] == 2
    assert unsafe({**values, **safe_writes(values)}) == []


@pytest.mark.parametrize("act", [0, 2])  # PX4's default warning, and Land
def test_a_low_battery_action_that_warns_or_lands_is_safe_and_left_alone(act: int) -> None:
    values = params(COM_OBL_RC_ACT=5, COM_LOW_BAT_ACT=act)
    assert unsafe(values) == []
    assert "COM_LOW_BAT_ACT" not in safe_writes(values)


def test_set_writes_hold_and_leaves_a_safe_data_link_action() -> None:
    assert safe_writes(params()) == {"COM_OBL_RC_ACT": 5, "NAV_RCL_ACT": 1}
    assert safe_writes(params(NAV_DLL_ACT=3)) == {"COM_OBL_RC_ACT": 5, "NAV_RCL_ACT": 1}
    assert safe_writes(params(NAV_DLL_ACT=2)) == {"COM_OBL_RC_ACT": 5, "NAV_RCL_ACT": 1, "NAV_DLL_ACT": 1}
    for values in (params(), params(NAV_DLL_ACT=2), params(COM_OBL_RC_ACT=3)):
        assert unsafe({**values, **safe_writes(values)}) == []


def fly(mode: str, values: dict[str, float]) -> tuple[Phase, FakeAutopilot, list[tuple[str, dict]]]:
    ap = FakeAutopilot()
    ap.params = dict(values)
    settings = load_config(overrides={"agent.px4_params": mode}).agent
    events: list[tuple[str, dict]] = []
    flight = Flight(ap, settings, lambda event, **fields: events.append((event, fields)))  # type: ignore[arg-type]

    async def mission(f: Flight, stop: asyncio.Event) -> None:
        pass

    return asyncio.run(flight.run(mission, asyncio.Event())), ap, events


def test_check_refuses_to_take_off_naming_each_parameter() -> None:
    phase, ap, events = fly("check", params(NAV_DLL_ACT=2))
    assert phase == Phase.FAILED and "arm_and_takeoff" not in ap.commands
    assert [f["param"] for e, f in events if e == "px4_param_unsafe"] == ["NAV_RCL_ACT", "NAV_DLL_ACT"]
    [error] = [f["reason"] for e, f in events if e == "flight_error"]
    assert "refusing to take off" in error and "NAV_RCL_ACT=2" in error and "NAV_DLL_ACT=2" in error


def test_set_writes_safe_values_and_flies() -> None:
    phase, ap, events = fly("set", params())
    assert phase == Phase.LANDED and "arm_and_takeoff" in ap.commands
    assert ap.params["COM_OBL_RC_ACT"] == 5 and ap.params["NAV_RCL_ACT"] == 1
    [written] = [f for e, f in events if e == "px4_params_set"]
    assert written["read_back"] == written["written"] == {"COM_OBL_RC_ACT": 5, "NAV_RCL_ACT": 1}


def test_check_refuses_a_low_battery_return_and_set_writes_land() -> None:
    phase, ap, events = fly("check", params(COM_LOW_BAT_ACT=3))
    assert phase == Phase.FAILED and "arm_and_takeoff" not in ap.commands
    assert [f["param"] for e, f in events if e == "px4_param_unsafe"] == ["NAV_RCL_ACT", "COM_LOW_BAT_ACT"]
    phase, ap, events = fly("set", params(COM_LOW_BAT_ACT=3))
    assert phase == Phase.LANDED and ap.params["COM_LOW_BAT_ACT"] == 2
    [written] = [f for e, f in events if e == "px4_params_set"]
    assert written["read_back"] == written["written"] == {"COM_OBL_RC_ACT": 5, "NAV_RCL_ACT": 1, "COM_LOW_BAT_ACT": 2}


def test_off_neither_reads_nor_writes() -> None:
    phase, ap, _ = fly("off", params())
    assert phase == Phase.LANDED
    assert "read_params" not in ap.commands and "set_param_int" not in ap.commands
    assert ap.params == PX4_DEFAULTS


def test_the_default_is_check() -> None:
    assert load_config().agent.px4_params == "check"
