"""The simulated PX4 on the wire, driven by a pymavlink ground station over loopback UDP."""

import json
import math
import socket
import struct
import threading
import time

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

from swarm.config import SITL_GCS_PORTS, gcs_port, sim_autopilot_url, vehicle_port
from swarm.errors import PortInUseError
from swarm.sim.px4 import FlightMode
from swarm.sim.server import run_simulator
from swarm.sim.worlds import World
from tests.sim.support import ACCEPTED, NAN, gcs, running_sim, sim_config, wait_until

pytestmark = pytest.mark.sim

OFFBOARD = FlightMode.OFFBOARD.custom_mode
HOLD = FlightMode.HOLD.custom_mode


def _armed(hb) -> bool:
    return bool(hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)


def test_pymavlink_arm_and_takeoff(port_base: int, box_world: World) -> None:
    config = sim_config(port_base)
    with running_sim(config, box_world), gcs(gcs_port(config.sim, 1)) as gs:
        hb = gs.heartbeat()
        assert hb.get_srcSystem() == 1 and hb.get_srcComponent() == 1
        assert hb.autopilot == mavlink.MAV_AUTOPILOT_PX4 and hb.type == mavlink.MAV_TYPE_QUADROTOR
        assert not _armed(hb) and hb.custom_mode == HOLD
        sys_status = gs.recv_until(lambda m: True, 3, "SYS_STATUS", "SYS_STATUS")
        assert sys_status.onboard_control_sensors_health & mavlink.MAV_SYS_STATUS_PREARM_CHECK
        assert sys_status.onboard_control_sensors_health & mavlink.MAV_SYS_STATUS_SENSOR_GPS
        state = gs.recv_until(lambda m: True, 3, "EXTENDED_SYS_STATE", "EXTENDED_SYS_STATE")
        assert state.landed_state == mavlink.MAV_LANDED_STATE_ON_GROUND

        ack = gs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        assert ack.result == ACCEPTED and (ack.target_system, ack.target_component) == (245, 190)
        assert _armed(gs.latest("HEARTBEAT"))  # the state change arrived before the ACK

        ack = gs.command(mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, NAN, NAN, NAN)
        assert ack.result == ACCEPTED
        assert gs.latest("HEARTBEAT").custom_mode == FlightMode.TAKEOFF.custom_mode
        assert gs.latest("EXTENDED_SYS_STATE").landed_state == mavlink.MAV_LANDED_STATE_TAKEOFF
        target = config.sim.takeoff_alt_m
        gs.recv_until(lambda m: -m.z > target - 0.1, 8, "altitude", "LOCAL_POSITION_NED")
        gs.recv_until(lambda m: m.landed_state == mavlink.MAV_LANDED_STATE_IN_AIR, 5, "in air", "EXTENDED_SYS_STATE")
        glob = gs.recv_until(lambda m: True, 2, "GLOBAL_POSITION_INT", "GLOBAL_POSITION_INT")
        assert glob.relative_alt == pytest.approx(target * 1000, abs=120)
        assert glob.alt == pytest.approx((config.mission.origin.alt_amsl_m + target) * 1000, abs=120)


