"""Flight logic and kinematics of one simulated vehicle, stepped with a fake clock (no sockets)."""

import math
from collections.abc import Callable

import numpy as np
import pytest

from swarm.config import SimSettings
from swarm.sim.autopilot import ACCEPTED, REJECTED, Setpoint, SimulatedPx4
from swarm.sim.battery import Battery
from swarm.sim.px4 import FlightMode, LandedState, Params

DT = 0.02
HOME = (2.0, 3.0, 0.5)  # a raised floor: the ground clamp is at the home height, not at z = 0


class Clock:
    def __init__(self, ap: SimulatedPx4) -> None:
        self.ap = ap
        self.now = 100.0

    def run(self, seconds: float, each=None) -> None:
        for _ in range(round(seconds / DT)):
            self.now += DT
            self.ap.step(DT, self.now)
            if each is not None:
                each()

    def run_until(self, condition, timeout: float) -> float:
        started = self.now
        while not condition():
            assert self.now - started < timeout, "condition not reached in simulated time"
            self.now += DT
            self.ap.step(DT, self.now)
        return self.now - started


@pytest.fixture
def sim() -> SimSettings:
    return SimSettings()


@pytest.fixture
def ap(sim: SimSettings) -> SimulatedPx4:
    return SimulatedPx4(HOME, Params(sim, 1))


def offboard_to(ap: SimulatedPx4, clock: Clock, target: tuple[float, float, float]) -> None:
    ap.set_setpoint(Setpoint(np.array(target, dtype=float), np.full(3, np.nan)), clock.now)
    assert ap.set_mode(FlightMode.OFFBOARD, clock.now) == ACCEPTED


def keep_streaming(ap: SimulatedPx4, clock: Clock, target) -> Callable[[], None]:
    return lambda: ap.set_setpoint(Setpoint(np.array(target, dtype=float), np.full(3, np.nan)), clock.now)


def test_takeoff_climbs_to_the_takeoff_altitude_then_holds(ap: SimulatedPx4, sim: SimSettings) -> None:
    clock = Clock(ap)
    assert ap.takeoff() != ACCEPTED  # disarmed
    assert ap.arm(clock.now) == ACCEPTED and ap.armed
    assert ap.takeoff() == ACCEPTED
    assert ap.mode == FlightMode.TAKEOFF and ap.landed_state == LandedState.TAKEOFF
    clock.run_until(lambda: ap.mode == FlightMode.HOLD, timeout=10)
    assert ap.landed_state == LandedState.IN_AIR
    clock.run(2.0)
    assert ap.height == pytest.approx(sim.takeoff_alt_m, abs=0.05)
    assert np.allclose(ap.position[:2], HOME[:2])


def test_speed_and_acceleration_limits(ap: SimulatedPx4, sim: SimSettings) -> None:
    clock = Clock(ap)
    ap.arm(clock.now)
    far = (HOME[0] + 30.0, HOME[1] - 20.0, HOME[2] + 8.0)
    offboard_to(ap, clock, far)
    previous = ap.velocity.copy()
    worst = {"xy": 0.0, "up": 0.0, "down": 0.0, "accel": 0.0}

    def record() -> None:
        nonlocal previous
        v = ap.velocity
        worst["xy"] = max(worst["xy"], math.hypot(v[0], v[1]))
        worst["up"] = max(worst["up"], v[2])
        worst["down"] = max(worst["down"], -v[2])
        worst["accel"] = max(worst["accel"], float(np.linalg.norm(v - previous)) / DT)
        previous = v.copy()

    stream = keep_streaming(ap, clock, far)
    clock.run(8.0, each=lambda: (stream(), record()))
    down = (far[0], far[1], HOME[2] + 0.3)
    stream = keep_streaming(ap, clock, down)
    clock.run(8.0, each=lambda: (stream(), record()))
    assert worst["xy"] == pytest.approx(sim.max_speed_xy_m_s, abs=1e-6)  # reached, never exceeded
    assert worst["up"] == pytest.approx(sim.max_speed_up_m_s, abs=1e-6)
    assert worst["down"] == pytest.approx(sim.max_speed_down_m_s, abs=1e-6)
    assert worst["accel"] <= sim.max_accel_m_s2 + 1e-6


