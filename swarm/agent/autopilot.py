"""One drone's autopilot, reached through the MAVSDK 4 asyncio API.

Works the same against the project's simulated vehicles and a real PX4. Three rules, found by probing MAVSDK 4
against the simulated vehicle, shape this module:

- every plugin call runs in the default executor and may block for seconds in C, so calls are never cancelled:
  `_call` waits with a timeout and, if the call is still running, keeps its task and raises; `close()` waits for
  such stragglers before destroying the Mavsdk instance (destroying it under a running call hangs the process);
- subscriptions feed unbounded queues, so every stream we open is consumed continuously by a task;
- MAVSDK logs to stderr with colours unless silenced, process-wide.

Positions are converted between the autopilot's local NED frame (origin at its local origin) and the shared
world frame (z-up) through the home position, which the autopilot reports both geodetically and locally.
"""

from __future__ import annotations

import asyncio
import functools
import math
import time
from collections.abc import AsyncIterator, Awaitable, Callable
from dataclasses import dataclass
from typing import Any

import mavsdk
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk, MavsdkConnectionError
from mavsdk.asyncio.plugins.action import ActionAsync, ActionError
from mavsdk.asyncio.plugins.offboard import OffboardAsync, OffboardError
from mavsdk.asyncio.plugins.param import ParamAsync, ParamError
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync
from mavsdk.plugins.offboard import PositionNedYaw

from swarm.config import GeoOrigin, Vec3
from swarm.errors import SwarmError
from swarm.geo import enu_to_ned, geo_to_world, ned_to_enu, yaw_enu_to_ned_deg, yaw_ned_to_enu_deg

_logs_silenced = False
OFFBOARD_MODE_SETTLE_S = 2.0  # after entering offboard, the reported mode may lag this long


def silence_mavsdk_logs() -> None:
    global _logs_silenced
    if not _logs_silenced:
        mavsdk.log_subscribe(lambda level, msg, file, line: True)
        _logs_silenced = True


class FlightError(SwarmError):
    """An autopilot command failed, was refused, or timed out."""


@dataclass
class TelemetryCache:
    """Latest telemetry, in the world frame; `updated` is the monotonic time of the last position sample."""

    position: Vec3 = (math.nan, math.nan, math.nan)
    velocity: Vec3 = (0.0, 0.0, 0.0)
    yaw_deg: float = 0.0
    flight_mode: str = "UNKNOWN"
    armed: bool = False
    landed_state: str = "UNKNOWN"
    updated: float = 0.0
    samples: int = 0
    battery: float = math.nan  # remaining fraction 0..1 (MAVSDK's remaining_percent / 100); NaN: not reported
    battery_min: float = math.nan  # the lowest seen