def test_params_ping_timesync_missions_and_unknown_commands(port_base: int, box_world: World) -> None:
    config = sim_config(port_base)
    with running_sim(config, box_world), gcs(gcs_port(config.sim, 1)) as gs:
        gs.heartbeat()
        mav = gs.conn.mav
        mav.param_set_send(1, 1, b"MIS_TAKEOFF_ALT", 2.5, mavlink.MAV_PARAM_TYPE_REAL32)
        echo = gs.recv_until(lambda m: m.param_id == "MIS_TAKEOFF_ALT", 2, "PARAM_VALUE echo", "PARAM_VALUE")
        assert echo.param_value == 2.5
        mav.param_request_read_send(1, 1, b"MPC_XY_VEL_MAX", -1)
        value = gs.recv_until(lambda m: m.param_id == "MPC_XY_VEL_MAX", 2, "PARAM_VALUE", "PARAM_VALUE")
        assert value.param_value == pytest.approx(config.sim.max_speed_xy_m_s)
        mav.param_request_list_send(1, 1)
        names = set()
        first = gs.recv_until(
            lambda m: names.add(m.param_id) or len(names) == m.param_count, 3, "all params", "PARAM_VALUE"
        )
        assert {"MIS_TAKEOFF_ALT", "MPC_XY_VEL_MAX", "MAV_SYS_ID", "COM_OF_LOSS_T"} <= names
        assert first.param_count == len(names)
        mav.param_request_read_send(1, 1, b"MAV_SYS_ID", -1)
        sysid = gs.recv_until(lambda m: m.param_id == "MAV_SYS_ID", 2, "MAV_SYS_ID", "PARAM_VALUE")
        assert struct.unpack("<i", struct.pack("<f", sysid.param_value))[0] == 1  # ints travel bytewise

        mav.ping_send(123456, 7, 0, 0)
        pong = gs.recv_until(lambda m: m.seq == 7, 2, "PING reply", "PING")
        assert (pong.time_usec, pong.target_system, pong.target_component) == (123456, 245, 190)
        mav.timesync_send(0, 987654321)
        sync = gs.recv_until(lambda m: m.ts1 == 987654321, 2, "TIMESYNC reply", "TIMESYNC")
        assert sync.tc1 > 0
        mav.mission_request_list_send(1, 1)
        count = gs.recv_until(lambda m: True, 2, "MISSION_COUNT", "MISSION_COUNT")
        assert count.count == 0 and count.target_system == 245

        ack = gs.command(mavlink.MAV_CMD_DO_SET_ROI_LOCATION, 0, 0, 0, 0, 1, 1, 1)
        assert ack.result == mavlink.MAV_RESULT_UNSUPPORTED
        ack = gs.command(mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
        assert ack.result == ACCEPTED
        version = gs.latest("AUTOPILOT_VERSION")  # sent before the ACK, as PX4 does
        assert version.capabilities & mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
        ack = gs.command(mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_HOME_POSITION)
        assert ack.result == ACCEPTED
        home = gs.latest("HOME_POSITION")
        assert home.altitude == round(config.mission.origin.alt_amsl_m * 1000)


def test_set_message_interval(port_base: int, box_world: World) -> None:
    config = sim_config(port_base)
    with running_sim(config, box_world), gcs(gcs_port(config.sim, 1)) as gs:
        gs.heartbeat()
        ack = gs.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED, 40000)
        assert ack.result == ACCEPTED
        ack = gs.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink.MAVLINK_MSG_ID_ATTITUDE, -1)
        assert ack.result == ACCEPTED
        counts = {"LOCAL_POSITION_NED": 0, "ATTITUDE": 0}
        started = time.monotonic()
        while time.monotonic() - started < 1.0:  # an observation window: counting a rate needs one
            msg = gs.conn.recv_match(type=list(counts), blocking=True, timeout=0.1)
            if msg is not None:
                counts[msg.get_type()] += 1
        assert 20 <= counts["LOCAL_POSITION_NED"] <= 30
        assert counts["ATTITUDE"] <= 1  # one may have been in flight