def test_reaches_an_offboard_target(ap: SimulatedPx4) -> None:
    clock = Clock(ap)
    ap.arm(clock.now)
    target = (HOME[0] + 4.0, HOME[1] + 2.0, HOME[2] + 1.5)
    offboard_to(ap, clock, target)
    stream = keep_streaming(ap, clock, target)
    clock.run(10.0, each=stream)
    assert np.linalg.norm(ap.position - target) < 0.05
    assert np.linalg.norm(ap.velocity) < 0.05
    assert ap.distance_m == pytest.approx(np.linalg.norm(np.subtract(target, HOME)), rel=0.15)  # overshoot


def hovering(ap: SimulatedPx4, clock: Clock, at: tuple[float, float, float]) -> None:
    ap.arm(clock.now)
    offboard_to(ap, clock, at)
    clock.run(10.0, each=keep_streaming(ap, clock, at))
    assert np.linalg.norm(ap.position - at) < 0.01 and np.linalg.norm(ap.velocity) < 0.01


def step_response(ap: SimulatedPx4, clock: Clock, target: tuple[float, float, float], axis: int) -> list[float]:
    trace: list[float] = []
    stream = keep_streaming(ap, clock, target)
    clock.run(10.0, each=lambda: (stream(), trace.append(float(ap.position[axis]))))
    return trace


@pytest.mark.parametrize("step_m", [0.5, 2.0])
def test_a_horizontal_position_step_overshoots_a_little_then_settles(ap: SimulatedPx4, step_m: float) -> None:
    """PX4's position and velocity loops with its defaults (MPC_XY_P 0.95, MPC_XY_VEL_P_ACC 1.8): damping 0.69,
    a few per cent of overshoot, as a real vehicle has; a point mass that stops dead would have none."""
    clock = Clock(ap)
    start = (HOME[0], HOME[1], HOME[2] + 1.5)
    hovering(ap, clock, start)
    target = (start[0] + step_m, start[1], start[2])
    trace = step_response(ap, clock, target, axis=0)
    overshoot = max(trace) - target[0]
    assert 0.01 * step_m < overshoot < 0.12 * step_m
    assert abs(trace[-1] - target[0]) < 0.01


def test_altitude_never_overshoots(ap: SimulatedPx4) -> None:
    """The vertical loops (MPC_Z_P 1.0, MPC_Z_VEL_P_ACC 4.0) are critically damped: a climb stops at its height."""
    clock = Clock(ap)
    start = (HOME[0], HOME[1], HOME[2] + 1.0)
    hovering(ap, clock, start)
    target = (start[0], start[1], start[2] + 1.0)
    trace = step_response(ap, clock, target, axis=2)
    assert max(trace) <= target[2] + 1e-3
    assert abs(trace[-1] - target[2]) < 0.01


def test_the_loop_gains_are_parameters_read_live(ap: SimulatedPx4) -> None:
    """A stiffer velocity loop (MPC_XY_VEL_P_ACC set as a ground station would) damps the same step more."""
    clock = Clock(ap)
    start = (HOME[0], HOME[1], HOME[2] + 1.5)
    hovering(ap, clock, start)
    default = max(step_response(ap, clock, (start[0] + 2.0, start[1], start[2]), axis=0)) - (start[0] + 2.0)
    ap.params.set("MPC_XY_VEL_P_ACC", 6.0)
    back = step_response(ap, clock, start, axis=0)
    assert min(back) > start[0] - 1e-3  # coming back, the stiff loop (damping 1.26) does not pass the start
    assert default > 0.02


def test_the_vehicle_tilts_into_its_acceleration(ap: SimulatedPx4) -> None:
    """Accelerating north pitches the nose down (FRD, yaw 0 = north), east rolls right, at atan(a / g)."""
    clock = Clock(ap)
    start = (HOME[0], HOME[1], HOME[2] + 1.5)
    hovering(ap, clock, start)
    north = (start[0], start[1] + 3.0, start[2])
    ap.set_setpoint(Setpoint(np.array(north), np.full(3, np.nan), yaw=0.0), clock.now)
    clock.run(0.1)
    roll, pitch = ap.attitude
    a_north = float(ap.body.acceleration[1])
    assert a_north > 1.0
    assert pitch == pytest.approx(-math.atan2(a_north, 9.81), abs=1e-6) and abs(roll) < 1e-3


def test_never_below_the_home_floor(ap: SimulatedPx4) -> None:
    clock = Clock(ap)
    ap.arm(clock.now)
    below = (HOME[0] + 1.0, HOME[1], HOME[2] - 5.0)
    offboard_to(ap, clock, below)
    stream = keep_streaming(ap, clock, below)
    lowest = []
    clock.run(3.0, each=lambda: (stream(), lowest.append(ap.position[2])))
    assert min(lowest) >= HOME[2]


