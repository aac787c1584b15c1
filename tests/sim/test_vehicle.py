"""MAVLink handling of one vehicle, fed encoded messages directly (no sockets, no real time)."""

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from swarm import geo
from swarm.config import load_config
from swarm.sim.px4 import FlightMode
from swarm.sim.vehicle import Downlink, SimVehicle

HOME = (2.0, 3.0, 0.0)
GCS_ADDR = ("127.0.0.1", 40000)


class CapturingSocket:
    def __init__(self) -> None:
        self.datagrams: list[bytes] = []

    def sendto(self, data: bytes, addr) -> None:
        self.datagrams.append(data)


class Bench:
    """A vehicle, a ground-station encoder and a decoder for what the vehicle sends."""

    def __init__(self, **settings: object) -> None:
        self.config = load_config(overrides={"mission.world": "box", **settings})
        self.sock = CapturingSocket()
        self.now = 10.0
        self.vehicle = SimVehicle(1, HOME, self.config, Downlink(self.sock, GCS_ADDR), now=self.now)
        self.gcs = mavlink.MAVLink(None, srcSystem=245, srcComponent=190)
        self.decoder = mavlink.MAVLink(None)

    def send(self, msg: mavlink.MAVLink_message) -> list[mavlink.MAVLink_message]:
        """Deliver one message; return what the vehicle answered, in order."""
        self.vehicle.receive(msg.pack(self.gcs), GCS_ADDR, self.now)
        self.vehicle.downlink.flush()
        out = [m for d in self.sock.datagrams for m in self.decoder.parse_buffer(d) or []]
        self.sock.datagrams.clear()
        return out

    def command(self, command: int, *params: float) -> list[mavlink.MAVLink_message]:
        p = list(params) + [0.0] * (7 - len(params))
        return self.send(mavlink.MAVLink_command_long_message(1, 1, command, 0, *p))

    def run(self, seconds: float, each=None) -> None:
        for _ in range(round(seconds / 0.02)):
            self.now += 0.02
            if each is not None:
                each()
            self.vehicle.step(0.02, self.now)

    def telemetry(self) -> dict[str, mavlink.MAVLink_message]:
        """Every stream once (as at start), the last message of each type."""
        self.vehicle.tick(self.now)
        self.vehicle.downlink.flush()
        out = {m.get_type(): m for d in self.sock.datagrams for m in self.decoder.parse_buffer(d) or []}
        self.sock.datagrams.clear()
        for stream in self.vehicle._streams.values():
            stream.due = self.now  # due again at the next call
        return out

    @property
    def ap(self):
        return self.vehicle.autopilot


@pytest.fixture
def bench() -> Bench:
    return Bench()


def test_state_is_announced_before_the_ack(bench: Bench) -> None:
    out = bench.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert [m.get_type() for m in out] == ["HEARTBEAT", "EXTENDED_SYS_STATE", "COMMAND_ACK"]
    assert out[0].base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    assert (out[2].target_system, out[2].target_component) == (245, 190)
    # no change, no extra announcement
    assert [m.get_type() for m in bench.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)] == ["COMMAND_ACK"]


def test_commands_for_another_system_are_ignored(bench: Bench) -> None:
    assert bench.send(mavlink.MAVLink_command_long_message(7, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)) == []
    assert not bench.ap.armed


def test_takeoff_altitude_param7_is_amsl(bench: Bench) -> None:
    bench.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    amsl = bench.config.mission.origin.alt_amsl_m + 2.2
    out = bench.command(mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan, amsl)
    assert out[-1].result == mavlink.MAV_RESULT_ACCEPTED
    bench.run(5.0)
    assert bench.ap.height == pytest.approx(2.2, abs=0.05)


def test_global_int_setpoint(bench: Bench) -> None:
    lat, lon, _ = geo.world_to_geo(bench.config.mission.origin, (3.0, 5.0, 0.0))
    mask = 0b0000_1111_1111_1000 & ~mavlink.POSITION_TARGET_TYPEMASK_YAW_IGNORE  # position + yaw
    msg = mavlink.MAVLink_set_position_target_global_int_message(
        0,
        1,
        1,
        mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
        mask,
        round(lat * 1e7),
        round(lon * 1e7),
        1.2,
        0,
        0,
        0,
        0,
        0,
        0,
        math.radians(45),
        0,
    )
    bench.send(msg)
    sp = bench.ap._setpoint
    np.testing.assert_allclose(sp.position, [3.0, 5.0, 1.2], atol=0.02)
    assert np.isnan(sp.velocity).all() and sp.yaw == pytest.approx(math.radians(45)) and sp.yaw_rate is None


