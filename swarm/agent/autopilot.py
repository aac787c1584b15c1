"""One drone's autopilot, reached through the MAVSDK 4 asyncio API.

Works the same against the project's simulated vehicles and a real PX4. Three rules, found by probing MAVSDK 4
against the simulated vehicle, shape this module:

- every plugin call runs in the default executor and may block for seconds in C, so calls are never cancelled:
  `_call` waits with a timeout and, if the call is still running, keeps its task and raises; `close()` waits for
  such stragglers before destroying the Mavsdk instance (destroying it under a running call hangs the process);
- subscriptions feed unbounded queues, so every stream we open is consumed continuously by a task;
- MAVSDK logs to stderr with colours unless silenced, process-wide.

Positions are converted between the autopilot's local NED frame (origin at its local origin) and the shared
world frame (z-up) in one of two ways. With a global position (GPS, or a global origin set on the vehicle), through
the home position, which the autopilot reports both geodetically and locally. Without one (indoors, agent.frame =
"local"), through a `LocalFrame`: where the local origin lies in the world and which way its north points. PX4
then sends no home position and cannot fly Hold or Return (swarm.agent.px4_failsafe), so the agent takes off and
holds in offboard, and home is where the vehicle stood when the agent connected.
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
from mavsdk.asyncio.plugins.offboard import OffboardAsync, OffboardError, OffboardResult
from mavsdk.asyncio.plugins.param import ParamAsync, ParamError
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync
from mavsdk.plugins.offboard import PositionNedYaw

from swarm.config import AgentSettings, GeoOrigin, Vec3
from swarm.errors import SwarmError
from swarm.geo import enu_to_ned, geo_to_world, ned_to_enu, yaw_enu_to_ned_deg, yaw_ned_to_enu_deg

_logs_silenced = False
CALL_SLICE_S = 0.25  # a MAVSDK call's timeout is counted in slices of this (`Autopilot._call`)
OFFBOARD_MODE_SETTLE_S = 2.0  # after entering offboard, the reported mode may lag this long
OFFBOARD_START_ATTEMPTS = 3  # starts of offboard refused for a setpoint MAVSDK dropped meanwhile (`start_offboard`)


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


@dataclass(frozen=True)
class LocalFrame:
    """The autopilot's local NED frame placed in the world: its origin (world point) and the world bearing of its
    north axis (degrees counter-clockwise from the world's +y)."""

    origin: Vec3
    north_deg: float = 0.0

    def to_world(self, ned: Vec3) -> Vec3:
        x, y, z = self.vector_to_world(ned)
        o = self.origin
        return o[0] + x, o[1] + y, o[2] + z

    def vector_to_world(self, ned: Vec3) -> Vec3:
        """A local NED vector (a velocity) in world axes."""
        x, y, z = ned_to_enu(ned)
        c, s = math.cos(math.radians(self.north_deg)), math.sin(math.radians(self.north_deg))
        return c * x - s * y, s * x + c * y, z

    def to_local(self, p: Vec3) -> Vec3:
        x, y, z = p[0] - self.origin[0], p[1] - self.origin[1], p[2] - self.origin[2]
        c, s = math.cos(math.radians(self.north_deg)), math.sin(math.radians(self.north_deg))
        return enu_to_ned((c * x + s * y, -s * x + c * y, z))


def local_frame(settings: AgentSettings) -> LocalFrame | None:
    """The local frame agent.frame = "local" asks for; None to fly by the global position."""
    if settings.frame != "local":
        return None
    assert settings.local_origin is not None  # AgentSettings validates it
    return LocalFrame(settings.local_origin, settings.local_north_deg)


class Autopilot:
    def __init__(
        self, url: str, origin: GeoOrigin, command_timeout_s: float = 5.0, local_frame: LocalFrame | None = None
    ) -> None:
        """`local_frame`: fly without a global position, the world tied to the local frame this way."""
        self.url = url
        self.origin = origin
        self.local_frame = local_frame
        self._north_deg = 0.0 if local_frame is None else local_frame.north_deg  # world yaw = local yaw + this
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
        """The health items the agent waits for before it arms (`wait_healthy`), each ok or not: a home position
        only when flying by it (no local frame)."""
        assert self._tel is not None
        health = await self._call("health", self._tel.health)
        items = {"local position": health.is_local_position_ok, "armable": health.is_armable}
        if self.local_frame is None:
            items["home position"] = health.is_home_position_ok
        return items

    async def wait_healthy(self, timeout_s: float) -> None:
        """Wait until every `read_health` item is ok; then start the streams and place home in the world."""
        assert self._tel is not None
        deadline = time.monotonic() + timeout_s
        while bad := [name for name, ok in (await self.read_health()).items() if not ok]:
            if time.monotonic() > deadline:
                raise FlightError(f"autopilot not healthy within {timeout_s:.0f} s (no {', '.join(bad)})")
            await asyncio.sleep(0.2)
        if self.local_frame is None:
            home = await self._call("home", self._tel.home)
            self.home_world = geo_to_world(self.origin, home.latitude_deg, home.longitude_deg, home.absolute_altitude_m)
            local = (home.local_north_m, home.local_east_m, home.local_down_m)
            self._home_local_ned = local if all(math.isfinite(v) for v in local) else (0.0, 0.0, 0.0)
        tel = self._tel
        await self._call("set rate", lambda: tel.set_rate_position_velocity_ned(20.0))
        self._start_streams()
        await self.wait_until(lambda t: t.samples > 0, max(1.0, deadline - time.monotonic()), "position telemetry")
        if self.local_frame is not None:
            self.home_world = self.telemetry.position  # on the ground where it will arm: PX4's home to be

    # -- frames ------------------------------------------------------------------------------------------

    def local_to_world(self, ned: Vec3) -> Vec3:
        if self.local_frame is not None:
            return self.local_frame.to_world(ned)
        assert self.home_world is not None
        (n, e, d), (hn, he, hd) = ned, self._home_local_ned
        rel = ned_to_enu((n - hn, e - he, d - hd))
        return self.home_world[0] + rel[0], self.home_world[1] + rel[1], self.home_world[2] + rel[2]

    def world_to_local(self, p: Vec3) -> Vec3:
        if self.local_frame is not None:
            return self.local_frame.to_local(p)
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
        """Arm and climb to `altitude_m` above home: PX4's Takeoff mode, which ends in Hold; without a global
        position (a local frame), in offboard instead, since Hold could not run and PX4 would land."""
        assert self._action is not None and self.home_world is not None
        action = self._action
        if self.local_frame is not None:
            here = self.telemetry.position
            await self._call("arm", self._action.arm)
            await self.set_setpoint((here[0], here[1], self.home_world[2] + altitude_m), self.telemetry.yaw_deg)
            return
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
        setpoint = PositionNedYaw(n, e, d, yaw_enu_to_ned_deg(yaw_enu_deg - self._north_deg))
        offboard = self._offboard
        await self._call("offboard setpoint", lambda: offboard.set_position_ned(setpoint))
        if self.offboard_active and self._dropped_out_of_offboard():
            self.offboard_active = False  # setpoints stopped for a while (this process was frozen): enter again
        if not self.offboard_active:
            await self._call("offboard start", lambda: start_offboard(offboard, setpoint))
            self.offboard_active = True
            self._offboard_started = time.monotonic()

    def taken_over_by(self) -> str | None:
        """The mode the vehicle is in, while this agent commands offboard, when it is one the agent did not ask
        for and must not fight: a pilot's switch, or PX4's own failsafe (Land, Return). None while it flies
        offboard, or HOLD (PX4's offboard loss after this process was frozen: `set_setpoint` enters again)."""
        settled = time.monotonic() - self._offboard_started > OFFBOARD_MODE_SETTLE_S
        fresh = self.telemetry_age_s < OFFBOARD_MODE_SETTLE_S
        mode = self.telemetry.flight_mode
        if self.offboard_active and settled and fresh and mode not in ("OFFBOARD", "HOLD", "UNKNOWN"):
            return mode
        return None

    def _dropped_out_of_offboard(self) -> bool:
        """The vehicle reports HOLD, its failsafe when offboard setpoints stop, well after we entered offboard."""
        settled = time.monotonic() - self._offboard_started > OFFBOARD_MODE_SETTLE_S
        return settled and self.telemetry.flight_mode == "HOLD"

    async def hold(self, timeout_s: float | None = None) -> None:
        """Stop where it is: PX4's Hold; without a global position, an offboard setpoint where it is."""
        assert self._action is not None and self._offboard is not None
        if self.local_frame is not None:
            await self.set_setpoint(self.telemetry.position, self.telemetry.yaw_deg)
            return
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
        """Await one MAVSDK call; FlightError when it has not answered within `timeout_s` of time this process
        ran. The wait is cut in slices and a slice that overran by far (the process stopped or starved) counts
        only twice its length: a process frozen during a call would otherwise find it timed out on waking,
        while the autopilot, frozen with it or not, was never given the time to answer."""
        budget = timeout_s or self.command_timeout_s
        task = asyncio.ensure_future(fn())
        waited = 0.0
        while True:
            started = time.monotonic()
            done, _ = await asyncio.wait({task}, timeout=min(CALL_SLICE_S, budget - waited))
            if done:
                break
            waited += min(time.monotonic() - started, 2 * CALL_SLICE_S)
            if waited >= budget:
                self._stragglers.add(task)
                task.add_done_callback(self._stragglers.discard)
                raise FlightError(f"{what}: no answer from the autopilot within {budget:g} s")
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
            velocity = (v.north_m_s, v.east_m_s, v.down_m_s)
            frame = self.local_frame
            cache.velocity = ned_to_enu(velocity) if frame is None else frame.vector_to_world(velocity)
            cache.updated = time.monotonic()
            cache.samples += 1

        def on_attitude(att: Any) -> None:
            cache.yaw_deg = yaw_ned_to_enu_deg(att.yaw_deg) + self._north_deg

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


async def start_offboard(
    offboard: OffboardAsync, setpoint: PositionNedYaw, attempts: int = OFFBOARD_START_ATTEMPTS
) -> None:
    """Enter offboard mode with `setpoint` set. MAVSDK drops the setpoint it streams when a heartbeat shows the
    vehicle out of offboard more than 3 s after the last start (`OffboardImpl::process_heartbeat`), and `start`
    then fails with NO_SETPOINT_SET. A heartbeat between our setpoint and our start does that whenever the
    vehicle is in HOLD, as after this process was frozen (PX4's offboard loss): the drone landed instead of
    resuming. So such a start sets the setpoint again and starts again; any other refusal is raised."""
    for attempt in range(1, attempts + 1):
        try:
            await offboard.start()
            return
        except OffboardError as exc:
            if exc.result != OffboardResult.NO_SETPOINT_SET or attempt == attempts:
                raise
        await offboard.set_position_ned(setpoint)


async def _consume(stream: AsyncIterator[Any], handler: Callable[[Any], None]) -> None:
    try:
        async for item in stream:
            handler(item)
    finally:
        await stream.aclose()  # type: ignore[attr-defined]
