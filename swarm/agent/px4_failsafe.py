"""PX4's failsafe decisions, as pure functions: parameters and state in, action out. One model of PX4's rules
serves both sides: the simulated vehicle takes these actions (swarm/sim/autopilot.py), and the agent refuses to
fly where its own death would be a Return (swarm/agent/px4_params.py), so the two can never disagree.

Sources (PX4-Autopilot): `src/modules/commander/commander_params.c` (COM_OBL_RC_ACT, NAV_RCL_ACT, NAV_DLL_ACT,
COM_RCL_EXCEPT, COM_RC_IN_MODE, COM_DL_LOSS_T; in current PX4 `commander_params.yaml`, also COM_LOW_BAT_ACT and
COM_ARM_BAT_MIN) and `src/modules/commander/failsafe/failsafe.cpp` (`fromOffboardLossActParam`,
`fromNavDllOrRclActParam`, `fromBatteryWarningActParam`, the RC-loss exceptions), `src/lib/battery/`
(`battery_params_common.c`: BAT_LOW_THR, BAT_CRIT_THR, BAT_EMERGEN_THR; `Battery::determineWarning`),
`src/modules/commander/HealthAndArmingChecks/checks/batteryCheck.cpp` (arming), and the failsafe pages of the
PX4 user guide (`docs/en/config/safety.md`).

Offboard loss:
1. COM_OBL_RC_ACT names the action: 3 Return, 4 Land, 5 Hold, 6 Terminate, 7 Disarm are taken as they are.
2. 0 Position, 1 Altitude and 2 Manual (Stabilized) are modes flown with the sticks. With an RC the vehicle
   flies that mode (sticks centred: it holds). Without one, PX4 since PR #26289 (backported in #26391) applies
   the RC-loss failsafe NAV_RCL_ACT instead: 1 Hold, 2 Return (the default), 3 Land, 5 Terminate, 6 Disarm.
3. The RC-loss failsafe is not taken when COM_RC_IN_MODE = 4 (stick input disabled: PX4 never declares RC loss)
   or when COM_RCL_EXCEPT exempts the current mode (bit 0 Mission, bit 1 Hold / auto modes, bit 2 Offboard), nor
   when NAV_RCL_ACT is 0 (disabled in older PX4). Our reading of what PX4 flies then: the stick mode cannot run
   without sticks, and PX4's failsafe framework falls back from it (Position -> Altitude -> Stabilized -> Hold)
   to the first mode that can run, which for a vehicle with a position estimate is Hold.

Data-link loss: no GCS HEARTBEAT for COM_DL_LOSS_T seconds triggers NAV_DLL_ACT (0 disabled, the default).

Battery: the remaining fraction below BAT_LOW_THR (0.15) is a low warning, below BAT_CRIT_THR (0.07) critical,
below BAT_EMERGEN_THR (0.05) emergency (strictly below; while armed the warning only rises). Low only warns.
At critical and emergency COM_LOW_BAT_ACT acts: 0 warning only (the default), 2 Land, 3 Return at critical and
Land at emergency, 1 (deprecated, still honoured) Return at both; other values warn. The action is taken only for
a warning worse than the one at arming (a vehicle armed with a low battery is not sent home for it). Arming is
refused at critical or worse while COM_ARM_BAT_MIN is negative (the default, -1: "BAT_CRIT_THR is the
threshold"); when it is 0 or more, arming is refused below it instead, and a critical warning alone does not.

Modes without a global position (an indoor vehicle with no GPS and no global origin set): a multicopter's Hold
(AUTO_LOITER) and Return (AUTO_RTL) need one, Takeoff, Land and Offboard do not
(`src/modules/commander/ModeUtil/mode_requirements.cpp`). A failsafe action whose mode cannot run falls back
along Hold -> Return -> Land -> Descend (`FailsafeBase::getSelectedAction` in `failsafe/framework.cpp`), so
without a global position both Hold and Return become Land.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum, IntEnum


class Action(Enum):
    NONE = "none"
    HOLD = "Hold"
    RETURN = "Return"
    LAND = "Land"
    TERMINATE = "Terminate"
    DISARM = "Disarm"


@dataclass(frozen=True)
class Decision:
    action: Action
    param: str  # the parameter whose value decided it
    reason: str  # why this action, for the STATUSTEXT


# COM_OBL_RC_ACT values (commander_params.c)
OBL_POSITION, OBL_ALTITUDE, OBL_MANUAL = 0, 1, 2
_OBL_ACTIONS = {3: Action.RETURN, 4: Action.LAND, 5: Action.HOLD, 6: Action.TERMINATE, 7: Action.DISARM}
_OBL_NAMES = {OBL_POSITION: "Position", OBL_ALTITUDE: "Altitude", OBL_MANUAL: "Manual"}
# NAV_RCL_ACT and NAV_DLL_ACT values (commander_params.c); 0 is "disabled"
_LINK_ACTIONS = {1: Action.HOLD, 2: Action.RETURN, 3: Action.LAND, 5: Action.TERMINATE, 6: Action.DISARM}
RC_IN_MODE_DISABLED = 4  # COM_RC_IN_MODE: stick input disabled, no RC checks
RCL_EXCEPT_MISSION, RCL_EXCEPT_HOLD, RCL_EXCEPT_OFFBOARD = 1, 2, 4  # COM_RCL_EXCEPT bits 0, 1, 2

ParamReader = Callable[[str], float]
AUTO_MODES = ("HOLD", "TAKEOFF", "LAND", "RTL")  # PX4 flight mode names, as the simulator's FlightMode spells them


def rc_loss_exempt(param: ParamReader, mode: str) -> bool:
    """Whether COM_RCL_EXCEPT exempts `mode` (a PX4 flight mode name: OFFBOARD, HOLD, ...) from RC-loss failsafe."""
    bits = int(param("COM_RCL_EXCEPT"))
    if mode == "OFFBOARD":
        return bool(bits & RCL_EXCEPT_OFFBOARD)
    if mode in AUTO_MODES:
        return bool(bits & RCL_EXCEPT_HOLD)  # "Auto modes" in current PX4, "Hold" in older releases
    return False


def offboard_loss_action(param: ParamReader, mode: str, rc_present: bool) -> Decision:
    """What PX4 does when offboard setpoints stop for COM_OF_LOSS_T while in `mode` (OFFBOARD in practice)."""
    obl = int(param("COM_OBL_RC_ACT"))
    if obl in _OBL_ACTIONS:
        return Decision(_OBL_ACTIONS[obl], "COM_OBL_RC_ACT", f"COM_OBL_RC_ACT={obl}")
    stick_mode = _OBL_NAMES.get(obl, f"unknown COM_OBL_RC_ACT={obl}, Position")
    if rc_present:
        return Decision(Action.HOLD, "COM_OBL_RC_ACT", f"COM_OBL_RC_ACT={obl} ({stick_mode} mode, sticks centred)")
    if int(param("COM_RC_IN_MODE")) == RC_IN_MODE_DISABLED:
        reason = f"{stick_mode} mode needs sticks, COM_RC_IN_MODE=4: fall back to Hold"
        return Decision(Action.HOLD, "COM_RC_IN_MODE", reason)
    if rc_loss_exempt(param, mode):
        reason = f"{stick_mode} mode needs sticks, COM_RCL_EXCEPT exempts {mode}: Hold"
        return Decision(Action.HOLD, "COM_RCL_EXCEPT", reason)
    rcl = int(param("NAV_RCL_ACT"))
    action = _LINK_ACTIONS.get(rcl)
    if action is None:
        reason = f"{stick_mode} mode needs sticks, no RC, NAV_RCL_ACT={rcl} disabled: Hold"
        return Decision(Action.HOLD, "NAV_RCL_ACT", reason)
    return Decision(action, "NAV_RCL_ACT", f"{stick_mode} mode needs sticks, no RC: NAV_RCL_ACT={rcl}")


def datalink_loss_action(param: ParamReader) -> Decision:
    """What PX4 does when the GCS heartbeat has been missing for COM_DL_LOSS_T (NONE: NAV_DLL_ACT disabled)."""
    dll = int(param("NAV_DLL_ACT"))
    return Decision(_LINK_ACTIONS.get(dll, Action.NONE), "NAV_DLL_ACT", f"NAV_DLL_ACT={dll}")


class BatteryWarning(IntEnum):
    """PX4's battery warning levels (`battery_status.msg` WARNING_*), ordered by severity."""

    NONE = 0
    LOW = 1
    CRITICAL = 2
    EMERGENCY = 3

    @property
    def label(self) -> str:
        return self.name.lower()


