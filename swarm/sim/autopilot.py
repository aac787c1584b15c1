"""The flight logic of one simulated PX4 vehicle: arming, modes, setpoints, battery, failsafes, the landed state.

No MAVLink here (see vehicle.py): every command is a method that returns a MAV_RESULT. Positions are in the world
frame (x east, y north, z up); the vehicle never goes below its home height (its floor).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from swarm.agent.px4_failsafe import (
    BATTERY_WARNING_TEXT,
    Action,
    BatteryWarning,
    Decision,
    action_that_can_run,
    battery_arming_refusal,
    battery_warning,
    datalink_loss_action,
    low_battery_action,
    mode_can_run,
    offboard_loss_action,
)
from swarm.config import GeoOrigin, SimSettings, Vec3
from swarm.sim import kinematics
from swarm.sim.battery import Battery
from swarm.sim.kinematics import Body, Limits
from swarm.sim.px4 import FlightMode, LandedState, Params

ACCEPTED = mavlink.MAV_RESULT_ACCEPTED
DENIED = mavlink.MAV_RESULT_DENIED
REJECTED = mavlink.MAV_RESULT_TEMPORARILY_REJECTED  # what PX4 answers to a mode it cannot enter now

GROUND_EPS_M = 0.02  # this close to the home height counts as touching the ground
# PX4 enters OFFBOARD only while setpoints stream at >= 2 Hz (docs/en/flight_modes/offboard.md: "proof of life"
# at 2 Hz): a setpoint within the last 0.5 s
OFFBOARD_ENTRY_S = 0.5
ARRIVED_M = 0.1
_HOLD_MODES = (FlightMode.HOLD, FlightMode.POSCTL, FlightMode.MANUAL)
_WARNING_SEVERITY = {
    BatteryWarning.LOW: mavlink.MAV_SEVERITY_WARNING,
    BatteryWarning.CRITICAL: mavlink.MAV_SEVERITY_CRITICAL,
    BatteryWarning.EMERGENCY: mavlink.MAV_SEVERITY_EMERGENCY,
}


@dataclass
class Setpoint:
    """An offboard setpoint in the world frame; NaN axes are not controlled."""

    position: np.ndarray
    velocity: np.ndarray
    yaw: float | None = None  # NED rad
    yaw_rate: float | None = None  # rad/s


class RtlPhase(Enum):
    CLIMB = 1
    RETURN = 2
    DESCEND = 3


GROUND_REFRESH_M = 0.05  # the floor under the vehicle is looked up again after it moved this far


class SimulatedPx4:
    """PX4's flight logic for one simulated vehicle, as the simulator models it (the agent's side of the link is
    `swarm.agent.autopilot.Autopilot`, a MAVSDK client)."""

    def __init__(
        self,
        home: Vec3,
        params: Params,
        floor_below: Callable[[np.ndarray], float] | None = None,
        battery: Battery | None = None,
        local_origin: Vec3 | None = None,
        boot_time: float = 0.0,
        estimator_warmup_s: float = 0.0,
    ) -> None:
        """`floor_below(position)`: the z of the first surface under the vehicle (the world's floors: a vehicle
        landing on an upper storey touches its slab, as a real one would); None or NaN: the home height.
        `battery`: a full one of the default `sim.battery_minutes` when None. `local_origin`: the world point of
        the local NED frame's origin, where the estimator started (default: home). `estimator_warmup_s`: after
        `boot_time`, how long the estimator has no position estimate yet."""
        self.home = np.array(home, dtype=np.float64)  # where it was last armed (PX4 resets home at arming)
        self.local_origin = self.home.copy() if local_origin is None else np.array(local_origin, dtype=np.float64)
        self.gps = bool(int(params["EKF2_GPS_CTRL"]) & 1)  # GPS position fused (read at boot, as PX4 does)
        self.global_origin: GeoOrigin | None = None  # without GPS: set by SET_GPS_GLOBAL_ORIGIN
        self.now = boot_time  # the clock of the last step or command
        self.estimator_ready_at = boot_time + estimator_warmup_s
        self._floor_below = floor_below
        self._ground_at: np.ndarray | None = None  # where the floor under the vehicle was last looked up
        self._ground_z = float(self.home[2])
        self.params = params
        self.body = Body(self.home.copy())
        self.armed = False
        self.mode = FlightMode.HOLD
        self.landed_state = LandedState.ON_GROUND
        self.distance_m = 0.0
        self._hold_point = self.home.copy()
        self._hold_yaw: float | None = None
        self._auto_speed: float | None = None  # DO_CHANGE_SPEED / DO_REPOSITION override of MPC_XY_CRUISE
        self._takeoff_target = self.home.copy()
        self._land_xy = self.home[:2].copy()
        self._rtl_phase = RtlPhase.CLIMB
        self._rtl_z = self.home[2]
        self._setpoint: Setpoint | None = None
        self._setpoint_time = -math.inf
        self._ground_since: float | None = None
        self._flown_since_arm = False
        self._commanding_up = False
        self._touchdown_at: float | None = None  # since when an armed vehicle rests on the ground (land detector)
        # (roll, pitch) in rad the vehicle rests at on the ground: level, unless a test tips it over (a crash, a
        # slope); in flight the attitude follows the acceleration (swarm.sim.kinematics.tilt)
        self.rest_tilt = (0.0, 0.0)
        self._limits_key: tuple | None = None
        self._limits = self._make_limits(False)
        self.rc_present = False  # the simulated vehicles have no RC transmitter
        self._gcs_heartbeat_time: float | None = None
        self._datalink_lost = False
        self.battery = battery if battery is not None else Battery(SimSettings().battery_minutes)
        self._battery_at_arming = BatteryWarning.NONE
        self._battery_handled = BatteryWarning.NONE  # the worst warning announced (and acted on) since arming
        self.notices: list[tuple[int, str]] = []  # (MAV_SEVERITY, text) for STATUSTEXT, drained by the vehicle

    # --- state -------------------------------------------------------------------------------------------------

    @property
    def position(self) -> np.ndarray:
        return self.body.position

    @property
    def velocity(self) -> np.ndarray:
        return self.body.velocity

    @property
    def height(self) -> float:
        """Height above home (m)."""
        return float(self.body.position[2] - self.home[2])

    @property
    def ground_z(self) -> float:
        """z of the floor under the vehicle (the home height without a world)."""
        if self._floor_below is None:
            return float(self.home[2])
        p = self.body.position
        if self._ground_at is None or np.linalg.norm(p - self._ground_at) > GROUND_REFRESH_M:
            z = self._floor_below(p)
            self._ground_z = float(z) if math.isfinite(z) and z <= p[2] + GROUND_EPS_M else float(self.home[2])
            self._ground_at = p.copy()
        return self._ground_z

    @property
    def at_ground(self) -> bool:
        return float(self.body.position[2]) - self.ground_z <= GROUND_EPS_M

    @property
    def attitude(self) -> tuple[float, float]:
        """(roll, pitch) in rad: what the acceleration needs in flight, the resting attitude on the ground."""
        if self.landed_state == LandedState.ON_GROUND:
            return self.rest_tilt
        return kinematics.tilt(self.body)

    @property
    def airborne(self) -> bool:
        return self.landed_state != LandedState.ON_GROUND

    @property
    def battery_warning(self) -> BatteryWarning:
        return battery_warning(self.params.__getitem__, self.battery.remaining)

    @property
    def global_position(self) -> bool:
        """Whether the estimator has a global position: from GPS, or the local one placed by a set global origin."""
        return self.gps or self.global_origin is not None

    @property
    def position_valid(self) -> bool:
        """Whether the estimator has a local position yet (sim.estimator_warmup_s after boot)."""
        return self.now >= self.estimator_ready_at

    @property
    def armable(self) -> bool:
        """What the pre-arm check bit says: no reason to refuse arming."""
        return self.arming_refusal() is None

    def arming_refusal(self) -> str | None:
        """Why PX4 would refuse to arm now, in its words, or None. The checks the simulator can fail, in PX4's
        order of HealthAndArmingChecks: the position estimate (estimatorCheck.cpp: a multicopter arms in a mode
        that needs one only with one), the attitude (failureDetectorCheck.cpp: roll or pitch beyond FD_FAIL_R or
        FD_FAIL_P, a vehicle not standing level), an active data-link failsafe (rcAndDataLinkChecks.cpp: no ground
        station while NAV_DLL_ACT acts on its loss), the battery (batteryCheck.cpp)."""
        if not self.position_valid:
            return "no valid position estimate"
        roll, pitch = self.attitude
        if abs(roll) > math.radians(self.params["FD_FAIL_R"]):
            return "Attitude failure (roll)"
        if abs(pitch) > math.radians(self.params["FD_FAIL_P"]):
            return "Attitude failure (pitch)"
        if self._datalink_lost and int(self.params["NAV_DLL_ACT"]) != 0:
            return "no connection to the ground control station"
        refusal = battery_arming_refusal(self.params.__getitem__, self.battery.remaining)
        return None if refusal is None else refusal.reason

    def limits(self, offboard: bool = False) -> Limits:
        key = (offboard, self._auto_speed, self.params.version)
        if self._limits_key != key:
            self._limits, self._limits_key = self._make_limits(offboard), key
        return self._limits

    def _make_limits(self, offboard: bool) -> Limits:
        p = self.params
        max_xy = p["MPC_XY_VEL_MAX"]
        if not offboard:
            max_xy = min(max_xy, self._auto_speed or p["MPC_XY_CRUISE"])
        return Limits(
            max_xy=max_xy,
            max_up=p["MPC_Z_VEL_MAX_UP"],
            max_down=p["MPC_Z_VEL_MAX_DN"],
            max_accel=p["MPC_ACC_HOR"],
            gain_xy=p["MPC_XY_P"],
            gain_z=p["MPC_Z_P"],
            velocity_gain_xy=p["MPC_XY_VEL_P_ACC"],
            velocity_gain_z=p["MPC_Z_VEL_P_ACC"],
            max_yaw_rate=math.radians(p["MPC_YAWRAUTO_MAX"]),
        )

    # --- commands (each returns a MAV_RESULT) ------------------------------------------------------------------

    def arm(self, now: float, force: bool = False) -> int:
        self.now = now
        if self.armed:
            return ACCEPTED
        if not self.at_ground and not force:
            return DENIED
        refusal = None if force else self.arming_refusal()
        if refusal is not None:
            # PX4 reports the failed check and answers TEMPORARILY_REJECTED (Commander.cpp)
            self._notice(mavlink.MAV_SEVERITY_CRITICAL, f"Arming denied: {refusal}")
            return REJECTED
        self.armed = True
        self.home = self.body.position.copy()  # PX4 sets home where it arms (Commander: home on arming)
        self._ground_z = float(self.home[2])
        self._battery_at_arming = self.battery_warning
        self._battery_handled = BatteryWarning.NONE  # a low battery at arming is announced once armed, as PX4 does
        self._ground_since = now
        self._flown_since_arm = False
        self._hold_point = self.body.position.copy()
        self._update_landed_state()
        return ACCEPTED

    def disarm(self, force: bool = False) -> int:
        if not self.armed:
            return ACCEPTED
        if self.landed_state != LandedState.ON_GROUND and not force:
            return DENIED
        self._disarm()
        return ACCEPTED

    def takeoff(self, height: float | None = None) -> int:
        """Climb to `height` above home (MIS_TAKEOFF_ALT when None) over the current point, then hold."""
        if not self.armed:
            return DENIED
        height = self.params["MIS_TAKEOFF_ALT"] if height is None else height
        if not math.isfinite(height) or height <= GROUND_EPS_M:
            return DENIED
        self._takeoff_target = np.array([*self.position[:2], max(self.home[2] + height, self.position[2])])
        self._set_mode(FlightMode.TAKEOFF)
        return ACCEPTED

    def land(self) -> int:
        self._land_xy = self.position[:2].copy()
        self._set_mode(FlightMode.LAND)
        return ACCEPTED

    def return_to_launch(self) -> int:
        if not self._can_run(FlightMode.RTL):
            return REJECTED
        self._rtl_z = max(self.position[2], self.home[2] + self.params["RTL_RETURN_ALT"])
        self._rtl_phase = RtlPhase.DESCEND if self.at_ground else RtlPhase.CLIMB
        self._set_mode(FlightMode.RTL)
        return ACCEPTED

    def set_mode(self, mode: FlightMode, now: float) -> int:
        if mode == self.mode:
            return ACCEPTED
        if mode == FlightMode.OFFBOARD:
            if not self.position_valid:  # offboard needs a valid local position (docs/en/flight_modes/offboard.md)
                self._notice(mavlink.MAV_SEVERITY_CRITICAL, "Offboard refused: no valid position estimate")
                return REJECTED
            age = now - self._setpoint_time
            if age > OFFBOARD_ENTRY_S:
                # PX4 answers TEMPORARILY_REJECTED to a mode it cannot enter (Commander.cpp, DO_SET_MODE)
                why = "no setpoint yet" if math.isinf(age) else f"last setpoint {age:.1f} s ago"
                self._notice(mavlink.MAV_SEVERITY_CRITICAL, f"Offboard refused: setpoints must stream at 2 Hz, {why}")
                return REJECTED
            self._set_mode(mode)
            return ACCEPTED
        if mode == FlightMode.TAKEOFF:
            return self.takeoff() if self.armed else REJECTED
        if mode == FlightMode.LAND:
            return self.land()
        if mode == FlightMode.RTL:
            return self.return_to_launch()
        if not self._can_run(mode):
            return REJECTED
        self._enter_hold(mode)
        return ACCEPTED

    def reposition(self, target: np.ndarray, yaw: float | None, speed: float | None) -> int:
        """Fly to `target` (NaN axes: keep the current value) and hold there, in HOLD, as PX4's DO_REPOSITION."""
        if not self.armed or not self.airborne:
            return DENIED
        if not self._can_run(FlightMode.HOLD):
            return REJECTED
        self._enter_hold()
        self._hold_point = np.where(np.isnan(target), self.position, target)
        self._hold_yaw = yaw if yaw is not None and math.isfinite(yaw) else None
        if speed is not None and speed > 0:
            self._auto_speed = speed
        return ACCEPTED

    def change_speed(self, speed: float) -> int:
        """Horizontal speed in the auto modes; <= 0 restores the default (MPC_XY_CRUISE)."""
        self._auto_speed = speed if speed > 0 else None
        return ACCEPTED

    def set_setpoint(self, setpoint: Setpoint, now: float) -> None:
        self._setpoint = setpoint
        self._setpoint_time = now

    def gcs_heartbeat(self, now: float) -> None:
        """A ground station's HEARTBEAT arrived (MAVSDK sends one a second as a GCS): the data link is up."""
        self._gcs_heartbeat_time = now
        if self._datalink_lost:
            self._datalink_lost = False
            self._notice(mavlink.MAV_SEVERITY_INFO, "Data link regained")

    # --- physics -----------------------------------------------------------------------------------------------

    def step(self, dt: float, now: float) -> None:
        self.now = now
        before = self.body.position.copy()
        if self.mode == FlightMode.OFFBOARD and now - self._setpoint_time > self.params["COM_OF_LOSS_T"]:
            if self.armed:
                decision = offboard_loss_action(self.params.__getitem__, self.mode.name, self.rc_present)
                self._fail_safe(decision, "no offboard signal")
            else:
                self._enter_hold()  # on the ground, disarmed: nothing to fail safe, the mode just lapses
        self._check_datalink(now)
        self.battery.drain(dt, float(np.linalg.norm(self.body.velocity)), self.armed)
        self._check_battery()
        if self.armed:
            target_p, target_v, yaw, yaw_rate = self._guidance()
            limits = self.limits(offboard=self.mode == FlightMode.OFFBOARD)
            cmd = kinematics.velocity_command(self.body.position, target_p, target_v, limits)
            self._commanding_up = cmd[2] > 0.05
            kinematics.track(self.body, cmd, limits, dt, self.ground_z)
            kinematics.turn(self.body, yaw, yaw_rate, limits, dt)
        else:
            self._commanding_up = False
            kinematics.fall(self.body, dt, self.ground_z, self.params["MPC_ACC_HOR"])
            self.body.yaw_rate = 0.0
        self.distance_m += math.dist(self.body.position, before)
        self._progress()
        self._update_landed_state()
        self._auto_disarm(now)

    def _guidance(self) -> tuple[np.ndarray, np.ndarray, float | None, float | None]:
        """Position target, velocity target (NaN axes free) and yaw target/rate of the current mode."""
        zero = np.zeros(3)
        if self.mode == FlightMode.OFFBOARD and self._setpoint is not None:
            sp = self._setpoint
            return sp.position, sp.velocity, sp.yaw, sp.yaw_rate
        if self.mode == FlightMode.TAKEOFF:
            return self._takeoff_target, zero, None, None
        if self.mode == FlightMode.LAND or (self.mode == FlightMode.RTL and self._rtl_phase == RtlPhase.DESCEND):
            xy = self._land_xy if self.mode == FlightMode.LAND else self.home[:2]
            return (np.array([xy[0], xy[1], np.nan]), np.array([0.0, 0.0, -self.params["MPC_LAND_SPEED"]]), None, None)
        if self.mode == FlightMode.RTL:
            xy = self.position[:2] if self._rtl_phase == RtlPhase.CLIMB else self.home[:2]
            return np.array([xy[0], xy[1], self._rtl_z]), zero, None, None
        return self._hold_point, zero, self._hold_yaw, None

    def _progress(self) -> None:
        """Mode transitions that follow from where the vehicle got to."""
        p, v = self.body.position, self.body.velocity
        if self.mode == FlightMode.TAKEOFF:
            if abs(p[2] - self._takeoff_target[2]) < ARRIVED_M and abs(v[2]) < 0.3:
                if not self.global_position:  # Takeoff ends in Hold, which cannot run: PX4's fallback lands
                    self._notice(
                        mavlink.MAV_SEVERITY_CRITICAL, "Failsafe: Hold not possible without a global position, Land"
                    )
                    self.land()
                    return
                self._enter_hold()
                self._hold_point = self._takeoff_target.copy()
        elif self.mode == FlightMode.RTL:
            if self._rtl_phase == RtlPhase.CLIMB and abs(p[2] - self._rtl_z) < ARRIVED_M:
                self._rtl_phase = RtlPhase.RETURN
            elif self._rtl_phase == RtlPhase.RETURN and np.linalg.norm(p[:2] - self.home[:2]) < 0.2:
                self._rtl_phase = RtlPhase.DESCEND

    def _update_landed_state(self) -> None:
        """MAV_LANDED_STATE as PX4's land detector reports it. Armed, a vehicle that comes down is landed only
        once it has sat on the ground, not commanded up and barely moving (LNDMC_Z_VEL_MAX, LNDMC_XY_VEL_MAX), for
        LNDMC_TRIG_TIME: PX4's three stages (ground contact, maybe landed, landed) of LNDMC_TRIG_TIME / 3 each
        (MulticopterLandDetector.cpp). Until then it is landing (in Land, or Return's descent) or in the air. A
        vehicle that is landed stays so while it sits there, and a disarmed one on the ground is landed at once."""
        resting = self.at_ground and not self._commanding_up
        if resting and self.armed and self.landed_state != LandedState.ON_GROUND:
            v = self.body.velocity
            still = abs(float(v[2])) <= self.params["LNDMC_Z_VEL_MAX"]
            still = still and float(np.hypot(v[0], v[1])) <= self.params["LNDMC_XY_VEL_MAX"]
            if not still:
                self._touchdown_at = None
            elif self._touchdown_at is None:
                self._touchdown_at = self.now
        elif not resting:
            self._touchdown_at = None
        detected = self._touchdown_at is not None and self.now - self._touchdown_at >= self.params["LNDMC_TRIG_TIME"]
        if self.armed and self.mode == FlightMode.TAKEOFF:
            state = LandedState.TAKEOFF
        elif resting and (not self.armed or self.landed_state == LandedState.ON_GROUND or detected):
            state = LandedState.ON_GROUND
        elif self.mode == FlightMode.LAND or (self.mode == FlightMode.RTL and self._rtl_phase == RtlPhase.DESCEND):
            state = LandedState.LANDING
        else:
            state = LandedState.IN_AIR
        self.landed_state = state

    def _auto_disarm(self, now: float) -> None:
        """PX4's COM_DISARM_LAND after a landing and COM_DISARM_PRFLT when armed but never taking off."""
        if not self.armed:
            return
        if self.landed_state != LandedState.ON_GROUND:
            self._ground_since = None
            self._flown_since_arm = True
            return
        if self._ground_since is None:
            self._ground_since = now
        delay = self.params["COM_DISARM_LAND" if self._flown_since_arm else "COM_DISARM_PRFLT"]
        if delay > 0 and now - self._ground_since >= delay:
            self._disarm()

    # --- failsafes ---------------------------------------------------------------------------------------------

    def _check_datalink(self, now: float) -> None:
        """PX4's data-link loss: no GCS heartbeat for COM_DL_LOSS_T after one was heard; NAV_DLL_ACT, if set."""
        if self._gcs_heartbeat_time is None or self._datalink_lost:
            return
        if now - self._gcs_heartbeat_time <= self.params["COM_DL_LOSS_T"]:
            return
        self._datalink_lost = True
        decision = datalink_loss_action(self.params.__getitem__)
        if decision.action == Action.NONE or not (self.armed and self.airborne):
            self._notice(mavlink.MAV_SEVERITY_WARNING, f"Data link lost ({decision.reason}: no action)")
            return
        self._fail_safe(decision, "no connection to the ground station")

    def _check_battery(self) -> None:
        """PX4's battery failsafe while armed: each warning level once, as it is reached; in the air, at critical
        and emergency, COM_LOW_BAT_ACT's action (swarm.agent.px4_failsafe.low_battery_action)."""
        if not self.armed:
            return
        warning = self.battery_warning
        if warning <= self._battery_handled:
            return
        self._battery_handled = warning
        decision = low_battery_action(self.params.__getitem__, warning, self._battery_at_arming)
        if decision.action == Action.NONE or not self.airborne:  # on the ground: a warning only
            self._notice(_WARNING_SEVERITY[warning], f"{BATTERY_WARNING_TEXT[warning]} ({self.battery.remaining:.0%})")
            return
        self._fail_safe(decision, f"{warning.label} battery level")

    def _fail_safe(self, decision: Decision, cause: str) -> None:
        """Take a failsafe action and announce it, as PX4 does ("Failsafe activated: ..."); one whose mode cannot
        run without a global position falls back to Land (swarm.agent.px4_failsafe.action_that_can_run)."""
        action = action_that_can_run(decision.action, self.global_position)
        taken = action.value if action == decision.action else f"{action.value} ({decision.action.value} not possible)"
        self._notice(mavlink.MAV_SEVERITY_CRITICAL, f"Failsafe: {cause}, {taken} ({decision.reason})")
        if action == Action.HOLD:
            self._enter_hold()
        elif action == Action.RETURN:
            self.return_to_launch()
        elif action == Action.LAND:
            self.land()
        elif action in (Action.TERMINATE, Action.DISARM):
            self._enter_hold()  # out of OFFBOARD, so the loss is not taken again
            self._disarm()  # motors off: the vehicle falls

    def _notice(self, severity: int, text: str) -> None:
        self.notices.append((severity, text))

    # --- helpers -----------------------------------------------------------------------------------------------

    def _can_run(self, mode: FlightMode) -> bool:
        """PX4's mode requirements: a mode that needs a global position is refused without one, with its reason."""
        if mode_can_run(mode.name, self.global_position):
            return True
        self._notice(mavlink.MAV_SEVERITY_CRITICAL, f"Switching to {mode.name} is not possible: no global position")
        return False

    def _set_mode(self, mode: FlightMode) -> None:
        self.mode = mode
        self._update_landed_state()

    def _enter_hold(self, mode: FlightMode = FlightMode.HOLD) -> None:
        self._hold_point = self.body.position.copy()
        self._hold_yaw = None
        self._auto_speed = None
        self._set_mode(mode if mode in _HOLD_MODES else FlightMode.HOLD)

    def _disarm(self) -> None:
        self.armed = False
        self._ground_since = None
        self._commanding_up = False
        if self.mode in (FlightMode.TAKEOFF, FlightMode.LAND, FlightMode.RTL):
            self.mode = FlightMode.HOLD
        self._update_landed_state()