def test_body_frame_velocity_follows_the_heading(bench: Bench) -> None:
    bench.ap.body.yaw = math.pi / 2  # facing east
    mask = 0b0000_1111_1100_0111  # velocity only, yaw and yaw rate ignored
    bench.send(
        mavlink.MAVLink_set_position_target_local_ned_message(
            0, 1, 1, mavlink.MAV_FRAME_BODY_NED, mask, 0, 0, 0, 1.0, 0.0, -0.5, 0, 0, 0, 0, 0
        )
    )
    sp = bench.ap._setpoint
    assert np.isnan(sp.position).all()
    np.testing.assert_allclose(sp.velocity, [1.0, 0.0, 0.5], atol=1e-9)  # forward = east = +x, up = +z


def test_change_speed_limits_auto_modes(bench: Bench) -> None:
    bench.command(mavlink.MAV_CMD_DO_CHANGE_SPEED, 1, 0.5)
    assert bench.ap.limits().max_xy == 0.5
    assert bench.ap.limits(offboard=True).max_xy == bench.config.sim.max_speed_xy_m_s
    bench.command(mavlink.MAV_CMD_DO_CHANGE_SPEED, 1, -1)
    assert bench.ap.limits().max_xy == bench.config.sim.max_speed_xy_m_s


def test_param_set_changes_behaviour(bench: Bench) -> None:
    out = bench.send(mavlink.MAVLink_param_set_message(1, 1, b"MPC_XY_VEL_MAX", 1.25, mavlink.MAV_PARAM_TYPE_REAL32))
    assert out[0].get_type() == "PARAM_VALUE" and out[0].param_value == 1.25
    assert bench.ap.limits(offboard=True).max_xy == 1.25
    assert bench.send(mavlink.MAVLink_param_set_message(1, 1, b"NO_SUCH_PARAM", 1.0, 9)) == []  # as PX4


def test_nan_and_garbage_do_not_break_the_vehicle(bench: Bench) -> None:
    bench.vehicle.receive(b"\xfd\x05garbage" * 10, GCS_ADDR, bench.now)
    out = bench.command(mavlink.MAV_CMD_DO_SET_MODE, math.nan, math.nan, math.nan)
    assert out[-1].result == mavlink.MAV_RESULT_DENIED
    out = bench.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, math.nan, math.nan)
    assert out[-1].result == mavlink.MAV_RESULT_UNSUPPORTED
    assert bench.ap.mode == FlightMode.HOLD


def test_muted_downlink_sends_nothing(bench: Bench) -> None:
    bench.vehicle.telemetry_enabled = False
    assert bench.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == []
    assert bench.ap.armed  # commands are still obeyed
    bench.vehicle.tick(bench.now + 5)
    bench.vehicle.downlink.flush()
    assert bench.sock.datagrams == []


def test_the_battery_is_reported_as_px4_does_and_a_critical_one_is_not_armable() -> None:
    bench = Bench(**{"sim.battery_start": 0.12})
    out = bench.telemetry()
    battery, status = out["BATTERY_STATUS"], out["SYS_STATUS"]
    assert battery.battery_remaining == 12 and battery.charge_state == mavlink.MAV_BATTERY_CHARGE_STATE_LOW
    assert battery.voltages[0] == round(4 * (3.6 + 0.45 * 0.12) * 1000) and battery.voltages[1] == 65535
    assert (battery.current_battery, battery.current_consumed, battery.temperature) == (-1, -1, 32767)
    assert status.battery_remaining == 12 and status.voltage_battery == battery.voltages[0]
    assert status.onboard_control_sensors_health & mavlink.MAV_SYS_STATUS_PREARM_CHECK  # a low battery arms
    assert status.onboard_control_sensors_present & mavlink.MAV_SYS_STATUS_SENSOR_BATTERY
    bench.ap.battery.remaining = 0.0649
    out = bench.telemetry()
    assert out["BATTERY_STATUS"].charge_state == mavlink.MAV_BATTERY_CHARGE_STATE_CRITICAL
    assert out["BATTERY_STATUS"].battery_remaining == 6 and out["SYS_STATUS"].battery_remaining == 7  # PX4 rounds up
    assert not out["SYS_STATUS"].onboard_control_sensors_health & mavlink.MAV_SYS_STATUS_PREARM_CHECK
    answer = bench.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert [m.get_type() for m in answer] == ["STATUSTEXT", "STATUSTEXT", "COMMAND_ACK"]  # the reason first
    assert "".join(m.text for m in answer[:2]) == "Arming denied: critical battery, 6.5% below BAT_CRIT_THR 7.0%"
    assert answer[2].result == mavlink.MAV_RESULT_TEMPORARILY_REJECTED and not bench.ap.armed


def test_one_vehicle_can_start_with_another_battery() -> None:
    bench = Bench(**{"sim.battery_start": 0.9, "sim.battery_starts": {"1": 0.3}})  # keys as TOML spells them
    assert bench.ap.battery.remaining == pytest.approx(0.3)
    assert Bench(**{"sim.battery_start": 0.9, "sim.battery_starts": {"2": 0.3}}).ap.battery.remaining == 0.9