def test_offboard_setpoints_and_offboard_loss(port_base: int, box_world: World) -> None:
    config = sim_config(port_base, **{"sim.offboard_timeout_s": 0.5})
    with running_sim(config, box_world) as server, gcs(gcs_port(config.sim, 1)) as gs:
        gs.heartbeat()
        hold_on_loss = struct.unpack("<f", struct.pack("<i", 5))[0]  # COM_OBL_RC_ACT = 5 (Hold), INT32 bytewise
        gs.conn.mav.param_set_send(1, 1, b"COM_OBL_RC_ACT", hold_on_loss, mavlink.MAV_PARAM_TYPE_INT32)
        gs.recv_until(lambda m: m.param_id == "COM_OBL_RC_ACT", 2, "PARAM_VALUE echo", "PARAM_VALUE")
        set_mode = (mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 6)
        gs.conn.mav.command_long_send(1, 1, *set_mode[:1], 0, *set_mode[1:], 0, 0, 0, 0, 0)
        chunks = []  # the reason comes before the ACK, in chunks of 50 characters with one id
        while True:
            msg = gs.recv_until(lambda m: True, 3, "STATUSTEXT then ACK", ["STATUSTEXT", "COMMAND_ACK"])
            if msg.get_type() == "COMMAND_ACK":
                break
            chunks.append(msg)
        assert msg.result == mavlink.MAV_RESULT_TEMPORARILY_REJECTED  # no setpoint yet: what PX4 answers
        assert len(chunks) == 2 and chunks[0].id == chunks[1].id != 0 and [c.chunk_seq for c in chunks] == [0, 1]
        text = "".join(c.text for c in chunks)
        assert text == "Offboard refused: setpoints must stream at 2 Hz, no setpoint yet"
        mask = (
            mavlink.POSITION_TARGET_TYPEMASK_VX_IGNORE
            | mavlink.POSITION_TARGET_TYPEMASK_VY_IGNORE
            | mavlink.POSITION_TARGET_TYPEMASK_VZ_IGNORE
            | mavlink.POSITION_TARGET_TYPEMASK_AX_IGNORE
            | mavlink.POSITION_TARGET_TYPEMASK_AY_IGNORE
            | mavlink.POSITION_TARGET_TYPEMASK_AZ_IGNORE
            | mavlink.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE
        )

        def setpoint() -> None:  # 1 m north, 0.5 m east, 1.2 m up, facing east
            gs.conn.mav.set_position_target_local_ned_send(
                0, 1, 1, mavlink.MAV_FRAME_LOCAL_NED, mask, 1.0, 0.5, -1.2, 0, 0, 0, 0, 0, 0, math.pi / 2, 0
            )

        setpoint()
        assert gs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == ACCEPTED
        assert gs.command(*set_mode).result == ACCEPTED
        assert gs.latest("HEARTBEAT").custom_mode == OFFBOARD

        def arrived(m) -> bool:
            setpoint()
            return abs(m.x - 1.0) < 0.05 and abs(m.y - 0.5) < 0.05 and abs(m.z + 1.2) < 0.05

        gs.recv_until(arrived, 10, "the setpoint", "LOCAL_POSITION_NED")
        home = server.status()["vehicles"][0]["home"]
        position = server.status()["vehicles"][0]["position"]
        assert position == pytest.approx([home[0] + 0.5, home[1] + 1.0, home[2] + 1.2], abs=0.06)  # NED -> world
        attitude = gs.recv_until(lambda m: True, 2, "ATTITUDE", "ATTITUDE")
        assert attitude.yaw == pytest.approx(math.pi / 2, abs=0.05)
        # no more setpoints: COM_OBL_RC_ACT = 5, Hold
        hb = gs.recv_until(lambda m: m.custom_mode != OFFBOARD, 3, "offboard loss", "HEARTBEAT")
        assert hb.custom_mode == HOLD and _armed(hb)


def test_reposition_with_command_int(port_base: int, box_world: World) -> None:
    fast = {
        "sim.takeoff_alt_m": 1.0,
        "sim.max_speed_down_m_s": 2.0,
        "sim.land_speed_m_s": 1.5,
        "sim.position_gain_xy": 3.0,
        "sim.position_gain_z": 3.0,
        "sim.velocity_gain_xy": 8.0,
        "sim.velocity_gain_z": 12.0,
    }
    config = sim_config(port_base, **fast)
    with running_sim(config, box_world) as server, gcs(gcs_port(config.sim, 1)) as gs:
        gs.heartbeat()
        gs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        gs.command(mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, NAN, NAN, NAN)
        gs.recv_until(lambda m: m.custom_mode == HOLD, 8, "takeoff done", "HEARTBEAT")
        home = gs.recv_until(lambda m: True, 3, "HOME_POSITION", "HOME_POSITION")
        lat = home.latitude + round(1.0 / 6378137.0 * 180 / math.pi * 1e7)  # 1 m north
        ack = gs.command_int(
            mavlink.MAV_CMD_DO_REPOSITION,
            mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
            (-1, 0, 0, NAN),
            lat,
            home.longitude,
            1.0,
        )
        assert ack.result == ACCEPTED
        gs.recv_until(
            lambda m: abs(m.x - 1.0) < 0.05 and abs(m.z + 1.0) < 0.05, 8, "reposition target", "LOCAL_POSITION_NED"
        )
        assert server.status()["vehicles"][0]["mode"] == "HOLD"
        assert gs.command(mavlink.MAV_CMD_NAV_LAND).result == ACCEPTED
        hb = gs.recv_until(lambda m: not _armed(m), 10, "auto-disarm after landing", "HEARTBEAT")
        assert gs.latest("EXTENDED_SYS_STATE").landed_state == mavlink.MAV_LANDED_STATE_ON_GROUND
        assert hb.custom_mode == HOLD


