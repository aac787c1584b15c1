"""A vehicle without GPS, as PX4 is indoors: local position only, no home position or Hold until a global origin
is set; its local origin is where its estimator started, and its home moves to wherever it arms. Fed encoded
MAVLink directly (the bench of test_vehicle.py): no sockets, no real time."""

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from swarm import geo
from swarm.agent.autopilot import LocalFrame
from swarm.agent.px4_failsafe import Action, action_that_can_run, mode_can_run
from swarm.sim.px4 import FlightMode
from tests.sim.test_vehicle import HOME, Bench

OFFSET = (1.5, -2.0, 0.3)  # the local origin from the spawn point, world frame
REJECTED = mavlink.MAV_RESULT_TEMPORARILY_REJECTED
ACCEPTED = mavlink.MAV_RESULT_ACCEPTED


def no_gps_bench() -> Bench:
    return Bench(**{"sim.gps": False, "sim.local_origin_offset": list(OFFSET)})


def set_mode(bench: Bench, mode: FlightMode) -> list[mavlink.MAVLink_message]:
    main, sub = mode.value
    return bench.command(mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, main, sub)


def take_off_in_offboard(bench: Bench, height: float) -> None:
    """Arm and climb in offboard over the spawn point, as the agent does without a global position."""
    assert bench.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)[-1].result == ACCEPTED
    target = np.array(HOME) + (0.0, 0.0, height)
    stream = offboard_stream(bench, target)
    stream()
    assert set_mode(bench, FlightMode.OFFBOARD)[-1].result == ACCEPTED
    bench.run(4.0, stream)


def offboard_stream(bench: Bench, world_target: np.ndarray):
    n, e, d = geo.enu_to_ned(tuple(world_target - (np.array(HOME) + OFFSET)))

    def send() -> None:
        bench.send(
            mavlink.MAVLink_set_position_target_local_ned_message(
                0, 1, 1, mavlink.MAV_FRAME_LOCAL_NED, 0b110111111000, n, e, d, 0, 0, 0, 0, 0, 0, 0, 0
            )
        )

    return send


def status_texts(bench: Bench) -> str:
    """Every STATUSTEXT the vehicle sent since the last look, joined."""
    bench.vehicle.downlink.flush()
    out = [m for d in bench.sock.datagrams for m in bench.decoder.parse_buffer(d) or []]
    bench.sock.datagrams.clear()
    return "".join(m.text for m in out if m.get_type() == "STATUSTEXT")


def test_without_gps_only_local_position_is_reported() -> None:
    bench = no_gps_bench()
    assert bench.ap.params["EKF2_GPS_CTRL"] == 0 and Bench().ap.params["EKF2_GPS_CTRL"] == 7  # PX4's default
    out = bench.telemetry()
    assert {"HOME_POSITION", "GLOBAL_POSITION_INT", "GPS_RAW_INT"}.isdisjoint(out), sorted(out)
    sensors = out["SYS_STATUS"].onboard_control_sensors_health
    assert sensors & mavlink.MAV_SYS_STATUS_SENSOR_VISION_POSITION  # MAVSDK's local position ok
    assert not sensors & mavlink.MAV_SYS_STATUS_SENSOR_GPS
    local = out["LOCAL_POSITION_NED"]  # relative to the local origin, not to home
    assert (local.x, local.y, local.z) == pytest.approx(geo.enu_to_ned(tuple(-np.array(OFFSET))), abs=1e-3)
    with_gps = Bench().telemetry()
    assert {"HOME_POSITION", "GLOBAL_POSITION_INT", "GPS_RAW_INT"} <= set(with_gps)
    assert with_gps["SYS_STATUS"].onboard_control_sensors_health & mavlink.MAV_SYS_STATUS_SENSOR_GPS


def test_hold_and_return_are_refused_without_a_global_position_and_a_failsafe_hold_lands() -> None:
    bench = no_gps_bench()
    take_off_in_offboard(bench, 2.0)
    assert bench.ap.height == pytest.approx(2.0, abs=0.05) and bench.ap.mode == FlightMode.OFFBOARD
    for mode in (FlightMode.HOLD, FlightMode.RTL):
        answer = set_mode(bench, mode)
        assert answer[-1].result == REJECTED, mode
        assert "no global position" in "".join(m.text for m in answer if m.get_type() == "STATUSTEXT")
    assert bench.command(mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH)[-1].result == REJECTED
    assert bench.ap.mode == FlightMode.OFFBOARD
    bench.ap.params.set("COM_OBL_RC_ACT", 5)  # offboard loss: Hold, which cannot run here
    bench.sock.datagrams.clear()
    bench.run(1.5)  # setpoints stopped
    assert bench.ap.mode == FlightMode.LAND
    assert "Failsafe: no offboard signal, Land (Hold not possible)" in status_texts(bench)


def test_takeoff_mode_without_a_global_position_ends_in_a_landing() -> None:
    bench = no_gps_bench()
    bench.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert bench.command(mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan, math.nan)[-1].result == (
        ACCEPTED
    )
    bench.run(4.0)
    assert bench.ap.mode == FlightMode.LAND  # Takeoff ends in Hold, which falls back to Land