def test_disarmed_in_air_falls_to_the_floor(ap: SimulatedPx4) -> None:
    clock = Clock(ap)
    ap.arm(clock.now)
    ap.takeoff()
    clock.run_until(lambda: ap.mode == FlightMode.HOLD, timeout=10)
    assert ap.disarm() != ACCEPTED  # in the air without force
    assert ap.disarm(force=True) == ACCEPTED
    clock.run(2.0)
    assert ap.position[2] == HOME[2] and ap.landed_state == LandedState.ON_GROUND


def test_landing_disarms_com_disarm_land_after_touchdown(ap: SimulatedPx4, sim: SimSettings) -> None:
    clock = Clock(ap)
    ap.arm(clock.now)
    ap.takeoff()
    clock.run_until(lambda: ap.mode == FlightMode.HOLD, timeout=10)
    assert ap.land() == ACCEPTED and ap.landed_state == LandedState.LANDING
    descent = []
    while ap.landed_state != LandedState.ON_GROUND:
        assert len(descent) < 10 / DT
        clock.now += DT
        ap.step(DT, clock.now)
        descent.append(-ap.velocity[2])
    assert max(descent) == pytest.approx(sim.land_speed_m_s, abs=1e-3)  # approached by the velocity loop
    assert ap.armed
    waited = clock.run_until(lambda: not ap.armed, timeout=5)
    assert waited == pytest.approx(2.0, abs=2 * DT)  # PX4's default COM_DISARM_LAND
    assert ap.mode == FlightMode.HOLD and ap.position[2] == HOME[2]


@pytest.mark.parametrize("trig_time", [1.0, 3.0])
def test_a_landing_is_detected_lndmc_trig_time_after_touchdown(ap: SimulatedPx4, trig_time: float) -> None:
    """PX4's land detector: ground contact, maybe landed, landed, LNDMC_TRIG_TIME / 3 each; until then the
    vehicle on the floor still says landing (and so does not disarm)."""
    ap.params.set("LNDMC_TRIG_TIME", trig_time)
    clock = Clock(ap)
    ap.arm(clock.now)
    ap.takeoff()
    clock.run_until(lambda: ap.mode == FlightMode.HOLD, timeout=10)
    assert ap.land() == ACCEPTED
    clock.run_until(lambda: ap.at_ground and abs(ap.velocity[2]) < 0.01, timeout=10)  # touchdown
    assert ap.landed_state == LandedState.LANDING and ap.airborne
    detected = clock.run_until(lambda: ap.landed_state == LandedState.ON_GROUND, timeout=10)
    assert detected == pytest.approx(trig_time, abs=2 * DT)
    assert ap.armed  # COM_DISARM_LAND counts from the detection
    assert clock.run_until(lambda: not ap.armed, timeout=5) == pytest.approx(2.0, abs=2 * DT)


def test_armed_without_taking_off_disarms_after_the_preflight_delay(ap: SimulatedPx4) -> None:
    clock = Clock(ap)
    ap.arm(clock.now)
    waited = clock.run_until(lambda: not ap.armed, timeout=15)
    assert waited == pytest.approx(10.0, abs=2 * DT)


def test_offboard_needs_a_setpoint_stream_of_2_hz(ap: SimulatedPx4) -> None:
    clock = Clock(ap)
    assert ap.set_mode(FlightMode.OFFBOARD, clock.now) == REJECTED
    assert "no setpoint yet" in ap.notices[-1][1]
    ap.set_setpoint(Setpoint(np.array(HOME), np.full(3, np.nan)), clock.now)
    clock.run(0.6)
    assert ap.set_mode(FlightMode.OFFBOARD, clock.now) == REJECTED  # older than 0.5 s: below 2 Hz
    assert "Offboard refused" in ap.notices[-1][1] and "0.6 s ago" in ap.notices[-1][1]
    ap.set_setpoint(Setpoint(np.array(HOME), np.full(3, np.nan)), clock.now)
    clock.run(0.4)
    assert ap.set_mode(FlightMode.OFFBOARD, clock.now) == ACCEPTED


def fly_offboard_then_stop(ap: SimulatedPx4, clock: Clock, target: tuple[float, float, float]) -> float:
    """Arm, fly offboard towards target for 2 s, stop the setpoints; the seconds until the vehicle left OFFBOARD."""
    ap.arm(clock.now)
    offboard_to(ap, clock, target)
    clock.run(2.0, each=keep_streaming(ap, clock, target))
    return clock.run_until(lambda: ap.mode != FlightMode.OFFBOARD, timeout=5)