class Autopilot:
    def __init__(self, url: str, origin: GeoOrigin, command_timeout_s: float = 5.0) -> None:
        self.url = url
        self.origin = origin
        self.command_timeout_s = command_timeout_s
        self.telemetry = TelemetryCache()
        self.home_world: Vec3 | None = None
        self._home_local_ned: Vec3 = (0.0, 0.0, 0.0)
        self._sdk: Mavsdk | None = None
        self._action: ActionAsync | None = None
        self._offboard: OffboardAsync | None = None
        self._tel: TelemetryAsync | None = None
        self._param: ParamAsync | None = None
        self.on_status_text: Callable[[str, str], None] | None = None  # (severity, text) of each STATUSTEXT
        self._stragglers: set[asyncio.Task[Any]] = set()
        self._streams: list[asyncio.Task[None]] = []
        self.offboard_active = False
        self._offboard_started = 0.0

    # -- connection ---------------------------------------------------------------------------------------

    async def connect(self, timeout_s: float) -> None:
        silence_mavsdk_logs()
        sdk = self._sdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
        try:
            await self._call("connect", lambda: sdk.add_any_connection(self.url), timeout_s)
        except MavsdkConnectionError as exc:
            raise FlightError(f"cannot open autopilot link {self.url}: {exc}") from None
        system = await sdk.first_autopilot(timeout_s=timeout_s)
        if system is None:
            raise FlightError(f"no autopilot heartbeat on {self.url} within {timeout_s:.0f} s")
        self._action, self._offboard, self._tel = ActionAsync(system), OffboardAsync(system), TelemetryAsync(system)
        self._param = ParamAsync(system)

    async def read_health(self) -> dict[str, bool]:
        """The health items the agent waits for before it arms (`wait_healthy`), each ok or not."""
        assert self._tel is not None
        health = await self._call("health", self._tel.health)
        return {
            "local position": health.is_local_position_ok,
            "home position": health.is_home_position_ok,
            "armable": health.is_armable,
        }

    async def wait_healthy(self, timeout_s: float) -> None:
        """Wait until the autopilot reports healthy, armable and a home position; then start the streams."""
        assert self._tel is not None
        deadline = time.monotonic() + timeout_s
        while True:
            health = await self._call("health", self._tel.health)
            if health.is_local_position_ok and health.is_home_position_ok and health.is_armable:
                break
            if time.monotonic() > deadline:
                raise FlightError(f"autopilot not healthy within {timeout_s:.0f} s ({health})")
            await asyncio.sleep(0.2)
        home = await self._call("home", self._tel.home)
        self.home_world = geo_to_world(self.origin, home.latitude_deg, home.longitude_deg, home.absolute_altitude_m)
        local = (home.local_north_m, home.local_east_m, home.local_down_m)
        self._home_local_ned = local if all(math.isfinite(v) for v in local) else (0.0, 0.0, 0.0)
        tel = self._tel
        await self._call("set rate", lambda: tel.set_rate_position_velocity_ned(20.0))
        self._start_streams()
        await self.wait_until(lambda t: t.samples > 0, max(1.0, deadline - time.monotonic()), "position telemetry")

    # -- frames ------------------------------------------------------------------------------------------

    def local_to_world(self, ned: Vec3) -> Vec3:
        assert self.home_world is not None
        (n, e, d), (hn, he, hd) = ned, self._home_local_ned
        rel = ned_to_enu((n - hn, e - he, d - hd))
        return self.home_world[0] + rel[0], self.home_world[1] + rel[1], self.home_world[2] + rel[2]

    def world_to_local(self, p: Vec3) -> Vec3:
        assert self.home_world is not None
        (x, y, z), (hx, hy, hz) = p, self.home_world
        rel = enu_to_ned((x - hx, y - hy, z - hz))
        local = self._home_local_ned
        return local[0] + rel[0], local[1] + rel[1], local[2] + rel[2]

    @property
    def height_above_home(self) -> float:
        assert self.home_world is not None
        return self.telemetry.position[2] - self.home_world[2]

    @property
    def telemetry_age_s(self) -> float:
        return time.monotonic() - self.telemetry.updated if self.telemetry.updated else math.inf

    # -- commands ----------------------------------------------------------------------------------------

    async def arm_and_takeoff(self, altitude_m: float) -> None:
        assert self._action is not None
        action = self._action
        await self._call("set takeoff altitude", lambda: action.set_takeoff_altitude(altitude_m))
        await self._call("arm", self._action.arm)
        await self._call("takeoff", self._action.takeoff)

    async def read_params(self, ints: tuple[str, ...], floats: tuple[str, ...]) -> dict[str, float]:
        """Read parameters over the MAVLink parameter protocol (MAVSDK's param plugin), ints and floats by name."""
        assert self._param is not None
        param, values = self._param, {}
        for name in ints:
            values[name] = float(await self._call(f"read {name}", functools.partial(param.get_param_int, name)))
        for name in floats:
            values[name] = float(await self._call(f"read {name}", functools.partial(param.get_param_float, name)))
        return values

    async def set_param_int(self, name: str, value: int) -> None:
        assert self._param is not None
        param = self._param
        await self._call(f"write {name}", lambda: param.set_param_int(name, value))

    async def set_setpoint(self, target_world: Vec3, yaw_enu_deg: float) -> None:
        """Command a world-frame position; starts offboard mode on first use."""
        assert self._offboard is not None
        n, e, d = self.world_to_local(target_world)
        setpoint = PositionNedYaw(n, e, d, yaw_enu_to_ned_deg(yaw_enu_deg))
        offboard = self._offboard
        await self._call("offboard setpoint", lambda: offboard.set_position_ned(setpoint))
        if self.offboard_active and self._dropped_out_of_offboard():
            self.offboard_active = False  # setpoints stopped for a while (this process was frozen): enter again
        if not self.offboard_active:
            await self._call("offboard start", self._offboard.start)
            self.offboard_active = True
            self._offboard_started = time.monotonic()

    def _dropped_out_of_offboard(self) -> bool:
        """The vehicle reports HOLD, its failsafe when offboard setpoints stop, well after we entered offboard."""
        settled = time.monotonic() - self._offboard_started > OFFBOARD_MODE_SETTLE_S
        return settled and self.telemetry.flight_mode == "HOLD"

    async def hold(self, timeout_s: float | None = None) -> None:
        assert self._action is not None and self._offboard is not None
        if self.offboard_active:
            self.offboard_active = False
            await self._call("offboard stop", self._offboard.stop, timeout_s)
        else:
            await self._call("hold", self._action.hold, timeout_s)

    async def land(self, timeout_s: float | None = None) -> None:
        assert self._action is not None
        self.offboard_active = False
        await self._call("land", self._action.land, timeout_s)

    async def wait_until(self, condition: Callable[[TelemetryCache], bool], timeout_s: float, what: str) -> None:
        deadline = time.monotonic() + timeout_s
        while not condition(self.telemetry):
            if time.monotonic() > deadline:
                raise FlightError(f"timed out after {timeout_s:.0f} s waiting for {what}")
            await asyncio.sleep(0.05)

    # -- plumbing ----------------------------------------------------------------------------------------

    async def _call(self, what: str, fn: Callable[[], Awaitable[Any]], timeout_s: float | None = None) -> Any:
        task = asyncio.ensure_future(fn())
        done, _ = await asyncio.wait({task}, timeout=timeout_s or self.command_timeout_s)
        if not done:
            self._stragglers.add(task)
            task.add_done_callback(self._stragglers.discard)
            raise FlightError(f"{what}: no answer from the autopilot within {timeout_s or self.command_timeout_s:g} s")
        try:
            return task.result()
        except (ActionError, OffboardError, ParamError) as exc:
            raise FlightError(f"{what} refused: {exc}") from None

    def _start_streams(self) -> None:
        assert self._tel is not None
        tel, cache = self._tel, self.telemetry

        def on_position(pv: Any) -> None:
            p, v = pv.position, pv.velocity
            cache.position = self.local_to_world((p.north_m, p.east_m, p.down_m))
            cache.velocity = ned_to_enu((v.north_m_s, v.east_m_s, v.down_m_s))
            cache.updated = time.monotonic()
            cache.samples += 1

        def on_attitude(att: Any) -> None:
            cache.yaw_deg = yaw_ned_to_enu_deg(att.yaw_deg)

        def on_mode(mode: Any) -> None:
            cache.flight_mode = mode.name

        def on_armed(armed: bool) -> None:
            cache.armed = bool(armed)

        def on_landed(state: Any) -> None:
            cache.landed_state = state.name

        def on_battery(battery: Any) -> None:
            # MAVSDK 2+ gives percent (BATTERY_STATUS.battery_remaining, else SYS_STATUS's); -1 when not estimated
            percent = battery.remaining_percent
            if math.isfinite(percent) and 0.0 <= percent <= 100.0:
                cache.battery = percent / 100.0
                seen = cache.battery_min
                cache.battery_min = cache.battery if math.isnan(seen) else min(seen, cache.battery)

        def on_status_text(status: Any) -> None:
            if self.on_status_text is not None:
                self.on_status_text(status.type.name, status.text)

        for stream, handler in (
            (tel.subscribe_position_velocity_ned, on_position),
            (tel.subscribe_attitude_euler, on_attitude),
            (tel.subscribe_flight_mode, on_mode),
            (tel.subscribe_armed, on_armed),
            (tel.subscribe_landed_state, on_landed),
            (tel.subscribe_battery, on_battery),
            (tel.subscribe_status_text, on_status_text),
        ):
            self._streams.append(asyncio.create_task(_consume(stream(), handler)))

    async def close(self, grace_s: float = 8.0) -> bool:
        """Stop streams and release MAVSDK; returns False if a stuck call kept the instance alive."""
        for task in self._streams:
            task.cancel()
        await asyncio.gather(*self._streams, return_exceptions=True)
        if self._stragglers:
            await asyncio.wait(set(self._stragglers), timeout=grace_s)
        if self._stragglers:
            return False  # destroying now would hang on the running call; process exit will reclaim it
        if self._sdk is not None:
            self._sdk.destroy()
            self._sdk = None
        return True


async def _consume(stream: AsyncIterator[Any], handler: Callable[[Any], None]) -> None:
    try:
        async for item in stream:
            handler(item)
    finally:
        await stream.aclose()  # type: ignore[attr-defined]
