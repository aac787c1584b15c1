"""The PX4 parameters that decide what a vehicle does when its agent dies, a link is lost or its battery runs
low, and which values are safe indoors. Pure: values in, findings and writes out (the reading and writing is in
flight.py).

An agent that dies stops its offboard setpoints and its GCS heartbeats. What PX4 then does is
`swarm.agent.px4_failsafe` (the same rules the simulated vehicle follows): with PX4's defaults and no RC, an
offboard loss is a Return, which climbs to RTL_RETURN_ALT (60 m by default) before flying home: through the
ceiling indoors. The agent cannot tell whether an RC is connected, so it assumes none (the worst case: with one,
a stick mode holds with centred sticks). A critical battery with COM_LOW_BAT_ACT = 3 (or the deprecated 1) is a
Return too; the agent goes home before that (agent.battery_home_fraction), but a battery that sags faster than
expected would still reach it, so such a value is a finding, and 'set' writes Land (2).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from swarm.agent.px4_failsafe import (
    Action,
    BatteryWarning,
    datalink_loss_action,
    low_battery_action,
    offboard_loss_action,
)

INT_PARAMS = ("COM_OBL_RC_ACT", "NAV_RCL_ACT", "NAV_DLL_ACT", "COM_RCL_EXCEPT", "COM_RC_IN_MODE", "COM_LOW_BAT_ACT")
FLOAT_PARAMS = ("RTL_RETURN_ALT", "COM_OF_LOSS_T")

OBL_HOLD = 5  # COM_OBL_RC_ACT: Hold mode
LINK_HOLD = 1  # NAV_RCL_ACT / NAV_DLL_ACT: Hold mode
LOW_BAT_LAND = 2  # COM_LOW_BAT_ACT: Land mode
STICK_MODES = {0: "Position", 1: "Altitude", 2: "Manual"}
KNOWN_OBL = set(range(8))


@dataclass(frozen=True)
class Finding:
    """One parameter that would make an agent death climb or return."""

    param: str
    value: float
    reason: str


def unsafe(values: Mapping[str, float]) -> list[Finding]:
    """Every parameter whose value makes the vehicle Return (climbing to RTL_RETURN_ALT) when its agent dies, its
    GCS link is lost or its battery is critical."""
    climb = f"Return climbs to RTL_RETURN_ALT={values['RTL_RETURN_ALT']:g} m above home"
    loss = f"after COM_OF_LOSS_T={values['COM_OF_LOSS_T']:g} s without setpoints"
    found: list[Finding] = []
    obl = int(values["COM_OBL_RC_ACT"])
    offboard = offboard_loss_action(values.__getitem__, "OFFBOARD", rc_present=False)
    if obl not in KNOWN_OBL:
        found.append(Finding("COM_OBL_RC_ACT", obl, "unknown offboard loss action"))
    elif offboard.action == Action.RETURN and offboard.param == "COM_OBL_RC_ACT":
        found.append(Finding("COM_OBL_RC_ACT", obl, f"offboard loss action is Return {loss}: {climb}"))
    elif offboard.action == Action.RETURN:  # a stick mode without an RC: the RC-loss action decided
        rcl = int(values["NAV_RCL_ACT"])
        reason = (
            f"COM_OBL_RC_ACT={obl} ({STICK_MODES[obl]} mode) needs sticks; without an RC the RC-loss action "
            f"applies {loss}: NAV_RCL_ACT={rcl} is Return: {climb} (or set COM_RCL_EXCEPT bit 2, Offboard)"
        )
        found.append(Finding(offboard.param, rcl, reason))
    if datalink_loss_action(values.__getitem__).action == Action.RETURN:
        dll = int(values["NAV_DLL_ACT"])
        found.append(Finding("NAV_DLL_ACT", dll, f"data-link loss action is Return (no GCS heartbeat): {climb}"))
    if battery_returns(values):
        act = int(values["COM_LOW_BAT_ACT"])
        found.append(Finding("COM_LOW_BAT_ACT", act, f"low-battery action is Return at critical battery: {climb}"))
    return found


def battery_returns(values: Mapping[str, float]) -> bool:
    """COM_LOW_BAT_ACT makes a critical or emergency battery a Return."""
    levels = (BatteryWarning.CRITICAL, BatteryWarning.EMERGENCY)
    return any(low_battery_action(values.__getitem__, level).action == Action.RETURN for level in levels)


def safe_writes(values: Mapping[str, float]) -> dict[str, int]:
    """What 'set' writes: offboard loss and RC loss hold, a data-link loss that would Return holds too, and a
    low-battery action that would Return lands instead."""
    writes = {"COM_OBL_RC_ACT": OBL_HOLD, "NAV_RCL_ACT": LINK_HOLD}
    if datalink_loss_action(values.__getitem__).action == Action.RETURN:
        writes["NAV_DLL_ACT"] = LINK_HOLD  # disabled (0) and Land stay as they are
    if battery_returns(values):
        writes["COM_LOW_BAT_ACT"] = LOW_BAT_LAND  # a warning (0) and Land stay as they are
    return writes