# COM_LOW_BAT_ACT values (failsafe.h LowBatteryAction): what each does at critical, and at emergency
_LOW_BAT_ACTIONS = {
    1: (Action.RETURN, Action.RETURN),  # Return (deprecated, absent from the parameter's current values)
    2: (Action.LAND, Action.LAND),
    3: (Action.RETURN, Action.LAND),  # Return at critical, Land at emergency
}
# What PX4 says when a level is reached and the action is a warning (its events, failsafe/framework.cpp)
BATTERY_WARNING_TEXT = {
    BatteryWarning.LOW: "Low battery level, return advised",
    BatteryWarning.CRITICAL: "Critical battery level, land now",
    BatteryWarning.EMERGENCY: "Emergency battery level, land immediately",
}


def battery_warning(param: ParamReader, remaining: float) -> BatteryWarning:
    """The warning level of a battery with `remaining` (0..1) charge (Battery::determineWarning)."""
    if remaining < param("BAT_EMERGEN_THR"):
        return BatteryWarning.EMERGENCY
    if remaining < param("BAT_CRIT_THR"):
        return BatteryWarning.CRITICAL
    if remaining < param("BAT_LOW_THR"):
        return BatteryWarning.LOW
    return BatteryWarning.NONE


def low_battery_action(
    param: ParamReader, warning: BatteryWarning, at_arming: BatteryWarning = BatteryWarning.NONE
) -> Decision:
    """What PX4 does on reaching `warning` in flight (NONE: a warning only), having armed at `at_arming`."""
    act = int(param("COM_LOW_BAT_ACT"))
    if warning < BatteryWarning.CRITICAL:
        return Decision(Action.NONE, "BAT_LOW_THR", f"{warning.label} battery: a warning only")
    if warning <= at_arming:
        return Decision(Action.NONE, "COM_LOW_BAT_ACT", f"{warning.label} battery since arming: a warning only")
    critical, emergency = _LOW_BAT_ACTIONS.get(act, (Action.NONE, Action.NONE))
    action = critical if warning == BatteryWarning.CRITICAL else emergency
    return Decision(action, "COM_LOW_BAT_ACT", f"COM_LOW_BAT_ACT={act}")


