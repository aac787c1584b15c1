"""PX4's failsafe rules as the simulator decides them (swarm/agent/px4_failsafe.py): one test per rule, no sockets."""

import pytest

from swarm.agent.px4_failsafe import (
    Action,
    BatteryWarning,
    battery_arming_refusal,
    battery_warning,
    datalink_loss_action,
    low_battery_action,
    offboard_loss_action,
)
from swarm.config import SimSettings
from swarm.sim.px4 import FlightMode, Params


@pytest.fixture
def params() -> Params:
    return Params(SimSettings(), 1)


def decide(params: Params, mode: FlightMode = FlightMode.OFFBOARD, rc: bool = False) -> Action:
    return offboard_loss_action(params.__getitem__, mode.name, rc).action


def test_px4_defaults() -> None:
    p = Params(SimSettings(), 1)
    assert (p["COM_OF_LOSS_T"], p["COM_OBL_RC_ACT"], p["NAV_RCL_ACT"], p["NAV_DLL_ACT"]) == (1.0, 0, 2, 0)
    assert (p["COM_DL_LOSS_T"], p["COM_RC_IN_MODE"], p["COM_RCL_EXCEPT"]) == (10, 3, 0)
    assert (p["RTL_RETURN_ALT"], p["COM_DISARM_LAND"]) == (60.0, 2.0)
    assert (p["BAT_LOW_THR"], p["BAT_CRIT_THR"], p["BAT_EMERGEN_THR"]) == pytest.approx((0.15, 0.07, 0.05))
    assert (p["COM_LOW_BAT_ACT"], p["COM_ARM_BAT_MIN"]) == (0, -1.0)
    ints = ("COM_OBL_RC_ACT", "NAV_RCL_ACT", "NAV_DLL_ACT", "COM_DL_LOSS_T", "COM_RC_IN_MODE", "COM_RCL_EXCEPT")
    for name in (*ints, "COM_LOW_BAT_ACT"):
        assert p.get(name).type == 6, name  # MAV_PARAM_TYPE_INT32, as in PX4
    for name in ("BAT_LOW_THR", "BAT_CRIT_THR", "BAT_EMERGEN_THR", "COM_ARM_BAT_MIN"):
        assert p.get(name).type == 9, name  # MAV_PARAM_TYPE_REAL32


def test_defaults_without_rc_take_the_rc_loss_action_return(params: Params) -> None:
    decision = offboard_loss_action(params.__getitem__, FlightMode.OFFBOARD, rc_present=False)
    assert decision.action == Action.RETURN
    assert "NAV_RCL_ACT=2" in decision.reason


@pytest.mark.parametrize("obl", [0, 1, 2])
def test_a_stick_mode_with_rc_is_flown_sticks_centred(params: Params, obl: int) -> None:
    params.set("COM_OBL_RC_ACT", obl)
    assert decide(params, rc=True) == Action.HOLD


@pytest.mark.parametrize(
    ("obl", "action"),
    [(3, Action.RETURN), (4, Action.LAND), (5, Action.HOLD), (6, Action.TERMINATE), (7, Action.DISARM)],
)
def test_a_non_stick_offboard_loss_action_is_taken_as_it_is(params: Params, obl: int, action: Action) -> None:
    params.set("NAV_RCL_ACT", 2)  # not consulted
    params.set("COM_OBL_RC_ACT", obl)
    assert decide(params) == action
    assert decide(params, rc=True) == action


@pytest.mark.parametrize(
    ("rcl", "action"),
    [
        (0, Action.HOLD),
        (1, Action.HOLD),
        (2, Action.RETURN),
        (3, Action.LAND),
        (5, Action.TERMINATE),
        (6, Action.DISARM),
    ],
)
def test_each_rc_loss_action_replaces_a_stick_mode(params: Params, rcl: int, action: Action) -> None:
    params.set("NAV_RCL_ACT", rcl)
    for obl in (0, 1, 2):
        params.set("COM_OBL_RC_ACT", obl)
        assert decide(params) == action, (obl, rcl)


def test_no_rc_expected_falls_back_to_hold(params: Params) -> None:
    params.set("COM_RC_IN_MODE", 4)
    assert decide(params) == Action.HOLD
    params.set("COM_RC_IN_MODE", 0)
    assert decide(params) == Action.RETURN