def test_offboard_loss_with_px4_defaults_returns_climbing_to_rtl_return_alt(ap: SimulatedPx4) -> None:
    target = (HOME[0] + 10.0, HOME[1], HOME[2] + 1.5)
    waited = fly_offboard_then_stop(ap, clock := Clock(ap), target)
    assert waited == pytest.approx(ap.params["COM_OF_LOSS_T"], abs=2 * DT)
    assert ap.mode == FlightMode.RTL
    assert any("Failsafe: no offboard signal, Return" in text for _, text in ap.notices)
    clock.run(10.0)
    assert ap.height > 10.0  # climbing towards RTL_RETURN_ALT (60 m): through any indoor ceiling


def test_offboard_loss_set_to_hold_holds_position(ap: SimulatedPx4, sim: SimSettings) -> None:
    ap.params.set("COM_OBL_RC_ACT", 5)
    target = (HOME[0] + 10.0, HOME[1], HOME[2] + 1.5)
    clock = Clock(ap)
    waited = fly_offboard_then_stop(ap, clock, target)
    assert ap.mode == FlightMode.HOLD
    assert waited == pytest.approx(sim.offboard_timeout_s, abs=2 * DT)
    where = ap.position.copy()
    clock.run(5.0)
    assert ap.position[0] < target[0] - 2.0  # stopped short of the old target
    assert np.linalg.norm(ap.position - where) < 1.5  # braked near where the link was lost
    assert ap.height < 2.5


@pytest.mark.parametrize(("name", "value"), [("NAV_RCL_ACT", 1), ("COM_RCL_EXCEPT", 4), ("COM_RC_IN_MODE", 4)])
def test_offboard_loss_holds_if_rc_loss_is_hold_exempt_or_unexpected(ap: SimulatedPx4, name: str, value: int) -> None:
    ap.params.set(name, value)
    fly_offboard_then_stop(ap, Clock(ap), (HOME[0] + 10.0, HOME[1], HOME[2] + 1.5))
    assert ap.mode == FlightMode.HOLD


def test_offboard_loss_set_to_land_lands(ap: SimulatedPx4) -> None:
    ap.params.set("COM_OBL_RC_ACT", 4)
    clock = Clock(ap)
    fly_offboard_then_stop(ap, clock, (HOME[0], HOME[1], HOME[2] + 1.5))
    assert ap.mode == FlightMode.LAND
    clock.run_until(lambda: not ap.armed, timeout=15)
    assert ap.landed_state == LandedState.ON_GROUND


def test_offboard_loss_set_to_disarm_falls_once(ap: SimulatedPx4) -> None:
    ap.params.set("COM_OBL_RC_ACT", 7)
    clock = Clock(ap)
    fly_offboard_then_stop(ap, clock, (HOME[0], HOME[1], HOME[2] + 1.5))
    assert not ap.armed and ap.mode == FlightMode.HOLD
    clock.run(3.0)
    assert ap.at_ground
    assert sum("Failsafe" in text for _, text in ap.notices) == 1


def test_datalink_loss_takes_nav_dll_act_only_when_set(ap: SimulatedPx4) -> None:
    clock = Clock(ap)
    ap.params.set("COM_OBL_RC_ACT", 5)
    ap.arm(clock.now)
    ap.takeoff()
    ap.gcs_heartbeat(clock.now)
    clock.run_until(lambda: ap.mode == FlightMode.HOLD, timeout=10)
    clock.run(ap.params["COM_DL_LOSS_T"] + 1.0)
    assert ap.mode == FlightMode.HOLD  # NAV_DLL_ACT = 0: disabled
    assert "Data link lost" in ap.notices[-1][1]
    ap.gcs_heartbeat(clock.now)
    ap.params.set("NAV_DLL_ACT", 3)  # Land
    lost_after = clock.run_until(lambda: ap.mode != FlightMode.HOLD, timeout=15)
    assert ap.mode == FlightMode.LAND
    assert lost_after == pytest.approx(ap.params["COM_DL_LOSS_T"], abs=2 * DT)
    assert "no connection to the ground station, Land" in ap.notices[-1][1]


