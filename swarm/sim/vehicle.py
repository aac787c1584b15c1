"""One simulated PX4 autopilot on the wire: parses MAVLink from its ground station, answers as PX4 does and
streams telemetry, enough for MAVSDK (in PX4 mode) and pymavlink ground stations to fly it.

What MAVSDK relies on: a HEARTBEAT from component 1 with autopilot PX4 and PX4 custom modes; SYS_STATUS health
bits including PREARM_CHECK (is_armable); BATTERY_STATUS (telemetry.battery; SYS_STATUS's battery fields until
the first one arrives); HOME_POSITION; EXTENDED_SYS_STATE (landed state); the new state
announced BEFORE each COMMAND_ACK; an ACK for every command (unknown ones UNSUPPORTED); a PARAM_VALUE echo for
every PARAM_SET; OFFBOARD refused without a setpoint in the last 0.5 s. Failsafes and refusals are announced in
STATUSTEXT (chunked past 50 characters, as MAVLink 2 allows); a GCS HEARTBEAT keeps the data link up.

The flight logic lives in autopilot.py; this module only translates MAVLink to and from it. Local NED is relative
to the vehicle's local origin (where its estimator started: the spawn point plus sim.local_origin_offset), not
its home, which moves to wherever it arms. Global positions are the mission origin plus the world position
(swarm.geo) while GPS is fused. Without GPS (EKF2_GPS_CTRL 0 at boot) the vehicle reports vision position in
SYS_STATUS instead of GPS, sends no GPS_RAW_INT, and no GLOBAL_POSITION_INT or HOME_POSITION (PX4 sends home only
with a valid global position, HOME_POSITION.hpp) until a SET_GPS_GLOBAL_ORIGIN places the local origin on the
globe; from then on global positions are that origin plus the local position.
"""

from __future__ import annotations

import logging
import math
import socket
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from swarm import geo
from swarm.agent.px4_failsafe import BatteryWarning
from swarm.config import GeoOrigin, SwarmConfig, Vec3
from swarm.sim.autopilot import ACCEPTED, DENIED, REJECTED, Setpoint, SimulatedPx4
from swarm.sim.battery import Battery
from swarm.sim.px4 import FlightMode, LandedState, Params

_log = logging.getLogger(__name__)

COMPONENT_ID = 1
FORCE_MAGIC = 21196  # ARM_DISARM param2 that forces (dis)arming, as PX4
UNSUPPORTED = mavlink.MAV_RESULT_UNSUPPORTED
INT32_MAX = 2**31 - 1
STATUSTEXT_CHUNK = 50  # characters in one STATUSTEXT
_SENSORS = (
    mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG
    | mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | mavlink.MAV_SYS_STATUS_AHRS
    | mavlink.MAV_SYS_STATUS_SENSOR_BATTERY
    | mavlink.MAV_SYS_STATUS_PREARM_CHECK
)
# MAVSDK's health: local position ok from GPS, optical flow or vision position present, enabled and healthy
_POSITION_SENSOR = {True: mavlink.MAV_SYS_STATUS_SENSOR_GPS, False: mavlink.MAV_SYS_STATUS_SENSOR_VISION_POSITION}
# BATTERY_STATUS charge_state of each warning (PX4's mavlink/streams/BATTERY_STATUS.hpp)
_CHARGE_STATE = {
    BatteryWarning.NONE: mavlink.MAV_BATTERY_CHARGE_STATE_OK,
    BatteryWarning.LOW: mavlink.MAV_BATTERY_CHARGE_STATE_LOW,
    BatteryWarning.CRITICAL: mavlink.MAV_BATTERY_CHARGE_STATE_CRITICAL,
    BatteryWarning.EMERGENCY: mavlink.MAV_BATTERY_CHARGE_STATE_EMERGENCY,
}
_CAPABILITIES = (
    mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
    | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
    | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_GLOBAL_INT
)
_PX4_VERSION = (1 << 24) | (14 << 16) | (0 << 8) | 0xFF  # 1.14.0 release, as AUTOPILOT_VERSION encodes it
_LOCAL_FRAMES = (
    mavlink.MAV_FRAME_LOCAL_NED,
    mavlink.MAV_FRAME_LOCAL_OFFSET_NED,
    mavlink.MAV_FRAME_BODY_NED,
    mavlink.MAV_FRAME_BODY_OFFSET_NED,
)
_RELATIVE_ALT_FRAMES = (
    mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT,
    mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
    mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT,
    mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT,
)
_GLOBAL_FRAMES = (mavlink.MAV_FRAME_GLOBAL, mavlink.MAV_FRAME_GLOBAL_INT, *_RELATIVE_ALT_FRAMES)