def test_silenced_telemetry_and_learned_peer(port_base: int, box_world: World) -> None:
    config = sim_config(port_base)
    with running_sim(config, box_world) as server:
        vport = vehicle_port(config.sim, 1)
        # a udpout-style client: the vehicle answers whoever talks to it, whatever port that is
        client = mavutil.mavlink_connection(
            f"udpout:127.0.0.1:{vport}", source_system=245, source_component=190, dialect="common"
        )
        try:
            garbage = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            garbage.sendto(b"\xfd\x09garbage that is no MAVLink" * 3, ("127.0.0.1", vport))
            garbage.close()

            def heartbeat_within(seconds: float) -> bool:
                deadline = time.monotonic() + seconds
                while time.monotonic() < deadline:
                    client.mav.heartbeat_send(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
                    if client.recv_match(type="HEARTBEAT", blocking=True, timeout=0.1) is not None:
                        return True
                return False

            assert heartbeat_within(5.0)
            assert server.status()["vehicles"][0]["gcs_seen"]
            server.set_telemetry_enabled(1, False)
            while client.recv_match(blocking=False) is not None:  # drop what was already queued
                pass
            assert not heartbeat_within(1.5)  # > 2 heartbeat periods of silence
            assert server.status()["vehicles"][0]["last_gcs_message_age_s"] < 0.5  # commands still arrive
            server.set_telemetry_enabled(1, True)
            assert heartbeat_within(2.0)
        finally:
            client.close()


def test_status_file_and_endpoints(port_base: int, box_world: World, tmp_path) -> None:
    path = tmp_path / "run" / "sim.json"
    config = sim_config(port_base, **{"mission.drones": 2, "sim.status_path": str(path)})
    stop = threading.Event()
    endpoints: list[list[dict]] = []
    result: dict = {}
    thread = threading.Thread(
        target=lambda: result.update(run_simulator(config, box_world, stop, on_ready=endpoints.append))
    )
    thread.start()
    try:
        wait_until(path.exists, 5, "status file")
        status = json.loads(path.read_text())
        assert status["ready"] and not status["done"] and status["world"] == "box"
        assert [v["id"] for v in status["vehicles"]] == [1, 2]
        vehicle = status["vehicles"][1]
        assert vehicle["vehicle_port"] == port_base + 1 and vehicle["gcs_port"] == port_base + 21
        assert vehicle["mode"] == "HOLD" and vehicle["landed_state"] == "on_ground" and not vehicle["armed"]
        assert vehicle["gcs_seen"] is False and vehicle["last_gcs_message_age_s"] is None
        assert set(vehicle) == {
            "id",
            "vehicle_port",
            "gcs_port",
            "home",
            "position",
            "velocity",
            "armed",
            "mode",
            "landed_state",
            "distance_m",
            "battery",
            "global_position",
            "local_origin",
            "collisions",
            "closest_world_m",
            "closest_world_at",
            "closest_drone_m",
            "gcs_seen",
            "last_gcs_message_age_s",
        }
    finally:
        stop.set()
        thread.join(timeout=10)
    assert not thread.is_alive()
    final = json.loads(path.read_text())
    assert final["done"] and result["done"]
    assert endpoints == [
        [
            {
                "id": k,
                "sysid": k,
                "vehicle_port": port_base + k - 1,
                "gcs_port": port_base + 19 + k,
                "host": "127.0.0.1",
                "connect_url": f"udpin://0.0.0.0:{port_base + 19 + k}",
            }
            for k in (1, 2)
        ]
    ]
    assert not list(path.parent.glob(".*.tmp"))


@pytest.mark.parametrize("taken", ["vehicle", "gcs"])
def test_port_in_use(port_base: int, box_world: World, taken: str) -> None:
    config = sim_config(port_base, **{"mission.drones": 3})
    port = vehicle_port(config.sim, 2) if taken == "vehicle" else gcs_port(config.sim, 3)
    holder = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    holder.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as MAVSDK binds
    holder.bind(("0.0.0.0", port))
    try:
        with pytest.raises(PortInUseError) as info:
            run_simulator(config, box_world, threading.Event())
    finally:
        holder.close()
    message = str(info.value)
    assert f"UDP port {port}" in message and "already in use" in message and "\n" not in message
    # nothing stays bound after the failure
    for k in (1, 2, 3):
        probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        probe.bind(("127.0.0.1", vehicle_port(config.sim, k)))
        probe.close()


def test_a_stalled_simulator_loop_is_reported_in_its_status(port_base: int, box_world: World) -> None:
    """A mission whose agents all failed safe at once had its simulator silent for 2 s; the status now says when
    the loop ran late (the process or the machine did not run) and for how long."""
    with running_sim(sim_config(port_base), box_world) as server, gcs(gcs_port(server.config.sim, 1)) as ground:
        ground.heartbeat()
        assert server.status()["stalls"] == []
        with server._lock:  # the loop cannot step, answer or send while we hold it
            time.sleep(0.8)
        wait_until(lambda: server.status()["stalls"] != [], 2.0, "the stall to be reported")
        [stall] = server.status()["stalls"]
        assert 0.7 <= stall["s"] < 2.0


def test_vehicles_from_ten_up_share_the_last_gcs_port_and_are_reached_by_dialling_them(
    port_base: int, box_world: World
) -> None:
    """As PX4 SITL (px4-rc.mavlink): instance i sends to 14540 + i, capped at 14549, so vehicles 10, 11 and 12
    all send to the tenth GCS port; each still answers whoever talks to it, so its agent dials its vehicle port."""
    config = sim_config(port_base, **{"mission.drones": 12, "mission.spawn_spacing_m": 1.0})
    shared = gcs_port(config.sim, SITL_GCS_PORTS)
    assert [gcs_port(config.sim, k) for k in (9, 10, 11, 12)] == [shared - 1, shared, shared, shared]
    assert [sim_autopilot_url(config.sim, k).split(":")[0] for k in (9, 10, 12)] == ["udpin", "udpout", "udpout"]
    with running_sim(config, box_world) as server, gcs(shared) as listener:
        heard: set[int] = set()
        deadline = time.monotonic() + 5.0
        while heard != {10, 11, 12} and time.monotonic() < deadline:
            msg = listener.conn.recv_match(type="HEARTBEAT", blocking=True, timeout=0.1)
            if msg is not None:
                heard.add(msg.get_srcSystem())
        assert heard == {10, 11, 12}  # one port, three vehicles, told apart by their sysid
        urls = {ep["id"]: ep["connect_url"] for ep in server.endpoints()}
        assert urls[9] == f"udpin://0.0.0.0:{shared - 1}"
        assert urls[12] == f"udpout://127.0.0.1:{vehicle_port(config.sim, 12)}"
        client = mavutil.mavlink_connection(
            f"udpout:127.0.0.1:{vehicle_port(config.sim, 12)}", source_system=245, source_component=190
        )
        try:
            deadline = time.monotonic() + 5.0
            answered = None
            while answered is None and time.monotonic() < deadline:
                client.mav.heartbeat_send(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
                answered = client.recv_match(type="HEARTBEAT", blocking=True, timeout=0.1)
            assert answered is not None and answered.get_srcSystem() == 12
        finally:
            client.close()