def test_velocity_setpoint_and_yaw(ap: SimulatedPx4) -> None:
    clock = Clock(ap)
    ap.arm(clock.now)
    velocity = np.array([0.0, 1.0, 0.5])  # north and up

    def sp() -> None:
        ap.set_setpoint(Setpoint(np.full(3, np.nan), velocity, yaw=math.radians(90)), clock.now)

    sp()
    ap.set_mode(FlightMode.OFFBOARD, clock.now)
    clock.run(3.0, each=sp)
    assert np.allclose(ap.velocity, velocity, atol=0.01)  # approached by the velocity loop
    assert ap.body.yaw == pytest.approx(math.radians(90))


def test_return_to_launch_lands_at_home(ap: SimulatedPx4) -> None:
    clock = Clock(ap)
    ap.arm(clock.now)
    target = (HOME[0] + 5.0, HOME[1] + 5.0, HOME[2] + 1.0)
    offboard_to(ap, clock, target)
    clock.run(6.0, each=keep_streaming(ap, clock, target))
    ap.params.set("RTL_RETURN_ALT", 3.0)
    assert ap.return_to_launch() == ACCEPTED
    clock.run_until(lambda: ap.height > 2.9, timeout=10)  # climbs to RTL_RETURN_ALT first
    clock.run_until(lambda: not ap.armed, timeout=40)
    assert np.linalg.norm(ap.position - HOME) < 0.25


def test_a_vehicle_over_an_upper_storey_lands_on_its_slab_not_through_it(sim: SimSettings) -> None:
    """Landing in place on the upper storey of a two-storey building (a mission stopped at its time limit): the
    vehicle used to descend to its home height, through the slab (a collision in gen:10)."""
    slab_top = 3.6

    def floor_below(p: np.ndarray) -> float:  # an upper floor over x > 5, the ground floor elsewhere
        return slab_top if p[0] > 5.0 and p[2] >= slab_top else HOME[2]

    ap = SimulatedPx4(HOME, Params(sim, 1), floor_below)
    clock = Clock(ap)
    ap.arm(clock.now)
    ap.takeoff()
    clock.run_until(lambda: ap.mode == FlightMode.HOLD, timeout=10)
    offboard_to(ap, clock, (7.0, 3.0, slab_top + 1.5))
    target = (7.0, 3.0, slab_top + 1.5)
    clock.run(12.0, keep_streaming(ap, clock, target))
    assert ap.position[0] == pytest.approx(7.0, abs=0.05) and ap.position[2] == pytest.approx(slab_top + 1.5, abs=0.05)
    assert ap.land() == ACCEPTED
    clock.run_until(lambda: not ap.armed, timeout=15)
    assert ap.position[2] == pytest.approx(slab_top, abs=1e-6)  # on the slab, disarmed by the land detector
    assert ap.landed_state == LandedState.ON_GROUND


def with_battery(sim: SimSettings, minutes: float, start: float) -> SimulatedPx4:
    return SimulatedPx4(HOME, Params(sim, 1), battery=Battery(minutes, start))


def hover(ap: SimulatedPx4, clock: Clock) -> None:
    ap.arm(clock.now)
    ap.takeoff()
    clock.run_until(lambda: ap.mode == FlightMode.HOLD, timeout=10)


def battery_notices(ap: SimulatedPx4) -> list[str]:
    return [text for _, text in ap.notices if "battery" in text]


def test_the_battery_drains_at_the_hover_rate_while_armed_and_faster_when_fast(sim: SimSettings) -> None:
    ap = with_battery(sim, minutes=10.0, start=1.0)
    clock = Clock(ap)
    clock.run(30.0)
    assert ap.battery.remaining == 1.0  # disarmed: no draw
    hover(ap, clock)
    start, hovered_s = ap.battery.remaining, 60.0
    clock.run(hovered_s)
    assert start - ap.battery.remaining == pytest.approx(hovered_s / 600.0, rel=1e-4)  # 10 min of hover per battery
    offboard_to(ap, clock, target := (HOME[0] + 200.0, HOME[1], HOME[2] + 1.5))
    clock.run(10.0, each=keep_streaming(ap, clock, target))
    fast = ap.battery.remaining
    clock.run(10.0, each=keep_streaming(ap, clock, target))
    speed = float(np.linalg.norm(ap.velocity))
    assert speed == pytest.approx(sim.max_speed_xy_m_s, abs=0.01)
    assert fast - ap.battery.remaining == pytest.approx(10.0 / 600.0 * (1 + 0.05 * speed**2), rel=1e-3)
    assert ap.battery.voltage_v < 4 * 4.05