def test_the_offboard_exemption_holds_and_other_bits_do_not(params: Params) -> None:
    params.set("COM_RCL_EXCEPT", 1 | 2)  # Mission, Hold: not Offboard
    assert decide(params) == Action.RETURN
    params.set("COM_RCL_EXCEPT", 4)
    assert decide(params) == Action.HOLD
    assert decide(params, mode=FlightMode.HOLD) == Action.RETURN  # bit 2 exempts Offboard only
    params.set("COM_RCL_EXCEPT", 2)
    assert decide(params, mode=FlightMode.HOLD) == Action.HOLD


def test_datalink_loss_takes_nav_dll_act_unless_disabled(params: Params) -> None:
    assert datalink_loss_action(params.__getitem__).action == Action.NONE  # PX4 default 0
    for dll, action in ((1, Action.HOLD), (2, Action.RETURN), (3, Action.LAND), (6, Action.DISARM)):
        params.set("NAV_DLL_ACT", dll)
        assert datalink_loss_action(params.__getitem__).action == action


W = BatteryWarning


@pytest.mark.parametrize(
    ("remaining", "warning"),
    [(1.0, W.NONE), (0.15, W.NONE), (0.1499, W.LOW), (0.07, W.LOW), (0.0699, W.CRITICAL), (0.05, W.CRITICAL)]
    + [(0.0499, W.EMERGENCY), (0.0, W.EMERGENCY)],
)
def test_battery_warning_levels_are_strictly_below_each_threshold(
    params: Params, remaining: float, warning: BatteryWarning
) -> None:
    assert battery_warning(params.__getitem__, remaining) == warning


@pytest.mark.parametrize(
    ("act", "critical", "emergency"),
    [
        (0, Action.NONE, Action.NONE),  # PX4's default: warnings only
        (1, Action.RETURN, Action.RETURN),  # deprecated Return
        (2, Action.LAND, Action.LAND),
        (3, Action.RETURN, Action.LAND),  # Return at critical, Land at emergency
        (9, Action.NONE, Action.NONE),  # unknown: a warning (fromBatteryWarningActParam has no case for it)
    ],
)
def test_com_low_bat_act_at_critical_and_emergency(params: Params, act: int, critical: Action, emergency: Action):
    params.set("COM_LOW_BAT_ACT", act)
    assert low_battery_action(params.__getitem__, W.CRITICAL).action == critical
    assert low_battery_action(params.__getitem__, W.EMERGENCY).action == emergency
    decision = low_battery_action(params.__getitem__, W.CRITICAL)
    assert decision.param == "COM_LOW_BAT_ACT" and decision.reason == f"COM_LOW_BAT_ACT={act}"


def test_a_low_battery_only_warns(params: Params) -> None:
    for act in (0, 1, 2, 3):
        params.set("COM_LOW_BAT_ACT", act)
        assert low_battery_action(params.__getitem__, W.LOW).action == Action.NONE
        assert low_battery_action(params.__getitem__, W.NONE).action == Action.NONE


def test_the_battery_action_is_only_for_a_warning_worse_than_at_arming(params: Params) -> None:
    params.set("COM_LOW_BAT_ACT", 3)
    assert low_battery_action(params.__getitem__, W.CRITICAL, at_arming=W.LOW).action == Action.RETURN
    assert low_battery_action(params.__getitem__, W.CRITICAL, at_arming=W.CRITICAL).action == Action.NONE
    assert low_battery_action(params.__getitem__, W.EMERGENCY, at_arming=W.CRITICAL).action == Action.LAND


def test_arming_is_refused_from_the_critical_threshold_by_default(params: Params) -> None:
    assert battery_arming_refusal(params.__getitem__, 0.10) is None  # low: reported, not refused
    assert battery_arming_refusal(params.__getitem__, 0.07) is None
    refusal = battery_arming_refusal(params.__getitem__, 0.069)
    assert refusal is not None and refusal.param == "BAT_CRIT_THR"
    assert refusal.reason == "critical battery, 6.9% below BAT_CRIT_THR 7.0%"
    emergency = battery_arming_refusal(params.__getitem__, 0.02)
    assert emergency is not None and emergency.param == "BAT_EMERGEN_THR"


def test_a_set_com_arm_bat_min_is_the_arming_threshold_instead(params: Params) -> None:
    params.set("COM_ARM_BAT_MIN", 0.3)
    refusal = battery_arming_refusal(params.__getitem__, 0.25)
    assert refusal is not None and refusal.param == "COM_ARM_BAT_MIN"
    assert battery_arming_refusal(params.__getitem__, 0.3) is None
    params.set("COM_ARM_BAT_MIN", 0.0)  # 0 and up: this threshold only, a critical battery alone arms
    assert battery_arming_refusal(params.__getitem__, 0.06) is None
