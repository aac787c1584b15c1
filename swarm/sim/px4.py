"""What makes the simulated autopilot look like PX4 on the wire: flight modes, landed states and parameters."""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import Enum, IntEnum

from pymavlink.dialects.v20 import common as mavlink

from swarm.config import SimSettings

# PX4 main modes (px4_custom_mode.h) and the AUTO sub modes
MAIN_MANUAL, MAIN_POSCTL, MAIN_AUTO, MAIN_OFFBOARD = 1, 3, 4, 6
SUB_TAKEOFF, SUB_LOITER, SUB_MISSION, SUB_RTL, SUB_LAND = 2, 3, 4, 5, 6


class FlightMode(Enum):
    """The PX4 modes the simulator flies; value = (main mode, sub mode)."""

    MANUAL = (MAIN_MANUAL, 0)
    POSCTL = (MAIN_POSCTL, 0)
    HOLD = (MAIN_AUTO, SUB_LOITER)
    TAKEOFF = (MAIN_AUTO, SUB_TAKEOFF)
    LAND = (MAIN_AUTO, SUB_LAND)
    RTL = (MAIN_AUTO, SUB_RTL)
    OFFBOARD = (MAIN_OFFBOARD, 0)

    @property
    def custom_mode(self) -> int:
        main, sub = self.value
        return (main << 16) | (sub << 24)

    @classmethod
    def from_px4(cls, main: int, sub: int) -> FlightMode | None:
        """The mode a DO_SET_MODE asks for, or None when the simulator does not fly it (e.g. MISSION)."""
        if main != MAIN_AUTO:
            sub = 0
        for mode in cls:
            if mode.value == (main, sub):
                return mode
        return None


class LandedState(IntEnum):
    """MAV_LANDED_STATE values."""

    ON_GROUND = mavlink.MAV_LANDED_STATE_ON_GROUND
    IN_AIR = mavlink.MAV_LANDED_STATE_IN_AIR
    TAKEOFF = mavlink.MAV_LANDED_STATE_TAKEOFF
    LANDING = mavlink.MAV_LANDED_STATE_LANDING

    @property
    def label(self) -> str:
        return self.name.lower()


REAL32 = mavlink.MAV_PARAM_TYPE_REAL32
INT32 = mavlink.MAV_PARAM_TYPE_INT32


@dataclass
class Param:
    value: float
    type: int = REAL32


