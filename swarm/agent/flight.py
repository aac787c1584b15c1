"""The flight sequence of one drone: connect, take off, follow a route, land, and fail safe.

A route is a list of world-frame waypoints. The drone is led along each straight segment by a setpoint (a
"carrot") that advances at the cruise speed and never runs more than `LOOKAHEAD_M` ahead of the drone, so it
flies the segments themselves, not shortcuts between them, at a speed the agent chooses.

Fail safe: if position telemetry stops for `telemetry_timeout_s` while airborne, the drone is told to hold,
then to land, and the flight ends in phase `failsafe`. A stop request (SIGINT/SIGTERM) ends the route early
and lands.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Callable
from enum import StrEnum

import numpy as np

from swarm.agent.autopilot import Autopilot, FlightError
from swarm.config import AgentSettings, Vec3

LOOKAHEAD_M = 1.0
SETPOINT_PERIOD_S = 0.1
LAND_TIMEOUT_S = 60.0
FAILSAFE_COMMAND_TIMEOUT_S = 0.6


class Phase(StrEnum):
    CONNECTING = "connecting"
    READY = "ready"
    TAKEOFF = "takeoff"
    FLYING = "flying"
    HOVERING = "hovering"
    LANDING = "landing"
    LANDED = "landed"
    FAILSAFE = "failsafe"
    FAILED = "failed"


class TelemetryLost(FlightError):
    pass


class StopRequested(Exception):
    pass


class Flight:
    def __init__(self, autopilot: Autopilot, settings: AgentSettings, log: Callable[..., None]) -> None:
        self.ap = autopilot
        self.settings = settings
        self.log = log
        self.phase = Phase.CONNECTING
        self.distance_m = 0.0
        self.airborne = False
        self._last_position: np.ndarray | None = None
        self._carrot: Vec3 | None = None

    def _set_phase(self, phase: Phase) -> None:
        if phase != self.phase:
            self.phase = phase
            self.log("phase", phase=phase.value)

    async def run(self, route: list[Vec3], stop: asyncio.Event) -> Phase:
        """Fly the whole mission; returns the final phase (LANDED, FAILSAFE or FAILED)."""
        s = self.settings
        try:
            await self.ap.connect(s.connect_timeout_s)
            await self.ap.wait_healthy(s.health_timeout_s)
            self._set_phase(Phase.READY)
            if s.start_delay_s > 0:
                await self._wait(s.start_delay_s, stop)
            self._check(stop)
            await self._take_off(stop)
            self._set_phase(Phase.FLYING)
            for waypoint in route:
                await self._fly_segment_to(waypoint, stop)
            if s.hover_s > 0:
                self._set_phase(Phase.HOVERING)
                await self._wait(s.hover_s, stop)
        except StopRequested:
            self.log("stop_requested", airborne=self.airborne)
        except TelemetryLost as exc:
            self.log("failsafe", reason=str(exc))
            await self._fail_safe()
            return self.phase
        except FlightError as exc:
            self.log("flight_error", reason=str(exc))
            if not self.airborne:
                self._set_phase(Phase.FAILED)
                return self.phase
        return await self._land()

    # -- stages ------------------------------------------------------------------------------------------

    async def _take_off(self, stop: asyncio.Event) -> None:
        self._set_phase(Phase.TAKEOFF)
        altitude = self.settings.altitude_m
        await self.ap.arm_and_takeoff(altitude)
        self.airborne = True
        deadline = time.monotonic() + 15.0 + altitude / 0.3
        while not self.ap.height_above_home >= 0.9 * altitude:  # written so that an unknown (NaN) height waits
            await self._tick(stop, deadline, "take-off altitude")

    async def _fly_segment_to(self, goal: Vec3, stop: asyncio.Event) -> None:
        here = np.array(self.ap.telemetry.position)
        start = np.array(self._carrot) if self._carrot is not None else here
        target = np.array(goal, dtype=float)
        segment = target - start
        length = float(np.linalg.norm(segment))
        yaw = math.degrees(math.atan2(segment[1], segment[0])) if length > 0.05 else self.ap.telemetry.yaw_deg
        speed = self.settings.cruise_speed_m_s
        deadline = time.monotonic() + 20.0 + 3.0 * (length + float(np.linalg.norm(start - here))) / speed
        travelled = 0.0
        while True:
            position = np.array(self.ap.telemetry.position)
            carrot = start + segment * (travelled / length) if length > 0 else target
            if travelled < length and np.linalg.norm(carrot - position) < LOOKAHEAD_M:
                travelled = min(length, travelled + speed * SETPOINT_PERIOD_S)
                carrot = start + segment * (travelled / length)
            self._carrot = tuple(float(c) for c in carrot)
            await self.ap.set_setpoint(self._carrot, yaw)
            if travelled >= length and np.linalg.norm(target - position) < self.settings.waypoint_tolerance_m:
                return
            await self._tick(stop, deadline, f"waypoint {tuple(round(c, 2) for c in goal)}")

    async def _wait(self, seconds: float, stop: asyncio.Event) -> None:
        """Wait on the ground or in the air, still watching for a stop request and for lost telemetry."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            await self._tick(stop, end + 1.0, "the end of a wait")

    async def _land(self) -> Phase:
        if not self.airborne:
            self._set_phase(Phase.LANDED)
            return self.phase
        self._set_phase(Phase.LANDING)
        try:
            await self.ap.hold()
        except FlightError as exc:
            self.log("flight_error", reason=str(exc))
        try:
            await self.ap.land()
            await self.ap.wait_until(
                lambda t: t.landed_state == "ON_GROUND" and not t.armed, LAND_TIMEOUT_S, "landing and disarm"
            )
        except FlightError as exc:
            self.log("flight_error", reason=str(exc))
            self._set_phase(Phase.FAILED)
            return self.phase
        self.airborne = False
        self._set_phase(Phase.LANDED)
        return self.phase

    async def _fail_safe(self) -> None:
        """Hold, then land; with no telemetry we cannot confirm either, so we report FAILSAFE.

        Short timeouts: both commands must leave before MAVSDK declares the link lost (3 s without a heartbeat)
        and stops sending; the vehicle may still hear us even though we no longer hear it.
        """
        self._set_phase(Phase.FAILSAFE)
        for step in (self.ap.hold, self.ap.land):
            try:
                await step(timeout_s=FAILSAFE_COMMAND_TIMEOUT_S)
                self.log("failsafe_command", command=step.__name__, accepted=True)
            except FlightError as exc:
                self.log("failsafe_command", command=step.__name__, accepted=False, reason=str(exc))

    # -- helpers -----------------------------------------------------------------------------------------

    async def _tick(self, stop: asyncio.Event, deadline: float, what: str) -> None:
        self._check(stop)
        if time.monotonic() > deadline:
            raise FlightError(f"timed out flying to {what}")
        await asyncio.sleep(SETPOINT_PERIOD_S)
        self._check(stop)

    def _check(self, stop: asyncio.Event) -> None:
        if stop.is_set():
            raise StopRequested
        if self.airborne and self.ap.telemetry_age_s > self.settings.telemetry_timeout_s:
            raise TelemetryLost(f"no position telemetry for {self.ap.telemetry_age_s:.1f} s")

    def update_distance(self) -> None:
        """Accumulate travelled distance from telemetry; called at the heartbeat rate."""
        p = self.ap.telemetry.position
        if not all(math.isfinite(c) for c in p):
            return
        current = np.array(p)
        if self._last_position is not None:
            self.distance_m += float(np.linalg.norm(current - self._last_position))
        self._last_position = current