def test_a_global_origin_places_the_local_frame_on_the_globe() -> None:
    bench = no_gps_bench()
    lat, lon, alt = 46.5, 6.6, 372.0
    answer = bench.send(mavlink.MAVLink_set_gps_global_origin_message(1, round(lat * 1e7), round(lon * 1e7), 372000))
    [origin] = [m for m in answer if m.get_type() == "GPS_GLOBAL_ORIGIN"]
    assert (origin.latitude, origin.longitude, origin.altitude) == (round(lat * 1e7), round(lon * 1e7), 372000)
    out = bench.telemetry()
    assert "HOME_POSITION" in out and "GLOBAL_POSITION_INT" in out and "GPS_RAW_INT" not in out
    home = out["HOME_POSITION"]
    assert (home.x, home.y, home.z) == pytest.approx(geo.enu_to_ned(tuple(-np.array(OFFSET))), abs=1e-3)
    expected = geo.world_to_geo(
        bench.config.mission.origin.model_copy(update={"lat_deg": lat, "lon_deg": lon, "alt_amsl_m": alt}),
        tuple(-np.array(OFFSET)),
    )
    assert home.latitude == round(expected[0] * 1e7) and home.longitude == round(expected[1] * 1e7)
    assert set_mode(bench, FlightMode.HOLD)[-1].result == ACCEPTED  # Hold can run now


def test_home_moves_to_where_the_vehicle_arms_and_the_local_origin_stays() -> None:
    bench = no_gps_bench()
    take_off_in_offboard(bench, 1.5)
    elsewhere = np.array(HOME) + (3.0, 1.0, 1.5)
    bench.run(6.0, offboard_stream(bench, elsewhere))
    assert bench.command(mavlink.MAV_CMD_NAV_LAND)[-1].result == ACCEPTED
    bench.run(8.0)  # down, and disarmed by COM_DISARM_LAND
    assert not bench.ap.armed and bench.ap.home == pytest.approx(HOME)
    bench.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert bench.ap.home[:2] == pytest.approx(elsewhere[:2], abs=0.05)  # PX4 resets home at arming
    assert bench.ap.local_origin == pytest.approx(np.array(HOME) + OFFSET)
    local = bench.telemetry()["LOCAL_POSITION_NED"]
    assert (local.x, local.y) == pytest.approx((1.0 - OFFSET[1], 3.0 - OFFSET[0]), abs=0.05)


def test_modes_that_need_a_global_position_and_the_failsafe_fallback() -> None:
    assert not mode_can_run("HOLD", False) and not mode_can_run("RTL", False)
    assert all(mode_can_run(m, False) for m in ("OFFBOARD", "LAND", "TAKEOFF"))
    assert all(mode_can_run(m, True) for m in ("HOLD", "RTL", "OFFBOARD"))
    assert action_that_can_run(Action.HOLD, False) == action_that_can_run(Action.RETURN, False) == Action.LAND
    assert action_that_can_run(Action.HOLD, True) == Action.HOLD
    assert action_that_can_run(Action.DISARM, False) == Action.DISARM


@pytest.mark.parametrize("north_deg", [0.0, 90.0, -30.0])
def test_a_local_frame_maps_both_ways(north_deg: float) -> None:
    frame = LocalFrame((4.0, -1.0, 0.5), north_deg)
    for ned in [(0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (0.0, 2.0, -1.0), (-3.0, 1.5, 0.2)]:
        assert frame.to_local(frame.to_world(ned)) == pytest.approx(ned, abs=1e-9)
    north = np.subtract(frame.to_world((1.0, 0.0, 0.0)), frame.origin)
    bearing = math.radians(north_deg)
    assert north == pytest.approx((-math.sin(bearing), math.cos(bearing), 0.0), abs=1e-9)
    assert frame.to_world((0.0, 0.0, -2.0))[2] == pytest.approx(2.5)  # down is down


def test_no_arming_and_no_offboard_before_the_estimator_has_a_position() -> None:
    bench = Bench(**{"sim.estimator_warmup_s": 3.0})
    out = bench.telemetry()
    assert "LOCAL_POSITION_NED" not in out  # PX4 sends it only with a valid estimate
    health = out["SYS_STATUS"].onboard_control_sensors_health
    assert not health & mavlink.MAV_SYS_STATUS_SENSOR_GPS and not health & mavlink.MAV_SYS_STATUS_PREARM_CHECK
    answer = bench.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert answer[-1].result == REJECTED and not bench.ap.armed
    assert "Arming denied: no valid position estimate" in "".join(
        m.text for m in answer if m.get_type() == "STATUSTEXT"
    )
    assert set_mode(bench, FlightMode.OFFBOARD)[-1].result == REJECTED
    bench.run(3.1)
    out = bench.telemetry()
    assert "LOCAL_POSITION_NED" in out
    assert out["SYS_STATUS"].onboard_control_sensors_health & mavlink.MAV_SYS_STATUS_PREARM_CHECK
    assert bench.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)[-1].result == ACCEPTED


def test_no_arming_while_the_data_link_failsafe_is_active() -> None:
    bench = Bench()
    bench.ap.params.set("NAV_DLL_ACT", 3)  # Land on data-link loss
    bench.send(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GCS, 8, 0, 0, 0, 3))
    bench.run(bench.ap.params["COM_DL_LOSS_T"] + 0.5)  # the ground station fell silent
    answer = bench.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    texts = "".join(m.text for m in answer if m.get_type() == "STATUSTEXT")
    assert answer[-1].result == REJECTED and "no connection to the ground control station" in texts
    bench.send(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GCS, 8, 0, 0, 0, 3))  # back
    assert bench.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)[-1].result == ACCEPTED
    disabled = Bench()  # NAV_DLL_ACT 0, PX4's default: a silent ground station does not stop arming
    disabled.send(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GCS, 8, 0, 0, 0, 3))
    disabled.run(disabled.ap.params["COM_DL_LOSS_T"] + 0.5)
    assert disabled.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)[-1].result == ACCEPTED
