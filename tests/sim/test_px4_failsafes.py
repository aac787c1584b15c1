"""PX4's failsafes on the simulated vehicle, driven by a real MAVSDK client over UDP loopback: what happens to a
drone when the process flying it in offboard dies (its setpoints and GCS heartbeats stop), for the parameter
values that matter (swarm/agent/px4_failsafe.py), and when its battery runs low. The client's death is
`Mavsdk.destroy()`, after every call ended.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import time
from collections.abc import AsyncIterator, Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import mavsdk
import pytest
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync, ActionError
from mavsdk.asyncio.plugins.mavlink_direct import MavlinkDirectAsync
from mavsdk.asyncio.plugins.offboard import OffboardAsync, PositionNedYaw
from mavsdk.asyncio.plugins.param import ParamAsync
from mavsdk.asyncio.plugins.telemetry import FlightMode, TelemetryAsync
from mavsdk.plugins.mavlink_direct import MavlinkMessage

from swarm.config import gcs_port
from swarm.sim.server import SimServer
from swarm.sim.worlds import World
from tests.sim.support import running_sim, sim_config

pytestmark = [pytest.mark.sim, pytest.mark.timeout(90)]

FLIGHT_ALT_M = 1.5


async def until(condition: Callable[[], Any], timeout: float, what: str) -> Any:
    deadline = time.monotonic() + timeout
    while not (value := condition()):
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        await asyncio.sleep(0.05)
    return value


def vehicle(server: SimServer) -> dict[str, Any]:
    return server.status()["vehicles"][0]


def height(server: SimServer) -> float:
    v = vehicle(server)
    return float(v["position"][2] - v["home"][2])


async def connect(port: int, armable: bool = True) -> tuple[Mavsdk, Any]:
    """A MAVSDK ground station on `port`, once the vehicle is healthy (and armable, unless told it is not)."""
    asyncio.get_running_loop().set_default_executor(ThreadPoolExecutor(16))
    mavsdk.log_subscribe(lambda *args: True)
    sdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
    await sdk.add_any_connection(f"udpin://127.0.0.1:{port}")
    drone = await sdk.first_autopilot(timeout_s=10.0)
    assert drone is not None
    telemetry = TelemetryAsync(drone)
    deadline = time.monotonic() + 10
    while not (await telemetry.health_all_ok() if armable else (await telemetry.health()).is_local_position_ok):
        assert time.monotonic() < deadline, "vehicle not healthy"
        await asyncio.sleep(0.1)
    return sdk, drone


async def battery_percent(drone: Any) -> float:
    """The first battery report MAVSDK hands on (percent in MAVSDK 4, BATTERY_STATUS.battery_remaining)."""
    async for battery in TelemetryAsync(drone).subscribe_battery():
        return float(battery.remaining_percent)
    raise AssertionError("the battery stream ended")


@contextlib.asynccontextmanager
async def status_texts(drone: Any) -> AsyncIterator[list[str]]:
    """Every STATUSTEXT the vehicle sends while in the block (MAVSDK joins the chunks)."""
    texts: list[str] = []

    async def collect() -> None:
        async for status in TelemetryAsync(drone).subscribe_status_text():
            texts.append(status.text)

    collector = asyncio.create_task(collect())
    try:
        yield texts
    finally:
        collector.cancel()
        await asyncio.gather(collector, return_exceptions=True)


async def fly_offboard_then_die(server: SimServer, port: int, ints: dict[str, int]) -> None:
    """Connect, write `ints`, take off, hover in offboard at FLIGHT_ALT_M, then the client dies."""
    sdk, drone = await connect(port)
    try:
        action, offboard, param = ActionAsync(drone), OffboardAsync(drone), ParamAsync(drone)
        for name, value in ints.items():
            await param.set_param_int(name, value)
            assert await param.get_param_int(name) == value
        await action.set_takeoff_altitude(FLIGHT_ALT_M)
        await action.arm()
        await action.takeoff()
        await until(lambda: vehicle(server)["mode"] == "HOLD" and height(server) > FLIGHT_ALT_M - 0.1, 15, "hover")
        await offboard.set_position_ned(PositionNedYaw(0.0, 0.0, -FLIGHT_ALT_M, 0.0))
        await offboard.start()
        await until(lambda: vehicle(server)["mode"] == "OFFBOARD", 3, "offboard")
        await asyncio.sleep(1.0)  # an observation window: the vehicle must stay in offboard while setpoints flow
        assert vehicle(server)["mode"] == "OFFBOARD"
    finally:
        sdk.destroy()  # the agent dies: setpoints and heartbeats stop


async def test_offboard_refused_without_setpoints_and_the_reason_reaches_mavsdk(
    port_base: int, box_world: World
) -> None:
    config = sim_config(port_base)
    with running_sim(config, box_world) as server:
        sdk, drone = await connect(gcs_port(config.sim, 1))
        texts: list[str] = []
        # one plugin, destroyed before the instance: a plugin left to the garbage collector was destroyed in an
        # executor thread after `sdk.destroy()`, and MAVSDK aborted the process (a pytest worker crashed)
        telemetry = TelemetryAsync(drone)

        async def collect() -> None:
            async for status in telemetry.subscribe_status_text():
                texts.append(status.text)

        collector = asyncio.create_task(collect())
        try:
            await ActionAsync(drone).arm()
            # MAVSDK itself refuses offboard.start() without a setpoint: send PX4's DO_SET_MODE (main mode 6) raw
            fields = {"target_system": 1, "target_component": 1, "command": 176, "confirmation": 0}
            fields |= {"param1": 1.0, "param2": 6.0, "param3": 0.0, "param4": 0.0}
            fields |= {"param5": 0.0, "param6": 0.0, "param7": 0.0}
            message = MavlinkMessage("COMMAND_LONG", 245, 190, 1, 1, json.dumps(fields))
            await MavlinkDirectAsync(drone).send_message(message)
            text = await until(lambda: next((t for t in texts if "Offboard refused" in t), None), 5, "STATUSTEXT")
            assert text == "Offboard refused: setpoints must stream at 2 Hz, no setpoint yet"  # chunks joined
            assert await telemetry.flight_mode() != FlightMode.OFFBOARD
            assert vehicle(server)["mode"] == "HOLD"
            await ActionAsync(drone).disarm()
        finally:
            collector.cancel()
            await asyncio.gather(collector, return_exceptions=True)
            telemetry.destroy()
            sdk.destroy()


async def test_agent_death_with_px4_defaults_returns_climbing_to_rtl_return_alt(
    port_base: int, box_world: World
) -> None:
    config = sim_config(port_base)
    with running_sim(config, box_world) as server:
        await fly_offboard_then_die(server, gcs_port(config.sim, 1), {})
        died = time.monotonic()
        await until(lambda: vehicle(server)["mode"] != "OFFBOARD", 3, "the offboard-loss failsafe")
        assert vehicle(server)["mode"] == "RTL"  # COM_OBL_RC_ACT 0 needs RC: NAV_RCL_ACT 2, Return
        assert time.monotonic() - died > 0.9  # COM_OF_LOSS_T = 1 s
        await until(lambda: height(server) > FLIGHT_ALT_M + 1.5, 5, "the climb towards RTL_RETURN_ALT (60 m)")
        assert vehicle(server)["mode"] == "RTL"


@pytest.mark.parametrize(
    "ints",
    [
        {"COM_OBL_RC_ACT": 5, "NAV_RCL_ACT": 1},  # what the agent's px4_params = "set" writes
        {"COM_RCL_EXCEPT": 4},  # Offboard exempt from RC loss: the Position mode falls back to Hold
        {"COM_RC_IN_MODE": 4},  # no RC expected
    ],
)
async def test_agent_death_holds_with_safe_values(port_base: int, box_world: World, ints: dict[str, int]) -> None:
    config = sim_config(port_base)
    with running_sim(config, box_world) as server:
        await fly_offboard_then_die(server, gcs_port(config.sim, 1), ints)
        await until(lambda: vehicle(server)["mode"] != "OFFBOARD", 3, "the offboard-loss failsafe")
        assert vehicle(server)["mode"] == "HOLD"
        where = vehicle(server)["position"]
        await asyncio.sleep(2.0)  # an observation window: it must still hover there, not climb
        assert vehicle(server)["mode"] == "HOLD" and vehicle(server)["armed"]
        assert abs(vehicle(server)["position"][2] - where[2]) < 0.15
        assert height(server) < FLIGHT_ALT_M + 0.3


async def test_data_link_loss_takes_nav_dll_act(port_base: int, box_world: World) -> None:
    config = sim_config(port_base)
    with running_sim(config, box_world) as server:
        ints = {"COM_OBL_RC_ACT": 5, "NAV_DLL_ACT": 3, "COM_DL_LOSS_T": 3}  # offboard loss: Hold; link loss: Land
        await fly_offboard_then_die(server, gcs_port(config.sim, 1), ints)
        died = time.monotonic()
        await until(lambda: vehicle(server)["mode"] == "HOLD", 3, "the offboard-loss Hold")
        await until(lambda: vehicle(server)["mode"] != "HOLD", 6, "the data-link loss failsafe")
        assert vehicle(server)["mode"] == "LAND"
        # no GCS heartbeat for COM_DL_LOSS_T = 3 s; MAVSDK sent one a second, the last up to 1 s before it died
        assert 1.9 < time.monotonic() - died < 4.5
        await until(lambda: not vehicle(server)["armed"], 15, "landed and disarmed")
        assert vehicle(server)["landed_state"] == "on_ground"


@pytest.mark.parametrize(("act", "modes"), [(2, ["LAND"]), (3, ["RTL", "LAND"])])
async def test_a_critical_battery_in_flight_takes_com_low_bat_act_and_says_so(
    port_base: int, box_world: World, act: int, modes: list[str]
) -> None:
    """From 12 % (low already), a battery that hovers for a minute is critical 3 s after arming, emergency 1.2 s
    later: COM_LOW_BAT_ACT 2 lands at critical; 3 returns at critical and lands at emergency."""
    config = sim_config(port_base, **{"sim.battery_start": 0.12, "sim.battery_minutes": 1.0})
    with running_sim(config, box_world) as server:
        sdk, drone = await connect(gcs_port(config.sim, 1))
        try:
            async with status_texts(drone) as texts:
                action, param = ActionAsync(drone), ParamAsync(drone)
                assert await asyncio.wait_for(battery_percent(drone), 5) == 12  # MAVSDK 4 gives percent
                await param.set_param_int("COM_LOW_BAT_ACT", act)
                await action.set_takeoff_altitude(FLIGHT_ALT_M)
                await action.arm()  # a low battery arms
                await action.takeoff()
                seen: list[str] = []

                def mode_changes() -> bool:
                    mode = vehicle(server)["mode"]
                    if mode not in ("TAKEOFF", "HOLD") and mode not in seen:
                        seen.append(mode)
                    return seen == modes

                await until(mode_changes, 10, f"the battery failsafe: {' then '.join(modes)}")
                assert vehicle(server)["battery"] < 0.05 if act == 3 else 0.05 <= vehicle(server)["battery"] < 0.07
                await until(lambda: not vehicle(server)["armed"], 20, "landed and disarmed")
                assert vehicle(server)["landed_state"] == "on_ground"
            failsafes = [t for t in texts if t.startswith("Failsafe")]
            if act == 2:
                assert failsafes[0] == "Failsafe: critical battery level, Land (COM_LOW_BAT_ACT=2)"
            else:
                assert failsafes == [
                    "Failsafe: critical battery level, Return (COM_LOW_BAT_ACT=3)",
                    "Failsafe: emergency battery level, Land (COM_LOW_BAT_ACT=3)",
                ]
            assert any(t.startswith("Low battery level, return advised") for t in texts)
        finally:
            sdk.destroy()


async def test_arming_is_refused_below_the_critical_battery_threshold(port_base: int, box_world: World) -> None:
    config = sim_config(port_base, **{"sim.battery_start": 0.06})
    with running_sim(config, box_world) as server:
        sdk, drone = await connect(gcs_port(config.sim, 1), armable=False)
        try:
            async with status_texts(drone) as texts:
                telemetry = TelemetryAsync(drone)
                assert not (await telemetry.health()).is_armable
                assert await asyncio.wait_for(battery_percent(drone), 5) == 6
                with pytest.raises(ActionError, match="COMMAND_DENIED"):
                    await ActionAsync(drone).arm()
                await until(lambda: any(t.startswith("Arming denied") for t in texts), 5, "the reason")
            assert "Arming denied: critical battery, 6.0% below BAT_CRIT_THR 7.0%" in texts
            assert not vehicle(server)["armed"]
        finally:
            sdk.destroy()
