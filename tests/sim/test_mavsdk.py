"""A real MAVSDK 4 client (asyncio API) flies a simulated vehicle: the simulator is a PX4 as far as MAVSDK knows.

Every MAVSDK call is awaited to completion before `destroy()`: destroying while a call is in flight leaves its
worker thread blocked in C forever.
"""

import asyncio
import time
from concurrent.futures import ThreadPoolExecutor

import mavsdk
import pytest
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.offboard import OffboardAsync, PositionNedYaw
from mavsdk.asyncio.plugins.telemetry import FlightMode, LandedState, TelemetryAsync

from swarm.config import gcs_port
from swarm.sim.worlds import World
from tests.sim.support import running_sim, sim_config

pytestmark = pytest.mark.sim


async def poll(read, condition, timeout: float, what: str):
    """Poll a latest-value telemetry read until condition(value) holds."""
    deadline = time.monotonic() + timeout
    while True:
        value = await read()
        if condition(value):
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what} (last: {value})")
        await asyncio.sleep(0.05)


@pytest.mark.timeout(90)
async def test_mavsdk_flies_the_simulated_vehicle(port_base: int, box_world: World) -> None:
    asyncio.get_running_loop().set_default_executor(ThreadPoolExecutor(16))
    mavsdk.log_subscribe(lambda *args: True)
    config = sim_config(port_base)
    started = time.monotonic()
    with running_sim(config, box_world) as server:
        sdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
        try:
            await sdk.add_any_connection(f"udpin://0.0.0.0:{gcs_port(config.sim, 1)}")
            drone = await sdk.first_autopilot(timeout_s=10.0)
            assert drone is not None
            action, offboard, telemetry = ActionAsync(drone), OffboardAsync(drone), TelemetryAsync(drone)

            await poll(telemetry.health_all_ok, bool, 10, "health_all_ok")
            assert (await telemetry.health()).is_armable
            await action.set_takeoff_altitude(2.0)
            assert await action.get_takeoff_altitude() == pytest.approx(2.0)

            await action.arm()
            assert await telemetry.armed()  # the heartbeat came before the ACK
            await action.takeoff()
            await poll(telemetry.position_velocity_ned, lambda pv: pv.position.down_m < -1.9, 10, "takeoff altitude")
            await poll(telemetry.flight_mode, lambda m: m == FlightMode.HOLD, 5, "hold after takeoff")
            assert await telemetry.landed_state() == LandedState.IN_AIR

            await offboard.set_position_ned(PositionNedYaw(1.0, 1.5, -1.5, 90.0))
            await offboard.start()
            assert await telemetry.flight_mode() == FlightMode.OFFBOARD

            def reached(pv) -> bool:
                p = pv.position
                return abs(p.north_m - 1.0) < 0.1 and abs(p.east_m - 1.5) < 0.1 and abs(p.down_m + 1.5) < 0.1

            await poll(telemetry.position_velocity_ned, reached, 10, "offboard setpoint")
            await offboard.stop()
            assert await telemetry.flight_mode() == FlightMode.HOLD

            await action.land()
            await poll(telemetry.armed, lambda armed: not armed, 15, "disarm after landing")
            assert await telemetry.landed_state() == LandedState.ON_GROUND
        finally:
            sdk.destroy()
        vehicle = server.status()["vehicles"][0]
        assert vehicle["position"][2] == 0.0 and vehicle["distance_m"] > 4.0
        assert vehicle["gcs_seen"] and server.status()["collisions"] == 0
    assert time.monotonic() - started < 30