class Downlink:
    """Where a vehicle's MAVLink goes: a UDP peer (learned from incoming packets); muted when disabled.

    Messages are queued and sent by flush() several to a datagram, as PX4 does: a third of the system calls.
    """

    MAX_DATAGRAM = 1200  # stays under a 1500-byte MTU

    def __init__(self, sock: socket.socket | None, peer: tuple[str, int]) -> None:
        self.sock = sock
        self.peer = peer
        self.enabled = True
        self.datagrams = 0
        self.errors = 0
        self._pending = bytearray()

    def write(self, buf: bytes) -> None:
        if not self.enabled or self.sock is None:
            return
        if len(self._pending) + len(buf) > self.MAX_DATAGRAM:
            self.flush()
        self._pending += buf

    def flush(self) -> None:
        if not self._pending:
            return
        data, self._pending = bytes(self._pending), bytearray()
        if not self.enabled or self.sock is None:
            return
        try:
            self.sock.sendto(data, self.peer)
            self.datagrams += 1
        except OSError:
            self.errors += 1  # nobody listening yet, or a transient network error: telemetry is best effort


@dataclass
class _Command:
    """COMMAND_LONG and COMMAND_INT in one shape; lat/lon in degrees (NaN when unset), z per `frame`."""

    command: int
    params: tuple[float, float, float, float]
    lat: float
    lon: float
    z: float
    frame: int
    src: tuple[int, int]


@dataclass
class _Stream:
    default_interval: float
    interval: float | None  # None = disabled
    due: float = 0.0