@dataclass(frozen=True)
class Refusal:
    param: str  # the parameter whose value decided it
    reason: str  # for the STATUSTEXT


def battery_arming_refusal(param: ParamReader, remaining: float) -> Refusal | None:
    """Why PX4 refuses to arm with `remaining` (0..1) charge, or None when the battery allows arming."""
    arm_min = param("COM_ARM_BAT_MIN")
    if arm_min >= 0:
        if remaining < arm_min:
            return Refusal("COM_ARM_BAT_MIN", f"battery {remaining:.1%} below COM_ARM_BAT_MIN {arm_min:.1%}")
        return None
    warning = battery_warning(param, remaining)
    if warning < BatteryWarning.CRITICAL:
        return None  # a low battery is reported, not refused
    threshold = "BAT_EMERGEN_THR" if warning == BatteryWarning.EMERGENCY else "BAT_CRIT_THR"
    return Refusal(threshold, f"{warning.label} battery, {remaining:.1%} below {threshold} {param(threshold):.1%}")


NEEDS_GLOBAL_POSITION = ("HOLD", "RTL")  # PX4 flight mode names (mode_requirements.cpp, multicopter)


def mode_can_run(mode: str, global_position: bool) -> bool:
    """Whether PX4 can fly `mode` (a flight mode name) with or without a global position estimate."""
    return global_position or mode not in NEEDS_GLOBAL_POSITION


def action_that_can_run(action: Action, global_position: bool) -> Action:
    """A failsafe action after PX4's fallback (framework.cpp): Hold and Return become Land without a global
    position; the others are taken as they are."""
    if action in (Action.HOLD, Action.RETURN) and not global_position:
        return Action.LAND
    return action