class Params:
    """The PX4 parameters the simulator honours (read live, so a PARAM_SET changes its behaviour)."""

    def __init__(self, sim: SimSettings, sysid: int) -> None:
        self._table: dict[str, Param] = {
            "MIS_TAKEOFF_ALT": Param(sim.takeoff_alt_m),
            "MPC_XY_VEL_MAX": Param(sim.max_speed_xy_m_s),
            "MPC_XY_CRUISE": Param(sim.max_speed_xy_m_s),
            "MPC_Z_VEL_MAX_UP": Param(sim.max_speed_up_m_s),
            "MPC_Z_VEL_MAX_DN": Param(sim.max_speed_down_m_s),
            "MPC_ACC_HOR": Param(sim.max_accel_m_s2),
            # The position and velocity loops (src/modules/mc_pos_control/multicopter_position_control_params.c;
            # what they do: swarm/sim/kinematics.py)
            "MPC_XY_P": Param(sim.position_gain_xy),
            "MPC_Z_P": Param(sim.position_gain_z),
            "MPC_XY_VEL_P_ACC": Param(sim.velocity_gain_xy),
            "MPC_Z_VEL_P_ACC": Param(sim.velocity_gain_z),
            "MPC_LAND_SPEED": Param(sim.land_speed_m_s),
            "MPC_YAWRAUTO_MAX": Param(90.0),
            # Failsafe parameters with PX4's defaults (src/modules/commander/commander_params.c,
            # src/modules/navigator/rtl_params.c); what the simulator does with them: swarm/agent/px4_failsafe.py
            "RTL_RETURN_ALT": Param(60.0),
            "COM_OF_LOSS_T": Param(sim.offboard_timeout_s),
            "COM_OBL_RC_ACT": Param(0, INT32),  # offboard loss: 0 Position mode
            "NAV_RCL_ACT": Param(2, INT32),  # RC loss: 2 Return
            "NAV_DLL_ACT": Param(0, INT32),  # data-link (GCS heartbeat) loss: 0 disabled
            "COM_DL_LOSS_T": Param(10, INT32),  # s
            "COM_RC_IN_MODE": Param(3, INT32),  # 3 RC or joystick, first kept; 4 stick input disabled
            "COM_RCL_EXCEPT": Param(0, INT32),  # RC-loss exemptions: bit 0 Mission, 1 Hold/auto, 2 Offboard
            # Battery (src/lib/battery/battery_params_common.c; commander_params.yaml): what the simulator does
            # with them is swarm/agent/px4_failsafe.py; the battery itself is swarm/sim/battery.py
            "BAT_LOW_THR": Param(0.15),
            "BAT_CRIT_THR": Param(0.07),
            "BAT_EMERGEN_THR": Param(0.05),
            "COM_LOW_BAT_ACT": Param(0, INT32),  # 0 warning, 2 Land, 3 Return at critical / Land at emergency
            "COM_ARM_BAT_MIN": Param(-1.0),  # negative: arming refused at BAT_CRIT_THR
            "COM_DISARM_LAND": Param(2.0),
            # The multicopter land detector (src/modules/land_detector/land_detector_params_mc.c): ground contact,
            # maybe landed and landed each hold for LNDMC_TRIG_TIME / 3 while the vehicle does not move faster than
            # these (MulticopterLandDetector.cpp, _set_hysteresis_factor)
            # The failure detector (src/modules/commander/failure_detector/failure_detector_params.c): roll or
            # pitch beyond these (degrees) is an attitude failure, and arming is refused while it lasts
            # (HealthAndArmingChecks/checks/failureDetectorCheck.cpp, "Preflight Fail: Attitude failure (roll)")
            "FD_FAIL_R": Param(60, INT32),
            "FD_FAIL_P": Param(60, INT32),
            "LNDMC_TRIG_TIME": Param(1.0),
            "LNDMC_Z_VEL_MAX": Param(0.25),
            "LNDMC_XY_VEL_MAX": Param(1.5),
            "COM_DISARM_PRFLT": Param(10.0),
            # Estimator aiding (src/modules/ekf2/module.yaml): GPS bits 0-2 (position, altitude, velocity), PX4's
            # default 7; external vision bits 0-3 (position, altitude, velocity, yaw), default 15, used when vision
            # data arrives. Read at boot, as PX4 applies them after a reboot: sim.gps = false boots with GPS off.
            "EKF2_GPS_CTRL": Param(7 if sim.gps else 0, INT32),
            "EKF2_EV_CTRL": Param(15, INT32),
            "MAV_SYS_ID": Param(sysid, INT32),
            "MAV_TYPE": Param(mavlink.MAV_TYPE_QUADROTOR, INT32),
            "SYS_AUTOSTART": Param(4001, INT32),  # PX4's SITL quadrotor airframe
        }
        self._names = list(self._table)
        self.version = 0  # bumped on every change, so readers can cache what they derive

    def __getitem__(self, name: str) -> float:
        return self._table[name].value

    def __contains__(self, name: str) -> bool:
        return name in self._table

    def __len__(self) -> int:
        return len(self._table)

    def names(self) -> list[str]:
        return list(self._names)

    def index(self, name: str) -> int:
        return self._names.index(name)

    def get(self, name: str) -> Param:
        return self._table[name]

    def set(self, name: str, value: float) -> None:
        """Set a known parameter from its value (in-process callers; the wire goes through set_wire)."""
        param = self._table[name]
        param.value = int(value) if param.type == INT32 else float(value)
        self.version += 1

    def set_wire(self, name: str, wire_value: float) -> bool:
        """Set from a PARAM_SET value (ints travel bytewise in the float, as PX4 does); False if unknown."""
        param = self._table.get(name)
        if param is None:
            return False
        param.value = _from_wire(wire_value) if param.type == INT32 else float(wire_value)
        self.version += 1
        return True

    def wire_value(self, name: str) -> float:
        param = self._table[name]
        return _to_wire(int(param.value)) if param.type == INT32 else float(param.value)


def _to_wire(value: int) -> float:
    return struct.unpack("<f", struct.pack("<i", value))[0]


def _from_wire(value: float) -> int:
    return struct.unpack("<i", struct.pack("<f", value))[0]