class SimVehicle:
    def __init__(
        self,
        drone_id: int,
        home: Vec3,
        config: SwarmConfig,
        downlink: Downlink | None = None,
        now: float = 0.0,
        floor_below: Callable[[np.ndarray], float] | None = None,
    ) -> None:
        sim = config.sim
        self.id = drone_id
        self.origin = config.mission.origin
        self.params = Params(sim, drone_id)
        battery = Battery(sim.battery_minutes, sim.battery_starts.get(drone_id, sim.battery_start))
        local_origin = tuple(np.add(home, sim.local_origin_offset))
        self.autopilot = SimulatedPx4(
            home, self.params, floor_below, battery, local_origin, now, sim.estimator_warmup_s
        )
        self.downlink = downlink or Downlink(None, (sim.host, 0))
        self.mav = mavlink.MAVLink(self.downlink, srcSystem=drone_id, srcComponent=COMPONENT_ID)  # sends
        self._parser = _new_parser()
        self.boot_time = now
        self.last_gcs_message: float | None = None
        self._now = now
        self._last_state = self._state()
        self._statustext_id = 0
        telemetry, heartbeat = 1.0 / sim.telemetry_hz, 1.0 / sim.heartbeat_hz
        self._senders: dict[int, Callable[[], None]] = {
            mavlink.MAVLINK_MSG_ID_HEARTBEAT: self._send_heartbeat,
            mavlink.MAVLINK_MSG_ID_SYS_STATUS: self._send_sys_status,
            mavlink.MAVLINK_MSG_ID_BATTERY_STATUS: self._send_battery_status,
            mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: self._send_extended_sys_state,
            mavlink.MAVLINK_MSG_ID_HOME_POSITION: self._send_home,
            mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: self._send_gps_raw,
            mavlink.MAVLINK_MSG_ID_ATTITUDE: self._send_attitude,
            mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: self._send_local_position,
            mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: self._send_global_position,
            mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION: self._send_autopilot_version,
            mavlink.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN: self._send_gps_global_origin,
        }
        intervals = {
            mavlink.MAVLINK_MSG_ID_HEARTBEAT: heartbeat,
            mavlink.MAVLINK_MSG_ID_SYS_STATUS: heartbeat,
            mavlink.MAVLINK_MSG_ID_BATTERY_STATUS: 2.0,  # PX4's 0.5 Hz (mavlink_main.cpp)
            mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: heartbeat,
            mavlink.MAVLINK_MSG_ID_HOME_POSITION: 1.0,
            mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: 1.0,
            mavlink.MAVLINK_MSG_ID_ATTITUDE: telemetry,
            mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: telemetry,
            mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: telemetry,
        }
        self._streams = {msg_id: _Stream(iv, iv, now) for msg_id, iv in intervals.items()}

    # --- public face -------------------------------------------------------------------------------------------

    @property
    def home(self) -> np.ndarray:
        return self.autopilot.home

    @property
    def telemetry_enabled(self) -> bool:
        """Fault injection: False drops every outgoing packet (a dead downlink); commands are still obeyed."""
        return self.downlink.enabled

    @telemetry_enabled.setter
    def telemetry_enabled(self, enabled: bool) -> None:
        self.downlink.enabled = enabled

    def receive(self, data: bytes, addr: tuple[str, int], now: float) -> None:
        """Handle one datagram from the ground station."""
        self._now = now
        messages = self._parser.parse_buffer(data) or ()
        if self._parser.buf_len():
            self._parser = _new_parser()  # a datagram holds whole messages: a torn one must not eat the next
        for msg in messages:
            if msg.get_type() == "BAD_DATA" or msg.get_srcSystem() == self.id:
                continue
            self.last_gcs_message = now
            self.downlink.peer = addr
            if msg.get_type() == "HEARTBEAT" and getattr(msg, "type", None) == mavlink.MAV_TYPE_GCS:
                self.autopilot.gcs_heartbeat(now)  # PX4 counts GCS heartbeats for the data link (COM_DL_LOSS_T)
            handler = self._handlers.get(msg.get_type())
            if handler is None:
                continue
            try:
                handler(self, msg)
            except Exception:  # a malformed message must not take the whole simulator down
                _log.exception("vehicle %d: cannot handle %s", self.id, msg.get_type())

    def step(self, dt: float, now: float) -> None:
        """Advance the physics by dt; announce a state change (arm, mode, landed) at once."""
        self._now = now
        self.autopilot.step(dt, now)
        self._send_notices()
        self._announce_state_change()

    def tick(self, now: float) -> None:
        """Send every telemetry stream that is due."""
        self._now = now
        for msg_id, stream in self._streams.items():
            if stream.interval is None or now < stream.due:
                continue
            self._senders[msg_id]()
            stream.due += stream.interval  # keeps the average rate when ticks come a little late
            if stream.due <= now:
                stream.due = now + stream.interval  # fell behind by a whole interval: no burst

    def status(self) -> dict:
        ap = self.autopilot
        age = None if self.last_gcs_message is None else round(self._now - self.last_gcs_message, 3)
        return {
            "id": self.id,
            "home": _rounded(ap.home),
            "position": _rounded(ap.position),
            "velocity": _rounded(ap.velocity),
            "armed": ap.armed,
            "mode": ap.mode.name,
            "landed_state": ap.landed_state.label,
            "distance_m": round(ap.distance_m, 3),
            "battery": round(ap.battery.remaining, 4),
            "global_position": ap.global_position,
            "local_origin": _rounded(ap.local_origin),
            "gcs_seen": self.last_gcs_message is not None,
            "last_gcs_message_age_s": age,
        }

    # --- state announcements -----------------------------------------------------------------------------------

    def _state(self) -> tuple[bool, FlightMode, LandedState]:
        ap = self.autopilot
        return ap.armed, ap.mode, ap.landed_state

    def _announce_state_change(self) -> None:
        state = self._state()
        if state != self._last_state:
            self._last_state = state
            self._send_heartbeat()
            self._send_extended_sys_state()

    def _send_notices(self) -> None:
        notices, self.autopilot.notices = self.autopilot.notices, []
        for severity, text in notices:
            _log.info("vehicle %d: %s", self.id, text)
            self._send_statustext(severity, text)

    def _send_statustext(self, severity: int, text: str) -> None:
        """One STATUSTEXT, or several chunks with one id when longer than 50 characters (MAVLink 2)."""
        data = text.encode("ascii", "replace")
        if len(data) <= STATUSTEXT_CHUNK:
            self.mav.statustext_send(severity, data)
            return
        self._statustext_id = self._statustext_id % 65535 + 1
        chunks = [data[i : i + STATUSTEXT_CHUNK] for i in range(0, len(data), STATUSTEXT_CHUNK)]
        if len(chunks[-1]) == STATUSTEXT_CHUNK:
            chunks.append(b"")  # the text ends with a NUL: a full last chunk needs an empty one after it
        for seq, chunk in enumerate(chunks):
            self.mav.statustext_send(severity, chunk, self._statustext_id, seq)

    def _ack(self, cmd: _Command, result: int) -> None:
        self._send_notices()  # a refusal's reason before its ACK, as PX4's mavlink_log comes before the ACK
        self._announce_state_change()  # MAVSDK reads armed/mode right after the ACK: state must arrive first
        self.mav.command_ack_send(cmd.command, result, 0, 0, cmd.src[0], cmd.src[1])

    # --- telemetry ---------------------------------------------------------------------------------------------

    def _boot_ms(self) -> int:
        return int((self._now - self.boot_time) * 1000) & 0xFFFFFFFF

    def _send_heartbeat(self) -> None:
        ap = self.autopilot
        base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (mavlink.MAV_MODE_FLAG_SAFETY_ARMED if ap.armed else 0)
        state = mavlink.MAV_STATE_ACTIVE if ap.armed else mavlink.MAV_STATE_STANDBY
        self.mav.heartbeat_send(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, base, ap.mode.custom_mode, state)

    def _send_sys_status(self) -> None:
        ap = self.autopilot
        sensors = _SENSORS | _POSITION_SENSOR[ap.gps]
        health = sensors if ap.armable else sensors & ~mavlink.MAV_SYS_STATUS_PREARM_CHECK
        if not ap.position_valid:
            health &= ~_POSITION_SENSOR[ap.gps]
        millivolts = round(ap.battery.voltage_v * 1000)
        remaining = math.ceil(ap.battery.remaining * 100)  # PX4 rounds up here, to the nearest in BATTERY_STATUS
        self.mav.sys_status_send(sensors, sensors, health, 150, millivolts, -1, remaining, 0, 0, 0, 0, 0, 0)

    def _send_battery_status(self) -> None:
        """As PX4 reports a battery without cell voltages or a current sensor: the total voltage in the first
        cell, unknown current and consumption (-1), unknown temperature (INT16_MAX), no time estimate (0)."""
        ap = self.autopilot
        voltages = [min(round(ap.battery.voltage_v * 1000), 65534)] + [65535] * 9
        self.mav.battery_status_send(
            0,
            mavlink.MAV_BATTERY_FUNCTION_ALL,
            mavlink.MAV_BATTERY_TYPE_LIPO,
            32767,
            voltages,
            -1,
            -1,
            -1,
            math.floor(ap.battery.remaining * 100 + 0.5),  # PX4's roundf: halves away from zero
            0,
            _CHARGE_STATE[ap.battery_warning],
        )

    def _send_extended_sys_state(self) -> None:
        self.mav.extended_sys_state_send(mavlink.MAV_VTOL_STATE_UNDEFINED, int(self.autopilot.landed_state))

    def _globe(self) -> tuple[GeoOrigin, np.ndarray] | None:
        """How world positions map to the globe: (geodetic point, the world point at it); None without a global
        position. With GPS the truth (the mission origin at the world origin); without it, the set global origin
        at the local origin."""
        ap = self.autopilot
        if ap.gps:
            return self.origin, np.zeros(3)
        if ap.global_origin is not None:
            return ap.global_origin, ap.local_origin
        return None

    def _geo(self, p: np.ndarray) -> tuple[int, int, int] | None:
        globe = self._globe()
        if globe is None:
            return None
        q = p - globe[1]
        lat, lon, alt = geo.world_to_geo(globe[0], (q[0], q[1], q[2]))
        return round(lat * 1e7), round(lon * 1e7), round(alt * 1000)

    def _from_geo(self, lat_deg: float, lon_deg: float, alt_amsl_m: float) -> np.ndarray | None:
        globe = self._globe()
        if globe is None:
            return None
        return np.array(geo.geo_to_world(globe[0], lat_deg, lon_deg, alt_amsl_m)) + globe[1]

    def _local_ned(self, p: np.ndarray) -> Vec3:
        return geo.enu_to_ned(tuple(p - self.autopilot.local_origin))

    def _send_home(self) -> None:
        geodetic = self._geo(self.home)
        if geodetic is None:
            return  # PX4 sends HOME_POSITION only with a valid global position (HOME_POSITION.hpp)
        x, y, z = self._local_ned(self.home)
        self.mav.home_position_send(*geodetic, x, y, z, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, int(self._now * 1e6))

    def _send_gps_global_origin(self) -> None:
        geodetic = self._geo(self.autopilot.local_origin)
        if geodetic is not None:
            self.mav.gps_global_origin_send(*geodetic, int(self._now * 1e6))

    def _send_gps_raw(self) -> None:
        ap = self.autopilot
        geodetic = self._geo(ap.position)
        if not ap.gps or geodetic is None:
            return  # no GPS receiver fused: nothing to report
        lat, lon, alt = geodetic
        speed = math.hypot(ap.velocity[0], ap.velocity[1])
        cog = round(math.degrees(math.atan2(ap.velocity[0], ap.velocity[1])) % 360 * 100) if speed > 0.1 else 65535
        self.mav.gps_raw_int_send(
            int(self._now * 1e6), mavlink.GPS_FIX_TYPE_3D_FIX, lat, lon, alt, 80, 120, round(speed * 100), cog, 14
        )

    def _send_attitude(self) -> None:
        body = self.autopilot.body
        roll, pitch = self.autopilot.attitude
        self.mav.attitude_send(self._boot_ms(), roll, pitch, body.yaw, 0.0, 0.0, body.yaw_rate)

    def _send_local_position(self) -> None:
        ap = self.autopilot
        if not ap.position_valid:
            return  # PX4 sends LOCAL_POSITION_NED only with a valid estimate (LOCAL_POSITION_NED.hpp)
        n, e, d = self._local_ned(ap.position)
        vn, ve, vd = geo.enu_to_ned(tuple(ap.velocity))
        self.mav.local_position_ned_send(self._boot_ms(), n, e, d, vn, ve, vd)

    def _send_global_position(self) -> None:
        ap = self.autopilot
        geodetic = self._geo(ap.position)
        if geodetic is None:
            return
        lat, lon, alt = geodetic
        vn, ve, vd = (_clamp_int16(v * 100) for v in geo.enu_to_ned(tuple(ap.velocity)))
        heading = round(math.degrees(ap.body.yaw) % 360 * 100) % 36000
        self.mav.global_position_int_send(self._boot_ms(), lat, lon, alt, round(ap.height * 1000), vn, ve, vd, heading)

    def _send_autopilot_version(self) -> None:
        self.mav.autopilot_version_send(_CAPABILITIES, _PX4_VERSION, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, self.id)

    # --- commands ----------------------------------------------------------------------------------------------

    def _on_command_long(self, msg: mavlink.MAVLink_command_long_message) -> None:
        if not self._for_me(msg):
            return
        self._run(
            _Command(
                msg.command,
                (msg.param1, msg.param2, msg.param3, msg.param4),
                msg.param5,
                msg.param6,
                msg.param7,
                mavlink.MAV_FRAME_GLOBAL,
                (msg.get_srcSystem(), msg.get_srcComponent()),
            )
        )

    def _on_command_int(self, msg: mavlink.MAVLink_command_int_message) -> None:
        if not self._for_me(msg):
            return
        lat = math.nan if msg.x == INT32_MAX else msg.x / 1e7
        lon = math.nan if msg.y == INT32_MAX else msg.y / 1e7
        self._run(
            _Command(
                msg.command,
                (msg.param1, msg.param2, msg.param3, msg.param4),
                lat,
                lon,
                msg.z,
                msg.frame,
                (msg.get_srcSystem(), msg.get_srcComponent()),
            )
        )

    def _run(self, cmd: _Command) -> None:
        handler = self._commands.get(cmd.command)
        if handler is None:
            _log.debug("vehicle %d: unsupported command %d", self.id, cmd.command)
        self._ack(cmd, handler(self, cmd) if handler else UNSUPPORTED)

    def _cmd_arm_disarm(self, cmd: _Command) -> int:
        force = _as_int(cmd.params[1]) == FORCE_MAGIC
        if _as_int(cmd.params[0]) == 1:
            return self.autopilot.arm(self._now, force)
        return self.autopilot.disarm(force)

    def _cmd_takeoff(self, cmd: _Command) -> int:
        if not math.isfinite(cmd.z):
            return self.autopilot.takeoff(None)  # MAVSDK in PX4 mode: use MIS_TAKEOFF_ALT
        return self.autopilot.takeoff(self._world_z(cmd.z, cmd.frame) - self.home[2])

    def _cmd_land(self, cmd: _Command) -> int:
        return self.autopilot.land()

    def _cmd_rtl(self, cmd: _Command) -> int:
        return self.autopilot.return_to_launch()

    def _cmd_set_mode(self, cmd: _Command) -> int:
        base, main, sub = (_as_int(p) for p in cmd.params[:3])
        if not base & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return DENIED
        mode = FlightMode.from_px4(main, sub)
        return self.autopilot.set_mode(mode, self._now) if mode else REJECTED

    def _cmd_reposition(self, cmd: _Command) -> int:
        if cmd.frame not in _GLOBAL_FRAMES:
            return UNSUPPORTED
        here = self._geo(self.autopilot.position)
        if here is None:
            return self.autopilot.reposition(self.autopilot.position, None, None)  # refused: no global position
        lat = cmd.lat if math.isfinite(cmd.lat) else here[0] / 1e7
        lon = cmd.lon if math.isfinite(cmd.lon) else here[1] / 1e7
        x, y, _ = self._from_geo(lat, lon, 0.0)  # type: ignore[misc]
        z = self._world_z(cmd.z, cmd.frame) if math.isfinite(cmd.z) else math.nan
        speed = cmd.params[0] if math.isfinite(cmd.params[0]) and cmd.params[0] > 0 else None
        yaw = cmd.params[3] if math.isfinite(cmd.params[3]) else None
        return self.autopilot.reposition(np.array([x, y, z]), yaw, speed)

    def _cmd_change_speed(self, cmd: _Command) -> int:
        if _as_int(cmd.params[0]) in (mavlink.SPEED_TYPE_AIRSPEED, mavlink.SPEED_TYPE_GROUNDSPEED):
            return self.autopilot.change_speed(cmd.params[1] if math.isfinite(cmd.params[1]) else -1.0)
        return ACCEPTED  # climb/descent speed: PX4 accepts and ignores it in most modes

    def _cmd_message_interval(self, cmd: _Command) -> int:
        stream = self._streams.get(_as_int(cmd.params[0], -1))
        interval_us = cmd.params[1]
        if stream is None or not math.isfinite(interval_us):
            return UNSUPPORTED
        if interval_us < 0:
            stream.interval = None
        else:
            stream.interval = stream.default_interval if interval_us == 0 else interval_us / 1e6
            stream.due = self._now
        return ACCEPTED

    def _cmd_request_message(self, cmd: _Command) -> int:
        sender = self._senders.get(_as_int(cmd.params[0], -1))
        if sender is None:
            return UNSUPPORTED
        sender()
        return ACCEPTED

    def _cmd_request_capabilities(self, cmd: _Command) -> int:
        self._send_autopilot_version()
        return ACCEPTED

    def _world_z(self, alt: float, frame: int) -> float:
        """World z of a command altitude: AMSL, or relative to home in the relative-altitude frames."""
        if frame in _RELATIVE_ALT_FRAMES:
            return self.home[2] + alt
        globe = self._globe()
        if globe is None:
            return math.nan
        return geo.geo_to_world(globe[0], globe[0].lat_deg, globe[0].lon_deg, alt)[2] + globe[1][2]

    # --- setpoints ---------------------------------------------------------------------------------------------

    def _on_local_setpoint(self, msg: mavlink.MAVLink_set_position_target_local_ned_message) -> None:
        if not self._for_me(msg) or msg.coordinate_frame not in _LOCAL_FRAMES:
            return
        mask = msg.type_mask
        pos_ned = _masked((msg.x, msg.y, msg.z), mask, 1)
        vel_ned = _masked((msg.vx, msg.vy, msg.vz), mask, 8)
        ap = self.autopilot
        frame = msg.coordinate_frame
        if frame in (mavlink.MAV_FRAME_BODY_NED, mavlink.MAV_FRAME_BODY_OFFSET_NED):
            pos_ned, vel_ned = _body_to_ned(pos_ned, ap.body.yaw), _body_to_ned(vel_ned, ap.body.yaw)
        position = np.array(geo.ned_to_enu(tuple(pos_ned)))
        if frame == mavlink.MAV_FRAME_LOCAL_NED:
            position = position + ap.local_origin
        else:
            position = position + ap.position  # offset frames are relative to the current position
        velocity = np.array(geo.ned_to_enu(tuple(vel_ned)))
        self._set_setpoint(position, velocity, mask, msg.yaw, msg.yaw_rate)

    def _on_global_setpoint(self, msg: mavlink.MAVLink_set_position_target_global_int_message) -> None:
        if not self._for_me(msg) or msg.coordinate_frame not in _GLOBAL_FRAMES:
            return
        point = self._from_geo(msg.lat_int / 1e7, msg.lon_int / 1e7, 0.0)
        if point is None:
            return  # no global position: PX4 cannot place a global setpoint
        mask = msg.type_mask
        x, y = point[0], point[1]
        lat, lon, alt = _masked((y, x, self._world_z(msg.alt, msg.coordinate_frame)), mask, 1)
        position = np.array([lon, lat, alt])
        velocity = np.array(geo.ned_to_enu(tuple(_masked((msg.vx, msg.vy, msg.vz), mask, 8))))
        self._set_setpoint(position, velocity, mask, msg.yaw, msg.yaw_rate)

    def _set_setpoint(self, position: np.ndarray, velocity: np.ndarray, mask: int, yaw: float, rate: float) -> None:
        yaw_target = None if mask & mavlink.POSITION_TARGET_TYPEMASK_YAW_IGNORE else yaw
        rate_target = None if mask & mavlink.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE else rate
        self.autopilot.set_setpoint(Setpoint(position, velocity, yaw_target, rate_target), self._now)

    # --- parameters, pings, missions ---------------------------------------------------------------------------

    def _send_param(self, name: str) -> None:
        self.mav.param_value_send(
            name.encode(),
            self.params.wire_value(name),
            self.params.get(name).type,
            len(self.params),
            self.params.index(name),
        )

    def _on_param_request_list(self, msg: mavlink.MAVLink_param_request_list_message) -> None:
        if self._for_me(msg):
            for name in self.params.names():
                self._send_param(name)

    def _on_param_request_read(self, msg: mavlink.MAVLink_param_request_read_message) -> None:
        if not self._for_me(msg):
            return
        if msg.param_index >= 0:
            names = self.params.names()
            if msg.param_index < len(names):
                self._send_param(names[msg.param_index])
        elif msg.param_id in self.params:
            self._send_param(msg.param_id)

    def _on_param_set(self, msg: mavlink.MAVLink_param_set_message) -> None:
        if self._for_me(msg) and self.params.set_wire(msg.param_id, msg.param_value):
            self._send_param(msg.param_id)  # the echo is the acknowledgement (unknown names get none, as PX4)

    def _on_set_gps_global_origin(self, msg: mavlink.MAVLink_set_gps_global_origin_message) -> None:
        """Place the local origin on the globe (PX4's EKF2 takes it while GPS does not fix the origin)."""
        if msg.target_system not in (0, self.id) or self.autopilot.gps:
            return
        self.autopilot.global_origin = GeoOrigin(
            lat_deg=msg.latitude / 1e7, lon_deg=msg.longitude / 1e7, alt_amsl_m=msg.altitude / 1000
        )
        self._send_gps_global_origin()

    def _on_ping(self, msg: mavlink.MAVLink_ping_message) -> None:
        if msg.target_system == 0:  # a request; a non-zero target is a reply to someone
            self.mav.ping_send(msg.time_usec, msg.seq, msg.get_srcSystem(), msg.get_srcComponent())

    def _on_timesync(self, msg: mavlink.MAVLink_timesync_message) -> None:
        if msg.tc1 == 0:
            self.mav.timesync_send(int(self._now * 1e9), msg.ts1)

    def _on_mission_request_list(self, msg: mavlink.MAVLink_mission_request_list_message) -> None:
        if self._for_me(msg):
            self.mav.mission_count_send(msg.get_srcSystem(), msg.get_srcComponent(), 0, msg.mission_type)

    def _on_mission_count(self, msg: mavlink.MAVLink_mission_count_message) -> None:
        if self._for_me(msg):
            self.mav.mission_ack_send(
                msg.get_srcSystem(), msg.get_srcComponent(), mavlink.MAV_MISSION_UNSUPPORTED, msg.mission_type
            )

    def _on_mission_clear_all(self, msg: mavlink.MAVLink_mission_clear_all_message) -> None:
        if self._for_me(msg):
            self.mav.mission_ack_send(
                msg.get_srcSystem(), msg.get_srcComponent(), mavlink.MAV_MISSION_ACCEPTED, msg.mission_type
            )

    def _for_me(self, msg: mavlink.MAVLink_message) -> bool:
        target = getattr(msg, "target_system", 0)
        component = getattr(msg, "target_component", 0)
        return target in (0, self.id) and component in (0, COMPONENT_ID)

    # Keyed by message type, each handler takes that type's MAVLink_message subclass (hence Any).
    _handlers: dict[str, Callable[[SimVehicle, Any], None]] = {
        "COMMAND_LONG": _on_command_long,
        "COMMAND_INT": _on_command_int,
        "SET_POSITION_TARGET_LOCAL_NED": _on_local_setpoint,
        "SET_POSITION_TARGET_GLOBAL_INT": _on_global_setpoint,
        "PARAM_REQUEST_LIST": _on_param_request_list,
        "PARAM_REQUEST_READ": _on_param_request_read,
        "PARAM_SET": _on_param_set,
        "SET_GPS_GLOBAL_ORIGIN": _on_set_gps_global_origin,
        "PING": _on_ping,
        "TIMESYNC": _on_timesync,
        "MISSION_REQUEST_LIST": _on_mission_request_list,
        "MISSION_COUNT": _on_mission_count,
        "MISSION_CLEAR_ALL": _on_mission_clear_all,
    }
    _commands: dict[int, Callable[[SimVehicle, _Command], int]] = {
        mavlink.MAV_CMD_COMPONENT_ARM_DISARM: _cmd_arm_disarm,
        mavlink.MAV_CMD_NAV_TAKEOFF: _cmd_takeoff,
        mavlink.MAV_CMD_NAV_LAND: _cmd_land,
        mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH: _cmd_rtl,
        mavlink.MAV_CMD_DO_SET_MODE: _cmd_set_mode,
        mavlink.MAV_CMD_DO_REPOSITION: _cmd_reposition,
        mavlink.MAV_CMD_DO_CHANGE_SPEED: _cmd_change_speed,
        mavlink.MAV_CMD_SET_MESSAGE_INTERVAL: _cmd_message_interval,
        mavlink.MAV_CMD_REQUEST_MESSAGE: _cmd_request_message,
        mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: _cmd_request_capabilities,
    }


def _new_parser() -> mavlink.MAVLink:
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True  # garbage on the port must not raise
    return parser


def _masked(values: Vec3, mask: int, first_bit: int) -> np.ndarray:
    """The three values with NaN where the type mask ignores them (bits first_bit, <<1, <<2)."""
    out = np.array(values, dtype=np.float64)
    for axis in range(3):
        if mask & (first_bit << axis):
            out[axis] = np.nan
    return out


def _body_to_ned(v: np.ndarray, yaw: float) -> np.ndarray:
    """Rotate a body (forward, right, down) vector to NED; a horizontal pair with one NaN is read as 0."""
    if np.isnan(v[0]) and np.isnan(v[1]):
        return v
    f, r = np.nan_to_num(v[:2])
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([f * c - r * s, f * s + r * c, v[2]])


def _as_int(value: float, default: int = 0) -> int:
    """A command parameter as an integer; NaN ("unset" in MAVLink) gives the default."""
    return round(value) if math.isfinite(value) else default


def _clamp_int16(v: float) -> int:
    return max(-32768, min(32767, round(v)))


def _rounded(v: np.ndarray) -> list[float]:
    return [round(float(c), 3) + 0.0 for c in v]