@pytest.mark.parametrize(("act", "mode"), [(2, FlightMode.LAND), (3, FlightMode.RTL)])
def test_a_critical_battery_in_the_air_takes_com_low_bat_act(sim: SimSettings, act: int, mode: FlightMode) -> None:
    ap = with_battery(sim, minutes=1.0, start=0.16)
    ap.params.set("COM_LOW_BAT_ACT", act)
    clock = Clock(ap)
    hover(ap, clock)  # the low warning comes during the climb: only a warning
    assert battery_notices(ap) == ["Low battery level, return advised (15%)"]
    assert ap.mode == FlightMode.HOLD
    clock.run_until(lambda: ap.mode != FlightMode.HOLD, timeout=10)
    assert ap.mode == mode and ap.battery.remaining == pytest.approx(0.07, abs=0.001)
    action = "Land" if act == 2 else "Return"
    assert battery_notices(ap)[-1] == f"Failsafe: critical battery level, {action} (COM_LOW_BAT_ACT={act})"
    if act == 3:  # Return at critical, Land at emergency
        clock.run_until(lambda: ap.mode != FlightMode.RTL, timeout=5)
        assert ap.mode == FlightMode.LAND and ap.battery.remaining == pytest.approx(0.05, abs=0.001)
        assert battery_notices(ap)[-1] == "Failsafe: emergency battery level, Land (COM_LOW_BAT_ACT=3)"
    clock.run_until(lambda: not ap.armed, timeout=30)
    assert len(battery_notices(ap)) == 3  # each level once: low, critical, emergency (Land again where it is)


def test_with_px4s_default_a_critical_battery_only_warns(sim: SimSettings) -> None:
    ap = with_battery(sim, minutes=1.0, start=0.16)
    clock = Clock(ap)
    hover(ap, clock)
    clock.run(10.0)
    assert ap.mode == FlightMode.HOLD and ap.armed and ap.battery.remaining < 0.05
    assert [text.split(" (")[0] for text in battery_notices(ap)] == [
        "Low battery level, return advised",
        "Critical battery level, land now",
        "Emergency battery level, land immediately",
    ]


def test_arming_is_refused_below_the_critical_threshold_unless_forced(sim: SimSettings) -> None:
    ap = with_battery(sim, minutes=10.0, start=0.06)
    clock = Clock(ap)
    assert not ap.armable
    assert ap.arm(clock.now) == REJECTED and not ap.armed
    assert ap.notices[-1][1] == "Arming denied: critical battery, 6.0% below BAT_CRIT_THR 7.0%"
    ap.params.set("COM_ARM_BAT_MIN", 0.05)  # a threshold of its own: 6 % may arm
    assert ap.armable and ap.arm(clock.now) == ACCEPTED
    ap.disarm()
    ap.params.set("COM_ARM_BAT_MIN", -1.0)
    assert ap.arm(clock.now, force=True) == ACCEPTED  # forcing skips the checks, as in PX4


def test_a_low_battery_arms(sim: SimSettings) -> None:
    ap = with_battery(sim, minutes=10.0, start=0.10)
    assert ap.armable and ap.arm(Clock(ap).now) == ACCEPTED


@pytest.mark.parametrize(("tilt", "refusal"), [((70.0, 0.0), "roll"), ((0.0, -65.0), "pitch")])
def test_a_vehicle_not_standing_level_is_refused_arming(
    ap: SimulatedPx4, tilt: tuple[float, float], refusal: str
) -> None:
    """PX4's failure detector (FD_FAIL_R, FD_FAIL_P, 60 degrees): a vehicle tipped over is an attitude failure,
    and arming is refused with its reason, until it stands level or the limit is raised."""
    clock = Clock(ap)
    clock.run(0.1)
    ap.rest_tilt = (math.radians(tilt[0]), math.radians(tilt[1]))
    assert ap.attitude == ap.rest_tilt and not ap.armable
    assert ap.arm(clock.now) == REJECTED and not ap.armed
    assert ap.notices[-1][1] == f"Arming denied: Attitude failure ({refusal})"
    ap.params.set("FD_FAIL_R" if refusal == "roll" else "FD_FAIL_P", 90)
    assert ap.armable
    ap.params.set("FD_FAIL_R" if refusal == "roll" else "FD_FAIL_P", 60)
    ap.rest_tilt = (math.radians(10.0), 0.0)  # slightly off level: arms
    assert ap.arm(clock.now) == ACCEPTED
