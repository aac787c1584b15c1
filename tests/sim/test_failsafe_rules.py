"""PX4's failsafe rules as the simulator decides them (swarm/agent/px4_failsafe.py): one test per rule, no sockets."""

import pytest

from swarm.agent.px4_failsafe import Action, datalink_loss_action, offboard_loss_action
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
    for name in ("COM_OBL_RC_ACT", "NAV_RCL_ACT", "NAV_DLL_ACT", "COM_DL_LOSS_T", "COM_RC_IN_MODE", "COM_RCL_EXCEPT"):
        assert p.get(name).type == 6, name  # MAV_PARAM_TYPE_INT32, as in PX4


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
