"""The flight sequence of one drone: connect, take off, fly a mission, land, and fail safe.

The mission is a coroutine given the `Flight` once the drone is airborne: a scripted route (`route_mission`) or
the exploration task, which calls `fly_path` and `face` as it decides where to go. A path is a list of
world-frame waypoints. The drone is led along each straight segment by a setpoint (a "carrot") that advances at
the cruise speed and never runs more than `LOOKAHEAD_OPEN_M` ahead of the drone (`LOOKAHEAD_M` near the
segment's end). At a corner the carrot runs on into the next segment at once where the map shows the straight
way from the drone to it in open space (`is_roomy`, the planner's wider clearance), so the drone rounds the
corner inside it without stopping. Elsewhere (doorways, wall ends) the carrot waits while the drone is more than
`CROSS_TRACK_M` off the new segment until the drone, slowed down, is within `CORNER_CUT_M` of the corner; from
there it runs on where the map shows the straight way to it clear (`is_clear`, the planner's clearance), so
the drone turns near the corner instead of crawling into it. Without a map the drone flies the segments
themselves.

Separation: `neighbours()` gives the other airborne drones' positions, velocities and `heading_to` (the end of
the segment each is flying), from their heartbeats, positions extrapolated to now. The lower id has the right
of way. A drone closer than `separation_m` to a lower id stops and steps out of its way (up or down when the
other hovers; else to the nearest point the map lets it fly straight to, `is_clear`, well off the other's
segment) until the other has passed, then flies back to where it left its segment and on along it, unless the
map shows the straight way on clear (from a refuge beside a doorway, the line to the waypoint beyond it clips the
jamb). The drone with the right of way holds its position while a higher id is very close and in its way (not
one that stepped off its segment), and gives the segment up after MAX_YIELD_S. Which of these the drone does is
the pure step function of `swarm.agent.separation` (follow, hold, yield, rejoin, replan); the geometry is here. A
drone about to land first waits for any drone under it to move off, and lands beside one that sits on the ground
there.

Crew: a drone that keeps apart from others (`separation_m`) waits on the ground, once healthy, until it has heard
every other drone it is told of (`crew_size`, mission.drones) or for `agent.crew_wait_s` at most: until it hears
a peer it cannot keep clear of it (on a lossy link with TLS, peers were first heard 20 s after start, and two
drones that took off before then collided). A restarted agent whose drone is in the air does not wait.

Phases (`swarm.bus.phase.Phase`, what the heartbeat says) change as `swarm.agent.lifecycle.ALLOWED` says.

Battery: once the autopilot's battery telemetry falls below `agent.battery_home_fraction` during the mission
(or the hover after it), the flight logs `battery_low` once and ends the mission as a normal end would: the
mission is interrupted (`BatteryLow`), and in phase returning (out of its cluster: the others take over its
targets) the drone flies back above its take-off point the way the mission's `homeward` says (the exploration
plans it on its map; a scripted route is retraced through the waypoints reached, each leg flown once already)
and lands. A battery already that low on the ground is a refusal to take off. The threshold sits above PX4's
BAT_LOW_THR, so that the vehicle's own battery failsafe (`swarm.agent.px4_failsafe`) never has to act.

Fail safe: if position telemetry stops for `telemetry_timeout_s` while airborne, the drone is told to hold,
then to land, and the flight ends in phase `failsafe`; if telemetry comes back, the agent watches the landing
through as after a normal flight. Only silence this process was awake to hear counts: a gap while it was
stopped or starved of CPU is no evidence of a lost link (`swarm.agent.watchdog`). A stop request
(SIGINT/SIGTERM) ends the route early and lands.

Landing is watched, not assumed: a command the autopilot did not answer in time is retried by MAVSDK and may
arrive after LAND (a late HOLD leaves the drone hovering), so while the drone is airborne and not in LAND the
land command is sent again.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections import deque
from collections.abc import Awaitable, Callable, Collection
from typing import NamedTuple

import numpy as np

from swarm.agent.autopilot import Autopilot, FlightError
from swarm.agent.lifecycle import IllegalTransition, transition
from swarm.agent.px4_params import FLOAT_PARAMS, INT_PARAMS, safe_writes, unsafe
from swarm.agent.separation import MAX_YIELD_S, Cue, Manoeuvre, Separation, step
from swarm.agent.watchdog import LoopMonitor
from swarm.bus.phase import Phase
from swarm.config import AgentSettings, Vec3, vec3

# The carrot leads the drone by at most LOOKAHEAD_OPEN_M, and by LOOKAHEAD_M once the drone is within
# LOOKAHEAD_NEAR_M of the segment's end (linearly over the LOOKAHEAD_TAPER_M before). PX4's position loop turns a
# lead into a speed (MPC_XY_P 0.95 /s): 1.5 m lets the drone cruise at 1.4 m/s, and it comes into each corner
# nearly as it did with 1 m throughout. Measured on a 6 m straight in the simulator: a stop 0.083 m past the
# waypoint, against 0.076 m with 1 m throughout and 0.115 m with 1.6 m throughout (the drone's speed lags the
# lead's, so the taper starts well before the end).
LOOKAHEAD_M = 1.0
LOOKAHEAD_OPEN_M = 1.5
LOOKAHEAD_NEAR_M = 1.5
LOOKAHEAD_TAPER_M = 1.5
SETPOINT_PERIOD_S = 0.1
# The carrot runs on at the cruise speed by the time since the last setpoint, at most this: a loop that ticks
# late (other agents, the mapping thread) must not slow the drone, and after a stall the carrot must not jump.
# (Ticks are late by ~2 % in a 3-drone mission on 2 cores: `setpoint_period_s` in the agents' `flight_ended`.)
MAX_TICK_S = 2 * SETPOINT_PERIOD_S
TICKS_KEPT = 6000  # setpoint periods kept for the flight's figures: the last 10 minutes of flying segments
LAND_TIMEOUT_S = 60.0
STALL_S = 2.0  # a gap this long between two flight checks means this process was not running
LANDED_STATE_WAIT_S = 3.0  # after connecting, how long the landed state may stay unknown
FAILSAFE_COMMAND_TIMEOUT_S = 0.6
RELAND_AFTER_S = 2.0  # airborne, telemetry fresh and not in LAND this long after a land command: command it again
FAILSAFE_BLIND_S = 10.0  # after a failsafe land, telemetry still silent this long: stop watching (nothing to see)
BATTERY_WAIT_S = 3.0  # before arming, how long the first battery report may take
STEP_ASIDE_M = 0.7  # a yielding drone climbs or descends this much out of the way
PASS_HYSTERESIS_M = 0.3  # ... and resumes once the other is this much beyond the separation distance
PRIORITY_PAUSE_FRACTION = 1.0  # the drone with the right of way holds for one closer than this x separation
# (0.6 was too late: two drones closing at 3 m/s cover 0.7 m in a quarter second)
PASS_CLEARANCE_M = 0.6  # ... that is in its way: this close to the rest of its segment (a drone that stepped
# STEP_ASIDE_M off the segment is not, and holding for it would deadlock both)
CROSS_TRACK_M = 0.1  # the carrot waits while the drone is farther than this off its segment (carrot_may_advance)
REST_S = 0.5  # ... unless the drone has been at rest this long: it will get no closer (longer than a turn back takes)
# ... unless the drone is this close to the corner and the map shows the way to the carrot clear (`_may_cut_to`):
# led by a carrot at the corner the drone slows as it nears it (speed ~ distance), so the last CROSS_TRACK_M took
# it seconds at a crawl. Not from farther: cutting from 1 m (the carrot's lead near a corner) took a test route
# 14 % less time, but in a mission a drone that came at speed through a chain of short legs swung 0.1 m outside a
# 45-degree corner, 0.03 m from a wall (its momentum is from the legs before: the straight ways checked from it
# do not bound where it goes).
CORNER_CUT_M = 0.5
# A turn no sharper than this is cut wherever the map shows the straight way to the carrot clear, and the carrot's
# lead is kept through it (`gentle_turns`): the drone's heading changes little, so it does not swing wide at speed.
# A planned path bends every 0.5-1 m round the obstacles it keeps its clearance from (62 % of its segments were
# under 1 m on a generated building, 37 % of its turns under 30 degrees), and slowing to CORNER_CUT_M at each bend
# flew drones home at 0.8 m/s against 1.4 m/s.
GENTLE_TURN_DEG = 30.0
PARKED_FOR_S = 1.0  # a peer given way to that has been parked this long (`parked`) will not pass: the yield ends
SLOW_M_S = 0.2  # a peer slower than this, going nowhere, has no track to step off: the yielder climbs or descends
REFUGE_CLEAR_M = PASS_CLEARANCE_M + 0.2  # a refuge this far off the other's segment lets it pass
REJOIN_TOLERANCE_M = 0.1  # a drone flying its step aside back is at the segment again this close to it
LAND_CLEAR_M = PASS_CLEARANCE_M  # a drone this close horizontally under us is in the way of a landing
GROUNDED_M = 0.3  # a drone this low above our home's floor, and slow, sits on the ground
LAND_ASIDE_M = 1.0  # ... so we land this far beside it
LAND_SPOT_TOLERANCE_M = 0.1
WAITING_AT_M = 0.3  # a slow drone this close to where it is heading is waiting there (waiting_aside)
SILENT_CLEAR_M = 0.45  # a segment passing a silent drone closer than this touches it (two 0.2 m airframes + margin)

# Separation looks this far ahead at both drones' velocities: to hear (heartbeats 0.2 s apart), decide (a 0.1 s
# loop) and stop from cruise (PX4's velocity loop, about 0.6 s). A drone stepping aside or holding for one closing
# at 3 m/s starts 3 m earlier; one passing by, its closest approach beyond the separation, is let be.
REACTION_S = 1.0
ENTERING_HORIZON_S = 0.5  # the drone with the right of way holds for one that will be in its way this soon
TRACK_HORIZON_S = 3.0  # a yielding drone keeps away from where the other will be within this time


class Neighbour(NamedTuple):
    id: int
    position: Vec3
    velocity: Vec3
    heading_to: Vec3 | None = None  # the end of the segment it is flying
    silent: bool = False  # no recent heartbeat (its agent is frozen or dead): it will not move, whatever its id


Neighbours = Callable[[], list[Neighbour]]
Mission = Callable[["Flight", asyncio.Event], Awaitable[None]]


class TelemetryLost(FlightError):
    pass


class StopRequested(Exception):
    pass


class TakenOver(Exception):
    """The vehicle left offboard for a mode the agent did not ask for: the agent stops commanding it."""

    def __init__(self, mode: str) -> None:
        super().__init__(f"the vehicle switched to {mode} while the agent was commanding it")
        self.mode = mode


class BatteryLow(Exception):
    """The battery fell below agent.battery_home_fraction in flight: the mission ends, the drone goes home."""


class Flight:
    def __init__(
        self,
        autopilot: Autopilot,
        settings: AgentSettings,
        log: Callable[..., None],
        *,
        separation_m: float = 0.0,
        neighbours: Neighbours | None = None,
        is_clear: Callable[[Vec3, Vec3], bool] | None = None,
        is_roomy: Callable[[Vec3, Vec3], bool] | None = None,
        crew_size: int = 1,
        peers_heard: Callable[[], Collection[int]] | None = None,
    ) -> None:
        self.ap = autopilot
        self.settings = settings
        self.log = log
        autopilot.on_status_text = lambda severity, text: log("statustext", severity=severity, text=text)
        self.phase = Phase.CONNECTING
        self.distance_m = 0.0
        self.airborne = False
        self.separation_m = separation_m
        self.neighbours: Neighbours = neighbours or (lambda: [])
        # the straight flight from a to b keeps clear of everything the map shows (the planner's test)
        self.is_clear = is_clear or (lambda a, b: True)
        self.has_map = is_clear is not None
        # ... and keeps the wider clearance of open space (`_may_cut_to`); without it no corner is cut
        self.is_roomy = is_roomy
        self.crew_size = crew_size  # drones in the mission, this one included (the crew it waits to hear)
        self.peers_heard: Callable[[], Collection[int]] = peers_heard or (lambda: ())
        self.yields = 0
        # seconds between two setpoints along segments, the last TICKS_KEPT of them (`setpoint_periods`)
        self.tick_periods: deque[float] = deque(maxlen=TICKS_KEPT)
        # the drone with the right of way that gave a segment up for a peer that would not move: which, and when
        self.blocked_by: tuple[Neighbour, float] | None = None
        self.heading_to: Vec3 | None = None  # the end of the segment being flown (heartbeats carry it)
        self._last_position: np.ndarray | None = None
        self._carrot: Vec3 | None = None
        self.path_ahead: list[Vec3] = []  # the waypoints of the path being flown not reached yet
        self.reached: list[Vec3] = []  # every waypoint reached since take-off, in order (`retrace` flies it back)
        self.battery_low = False
        self._last_check = time.monotonic()
        self.loop_monitor = LoopMonitor()  # what this process did not hear is not silence (swarm.agent.watchdog)
        self._excused_sample: float | None = None  # the last sample after which a gap was excused (logged once)

    @property
    def setpoint(self) -> Vec3 | None:
        """The position setpoint the drone was last led by on a path (the carrot), or None."""
        return self._carrot

    async def brake(self) -> None:
        """Hold where the drone is now, not at its carrot: the map shows the way there blocked (the map changed
        under the path; a wall seen edge-on is mapped late). Called while the path is interrupted for a new one:
        until that comes, the autopilot keeps the last setpoint, and the drone flew on into the wall (gen:2)."""
        self._carrot = vec3(self.ap.telemetry.position)
        await self.ap.set_setpoint(self._carrot, self.ap.telemetry.yaw_deg)

    def _set_phase(self, phase: Phase) -> None:
        """Change phase as the lifecycle allows (`swarm.agent.lifecycle.ALLOWED`). An illegal change is a bug:
        logged loudly, and taken all the same (landing and failsafe are never refused; the heartbeat says what
        the drone does)."""
        if phase == self.phase:
            return
        try:
            transition(self.phase, phase)
        except IllegalTransition as exc:
            self.log("illegal_transition", reason=str(exc), previous=self.phase.value, wanted=phase.value)
        self.phase = phase
        self.log("phase", phase=phase.value)

    async def run(self, mission: Mission, stop: asyncio.Event, homeward: Mission | None = None) -> Phase:
        """Fly the whole mission; returns the final phase (LANDED, FAILSAFE or FAILED). `homeward` flies the drone
        back above its take-off point when a low battery ends the mission (default: `retrace`)."""
        monitor = asyncio.create_task(self.loop_monitor.run())
        try:
            return await self._run(mission, stop, homeward or retrace)
        finally:
            monitor.cancel()
            await asyncio.gather(monitor, return_exceptions=True)

    async def _run(self, mission: Mission, stop: asyncio.Event, homeward: Mission) -> Phase:
        s = self.settings
        try:
            await self.ap.connect(s.connect_timeout_s)
            await self.ap.wait_healthy(s.health_timeout_s)
            await self._px4_params()
            self._set_phase(Phase.READY)
            resuming = await self._already_flying()
            if not resuming:
                await self._wait_for_crew(stop)
            if s.start_delay_s > 0:
                await self._wait(s.start_delay_s, stop)
            self._check(stop)
            await self._take_off(stop, resuming)
            self._set_phase(Phase.FLYING)
            try:
                await mission(self, stop)
                if s.hover_s > 0:
                    self._set_phase(Phase.HOVERING)
                    await self._wait(s.hover_s, stop)
            except BatteryLow:
                self._set_phase(Phase.RETURNING)
                await homeward(self, stop)
        except TakenOver as exc:
            await self._taken_over(exc.mode, stop)
            return self.phase
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

    async def _take_off(self, stop: asyncio.Event, resuming: bool) -> None:
        """Arm and climb to the altitude, or, `resuming` (`_already_flying`), take the drone over where it is."""
        self._set_phase(Phase.TAKEOFF)
        self._last_check = time.monotonic()
        if resuming:
            self.airborne = True  # a restarted agent takes over its drone where it hovers (offboard-loss hold)
            self.log("resumed_in_air", position=[round(v, 2) for v in self.ap.telemetry.position])
            return
        await self._refuse_a_low_battery()
        altitude = self.settings.altitude_m
        await self.ap.arm_and_takeoff(altitude)
        self.airborne = True
        deadline = time.monotonic() + 15.0 + altitude / 0.3
        while not self.ap.height_above_home >= 0.9 * altitude:  # written so that an unknown (NaN) height waits
            await self._tick(stop, deadline, "take-off altitude")

    async def _wait_for_crew(self, stop: asyncio.Event) -> None:
        """On the ground, when keeping apart: wait up to agent.crew_wait_s to hear every other drone (the module
        docstring), and log whom it heard."""
        expected = self.crew_size - 1
        if self.separation_m <= 0 or expected <= 0 or self.settings.crew_wait_s <= 0:
            return
        started = time.monotonic()
        deadline = started + self.settings.crew_wait_s
        while len(self.peers_heard()) < expected and time.monotonic() < deadline:
            await self._pause(stop)
        heard = sorted(self.peers_heard())
        self.log(
            "crew",
            heard=heard,
            expected=expected,
            complete=len(heard) >= expected,
            waited_s=round(time.monotonic() - started, 2),
        )

    async def _refuse_a_low_battery(self) -> None:
        """On the ground, a battery already below agent.battery_home_fraction: refuse to take off (FlightError).
        Waits up to BATTERY_WAIT_S for the first report; a vehicle that reports no battery flies unwatched."""
        deadline = time.monotonic() + BATTERY_WAIT_S
        while math.isnan(self.ap.telemetry.battery) and time.monotonic() < deadline:
            await asyncio.sleep(0.05)
        fraction, threshold = self.ap.telemetry.battery, self.settings.battery_home_fraction
        if math.isnan(fraction):
            self.log("no_battery_telemetry", waited_s=BATTERY_WAIT_S)
        elif fraction < threshold:
            self.log("battery_low", fraction=round(fraction, 3), threshold=threshold, airborne=False)
            raise FlightError(
                f"refusing to take off: battery {fraction:.0%} is below agent.battery_home_fraction {threshold:.0%}"
            )

    async def _px4_params(self) -> None:
        """agent.px4_params: what the vehicle does when this agent dies must not be a climb (swarm.agent.px4_params);
        'set' makes it Hold, 'check' refuses to fly (FlightError on the ground: phase failed, exit 1)."""
        mode = self.settings.px4_params
        if mode == "off":
            return
        values = await self.ap.read_params(INT_PARAMS, FLOAT_PARAMS)
        self.log("px4_params", mode=mode, values=values)
        if mode == "set":
            writes = safe_writes(values)
            for name, value in writes.items():
                await self.ap.set_param_int(name, value)
            values = await self.ap.read_params(INT_PARAMS, FLOAT_PARAMS)
            read_back = {name: int(values[name]) for name in writes}
            self.log("px4_params_set", written=writes, read_back=read_back)
            if read_back != writes:
                raise FlightError(f"PX4 parameters written {writes} but read back {read_back}")
        findings = unsafe(values)
        for f in findings:
            self.log("px4_param_unsafe", param=f.param, value=f.value, reason=f.reason)
        if findings:
            names = ", ".join(f"{f.param}={f.value:g}" for f in findings)
            raise FlightError(
                f"refusing to take off: if this agent died the vehicle would Return, climbing ({names}); "
                "change them or set agent.px4_params = 'set'"
            )

    async def _already_flying(self) -> bool:
        """Armed and in the air: this process was restarted mid-mission (waits briefly for the landed state)."""
        deadline = time.monotonic() + LANDED_STATE_WAIT_S
        while self.ap.telemetry.landed_state == "UNKNOWN" and time.monotonic() < deadline:
            await asyncio.sleep(0.05)
        tel = self.ap.telemetry
        return tel.armed and tel.landed_state == "IN_AIR"

    async def fly_path(self, path: list[Vec3], stop: asyncio.Event, interrupt: asyncio.Event | None = None) -> bool:
        """Fly the waypoints in order, from where the drone is; False as soon as `interrupt` is set (or a yield
        lasted too long)."""
        # A path is planned from the drone's position. The carrot of an interrupted path can be a metre ahead
        # of the drone, round a corner of that path: a first segment from there is one nobody checked (a drone
        # cut through a doorway with its top in the lintel). So the new carrot starts on the new path, as far
        # along it as the old one led the drone in that direction: starting at the drone, it braked the drone
        # (from 1.2 to 0.34 m/s) at every new path, and an exploring drone gets one every few seconds.
        lead = carried_lead(self.ap.telemetry.position, self._carrot, path[0]) if path else 0.0
        self._carrot = None
        self.path_ahead = list(path)
        gentle, run_on = gentle_turns(self.ap.telemetry.position, path)
        try:
            for i, waypoint in enumerate(path):
                last = i == len(path) - 1
                if not await self._fly_segment_to(
                    waypoint, stop, interrupt, lead=lead, through=not last, gentle=gentle[i], run_on=run_on[i]
                ):
                    return False
                lead = 0.0
                self.path_ahead.pop(0)
                self.reached.append(waypoint)
            return True
        finally:
            self.path_ahead = []

    async def face(
        self, point: Vec3, seconds: float, stop: asyncio.Event, interrupt: asyncio.Event | None = None
    ) -> None:
        """Hold position, turn towards `point` and look at it for `seconds` (the camera maps while we wait); a
        lower id coming close meanwhile is given way to, and the look ends there; so it does when `interrupt` is
        set."""
        here = self.ap.telemetry.position
        yaw = math.degrees(math.atan2(point[1] - here[1], point[0] - here[0]))
        hold = self._carrot if self._carrot is not None else here
        self.heading_to = None
        end = time.monotonic() + seconds
        while time.monotonic() < end and not (interrupt is not None and interrupt.is_set()):
            position = np.array(self.ap.telemetry.position)
            rival = self._rival(position, position)  # no segment: only a lower id counts
            if rival is not None:
                await self._step_aside(rival.id, stop, None)
                return
            await self.ap.set_setpoint(hold, yaw)
            await self._pause(stop)

    async def _fly_segment_to(
        self,
        goal: Vec3,
        stop: asyncio.Event,
        interrupt: asyncio.Event | None = None,
        tolerance: float | None = None,
        lead: float = 0.0,
        through: bool = False,
        gentle: bool = False,
        run_on: float = 0.0,
    ) -> bool:
        """Fly the straight segment from the carrot (else the drone) to `goal`, reached within `tolerance` (by
        default the waypoint tolerance), the carrot starting `lead` metres along it; False when interrupted or a
        yield lasted too long. A segment flown `through` its end (a path goes on from it) is done as soon as
        the carrot is there: the next segment's carrot takes over while the drone is still on its way to the
        corner, and cuts it only where the map shows the cut clear (`carrot_may_advance`). `gentle`: the segment
        starts with a gentle turn (`gentle_turns`); `run_on`: how far the path runs on from its end through gentle
        turns, which the carrot's lead counts as if the segment went on."""
        tolerance = self.settings.waypoint_tolerance_m if tolerance is None else tolerance
        here = np.array(self.ap.telemetry.position)
        start = np.array(self._carrot) if self._carrot is not None else here
        target = np.array(goal, dtype=float)
        segment = target - start
        length = float(np.linalg.norm(segment))
        yaw = math.degrees(math.atan2(segment[1], segment[0])) if length > 0.05 else self.ap.telemetry.yaw_deg
        speed = self.settings.cruise_speed_m_s
        deadline = time.monotonic() + 20.0 + 3.0 * (length + float(np.linalg.norm(start - here))) / speed
        flying_to = f"waypoint {tuple(round(c, 2) for c in goal)}"  # what a missed deadline names
        travelled = min(max(lead, 0.0), length)
        separation = Separation()  # the manoeuvre (swarm.agent.separation): what to do about a drone nearby
        last_tick = time.monotonic() - SETPOINT_PERIOD_S
        slow_since: float | None = None  # when the drone came to rest and has stayed so (`still_since`)
        while True:
            if interrupt is not None and interrupt.is_set():
                separation = step(separation, Cue.INTERRUPTED, time.monotonic())
                return False
            now = time.monotonic()
            self.tick_periods.append(now - last_tick)
            tick_s, last_tick = min(now - last_tick, MAX_TICK_S), now
            self.heading_to = vec3(target)
            position = np.array(self.ap.telemetry.position)
            rival = self._rival(position, target)
            separation = step(separation, self._cue(rival), time.monotonic())
            if separation.manoeuvre == Manoeuvre.YIELD:
                assert rival is not None
                left_at: Vec3 = (float(position[0]), float(position[1]), float(position[2]))
                resume = left_at
                if await self._step_aside(rival.id, stop, interrupt):
                    # resume from the refuge if the way on is clear, else from where we left the segment; the
                    # deadline restarts
                    x, y, z = (float(c) for c in self.ap.telemetry.position)
                    way_to: Vec3 = (float(target[0]), float(target[1]), float(target[2]))
                    resume = resume_from((x, y, z), left_at, way_to, self.is_clear)
                    cue = Cue.WAY_ON_BLOCKED if resume == left_at else Cue.WAY_ON_CLEAR
                else:
                    cue = Cue.INTERRUPTED if interrupt is not None and interrupt.is_set() else Cue.YIELD_TIMED_OUT
                separation = step(separation, cue, time.monotonic())
                if separation.manoeuvre == Manoeuvre.REPLAN:
                    return False
                if separation.manoeuvre == Manoeuvre.REJOIN:
                    back = await self._fly_back_to(left_at, stop, interrupt)
                    separation = step(separation, Cue.BACK if back else Cue.NOT_BACK, time.monotonic())
                    if separation.manoeuvre == Manoeuvre.REPLAN:
                        return False
                start, travelled = np.array(resume), 0.0
                segment = target - start
                length = float(np.linalg.norm(segment))
                deadline = time.monotonic() + 20.0 + 3.0 * length / speed
                last_tick = time.monotonic() - SETPOINT_PERIOD_S  # the yield set its own setpoints
                continue
            if separation.manoeuvre == Manoeuvre.REPLAN:
                assert rival is not None
                self.log("blocked_by", peer=rival.id)
                self.blocked_by = (rival, time.monotonic())
                return False  # it is not moving off: the mission plans again
            if separation.manoeuvre == Manoeuvre.HOLD:
                # right of way, but someone is close and in our way: hold where we are (the carrot can be a
                # metre ahead, so merely not advancing it would carry us on into the other drone)
                deadline += SETPOINT_PERIOD_S  # holding does not count against the segment's time
                if length > 0:
                    along = float(np.dot(position - start, segment)) / length
                    travelled = min(travelled, max(along, 0.0))
                    if along < 0.0 or distance_to_line(position, start, target) > CROSS_TRACK_M:
                        # not on this segment yet (cutting the corner into it): hold right here, not at the
                        # corner or on the segment, where the straight way may not be checked
                        self._carrot = vec3(position)
                        await self.ap.set_setpoint(self._carrot, yaw)
                        await self._tick(stop, deadline, flying_to)
                        continue
            carrot = start + segment * (travelled / length) if length > 0 else target
            following = separation.manoeuvre == Manoeuvre.FOLLOW
            slow_since = still_since(slow_since, np.array(self.ap.telemetry.velocity), now)
            if following and travelled < length:
                ahead = min(length, travelled + speed * tick_s)
                proposed = start + segment * (ahead / length)
                lookahead = lookahead_before(float(np.linalg.norm(target - position)) + run_on)
                cut_is_clear = self._may_cut_to(position, proposed, start, gentle)
                rest_s = now - slow_since if slow_since is not None else 0.0
                if carrot_may_advance(position, rest_s, carrot, start, target, cut_is_clear, lookahead):
                    travelled, carrot = ahead, proposed
            self._carrot = vec3(carrot)
            await self.ap.set_setpoint(self._carrot, yaw)
            if travelled >= length and (through or np.linalg.norm(target - position) < tolerance):
                self.heading_to = None
                return True
            await self._tick(stop, deadline, flying_to)

    def _may_cut_to(self, position: np.ndarray, carrot: np.ndarray, corner: np.ndarray, gentle: bool = False) -> bool:
        """The map shows the straight way from the drone to `carrot` in open space (`is_roomy`: the planner's
        wider clearance), or the drone is within CORNER_CUT_M of the `corner` it turns at (the segment's start:
        on a path's first segment, where the drone was when it got the path), or the turn there is `gentle`, and
        the way is clear (`is_clear`, the planner's clearance). A carrot led round a corner only while this holds
        draws the drone through the fan of those ways (between the path and the chord, as it turns towards the
        carrot), every one of them checked. Narrow places (doorways, wall ends) are never roomy: there the drone
        turns on the path or, slowed down by then, within CORNER_CUT_M of its corner."""
        if not self.has_map:
            return False
        if self.is_roomy is not None and self.is_roomy(vec3(position), vec3(carrot)):
            return True
        near = gentle or float(np.linalg.norm(position - corner)) <= CORNER_CUT_M
        return near and self.is_clear(vec3(position), vec3(carrot))

    async def _fly_back_to(self, left_at: Vec3, stop: asyncio.Event, interrupt: asyncio.Event | None) -> bool:
        """Fly the step aside back, straight to where the segment was left, before going on along it. Going on at
        once, the carrot runs along the segment while the drone is still off it, and the drone cuts the corner
        between the two (from a step up in front of a door, its top went into the lintel)."""
        if float(np.linalg.norm(np.subtract(self.ap.telemetry.position, left_at))) <= REJOIN_TOLERANCE_M:
            return True
        self._carrot = vec3(self.ap.telemetry.position)
        return await self._fly_segment_to(left_at, stop, interrupt, tolerance=REJOIN_TOLERANCE_M)

    def _cue(self, rival: Neighbour | None) -> Cue:
        """What the separation manoeuvre is told about `rival`: a live lower id is given way to; any other is
        held for."""
        if rival is None:
            return Cue.CLEAR
        return Cue.GIVE_WAY if rival.id < self.settings.id and not rival.silent else Cue.HOLD_FOR

    def _rival(self, position: np.ndarray, target: np.ndarray) -> Neighbour | None:
        """The neighbour we must give way to (a lower id within the separation distance), or one we hold for: a
        higher id close to us and in the way of the rest of our segment to `target`, or a silent drone our
        segment would touch; else None. Close to us is now or within REACTION_S at both drones' velocities
        (`closest_approach`): two drones closing head-on at 3 m/s were 1.2 m apart a third of a second before
        they touched."""
        if self.separation_m <= 0:
            return None
        for n in sorted(self.neighbours(), key=lambda n: n.id):
            peer = np.asarray(n.position, dtype=float)
            distance = self._closest_approach(n, position)
            if n.silent or parked(n):
                # an obstacle, not a drone to give way to (stepping aside for it never ends: one hovering with
                # no target stays put): hold only when our segment would touch it, where it is or where it comes
                # down to; the planner routes around it
                sweep = [peer] if n.silent else where_it_will_be(n)
                touched = any(_in_the_way(p, position, target, SILENT_CLEAR_M) for p in sweep)
                if distance < self.separation_m and touched:
                    return n._replace(silent=True)
                continue
            if n.id < self.settings.id and distance < self.separation_m:
                return n
            if n.id > self.settings.id and distance < PRIORITY_PAUSE_FRACTION * self.separation_m:
                # where it is, or where it will be in a moment (one coming out of a doorway across our way); one
                # that waits where it stepped aside to is held for only when our segment would touch it: it moves
                # on once we pass, and holding for it deadlocks both (box: 190 s, our way round it 0.56 m off)
                clearance = SILENT_CLEAR_M if waiting_aside(n) else PASS_CLEARANCE_M
                soon = peer + np.asarray(n.velocity, dtype=float) * ENTERING_HORIZON_S
                if any(_in_the_way(p, position, target, clearance) for p in (peer, soon)):
                    return n
        return None

    async def _step_aside(self, peer_id: int, stop: asyncio.Event, interrupt: asyncio.Event | None) -> bool:
        """Give way to `peer_id`: move up or down (or back) out of its way until it is past; False if that took
        longer than MAX_YIELD_S or we were interrupted."""
        self.yields += 1
        peer = self._neighbour(peer_id)
        refuge = self._take_refuge(peer_id, peer)
        chosen_for = None if peer is None else peer.heading_to
        end = time.monotonic() + MAX_YIELD_S
        parked_since: float | None = None
        while time.monotonic() < end:
            if interrupt is not None and interrupt.is_set():
                return False
            await self.ap.set_setpoint(refuge, self.ap.telemetry.yaw_deg)
            peer = self._neighbour(peer_id)
            if peer is None or self._past(peer):
                return True
            # a peer that stopped with no segment to fly (it hovers at its goal or comes down to land) will not
            # pass: it is an obstacle now, which `_rival` holds for only when our way on would touch it. Parked
            # for a while, not between two paths: ended at once, a yield began again 0.2 s later, four times.
            now = time.monotonic()
            if not parked(peer):
                parked_since = None
            elif parked_since is None:
                parked_since = now
            if parked_since is not None and now - parked_since >= PARKED_FOR_S:
                return True
            # The refuge was chosen off the peer's segment of the moment; when the peer turns onto its next one
            # (its last, often: home) through our refuge, both would wait there until they time out.
            if peer.heading_to != chosen_for and refuge_in_the_way(np.asarray(refuge, dtype=float), peer):
                refuge = self._take_refuge(peer_id, peer)
                chosen_for = peer.heading_to
            await self._pause(stop)
        return False

    def _past(self, peer: Neighbour) -> bool:
        """`peer`, given way to, is past: farther than the separation (and PASS_HYSTERESIS_M) and not coming
        within it over REACTION_S, the test `_rival` gives way by. On the distance alone a drone closing from
        beyond it was given way to and found past at once, again and again, every few milliseconds."""
        here = np.asarray(self.ap.telemetry.position, dtype=float)
        far = (
            float(np.linalg.norm(np.asarray(peer.position, dtype=float) - here)) > self.separation_m + PASS_HYSTERESIS_M
        )
        return far and self._closest_approach(peer, here) >= self.separation_m

    def _closest_approach(self, n: Neighbour, position: np.ndarray) -> float:
        """How close `n` comes to us at `position` over REACTION_S, both at our velocities (`closest_approach`)."""
        relative = np.asarray(n.velocity, dtype=float) - np.asarray(self.ap.telemetry.velocity, dtype=float)
        return closest_approach(np.asarray(n.position, dtype=float) - position, relative, REACTION_S)

    def _take_refuge(self, peer_id: int, peer: Neighbour | None) -> Vec3:
        """Set the carrot on a refuge out of `peer`'s way (where we are, without one), and return it."""
        here = np.array(self.ap.telemetry.position)
        refuge = here
        if peer is not None:
            start = vec3(here)
            everyone = self.neighbours()
            others = [n for n in everyone if n.id != peer_id]
            candidates = moves_clear_of(here, off_the_others_ways(refuge_candidates(here, peer), others), everyone)
            safe = [c for c in candidates if self.is_clear(start, vec3(c))]
            refuge = choose_refuge(safe, peer, here) if safe else here
        self.log("give_way", to=peer_id, refuge=[round(float(v), 2) for v in refuge])
        self._carrot = vec3(refuge)
        self.heading_to = self._carrot
        return self._carrot

    async def _wait_for_room_below(self) -> None:
        """Before descending: hold (at most MAX_YIELD_S) while another drone flies under us; one that sits on the
        ground there (a failsafe landing) will not move off, so we move beside it instead."""
        end = time.monotonic() + MAX_YIELD_S
        logged = False
        while self.separation_m > 0 and time.monotonic() < end:
            below = self._below()
            if not below:
                return
            if any(n.silent or self._on_the_ground(n) for n in below):  # it will not move off
                break
            if not logged:
                self.log("landing_waits", below=[n.id for n in below])
                logged = True
            await asyncio.sleep(SETPOINT_PERIOD_S)
        below = self._below()
        if below:
            await self._move_beside(below)

    def _below(self) -> list[Neighbour]:
        here = self.ap.telemetry.position
        return [
            n
            for n in self.neighbours()
            if n.position[2] < here[2] and math.dist(n.position[:2], here[:2]) < LAND_CLEAR_M
        ]

    def _on_the_ground(self, n: Neighbour) -> bool:
        home = self.ap.home_world
        return home is not None and n.position[2] - home[2] < GROUNDED_M and math.hypot(*n.velocity) < SLOW_M_S

    async def _move_beside(self, below: list[Neighbour]) -> None:
        """Fly to the nearest safe spot LAND_ASIDE_M from the drones below, at our height, clear of every other
        drone (at most MAX_YIELD_S)."""
        here = np.array(self.ap.telemetry.position)
        centre = np.mean([n.position[:2] for n in below], axis=0)
        others = [np.asarray(n.position[:2], dtype=float) for n in self.neighbours()]
        spots = [
            np.array([centre[0] + LAND_ASIDE_M * math.cos(a), centre[1] + LAND_ASIDE_M * math.sin(a), here[2]])
            for a in np.linspace(0.0, 2 * math.pi, 8, endpoint=False)
        ]
        spots.sort(key=lambda c: float(np.linalg.norm(c - here)))
        start = vec3(here)
        clear = [
            c
            for c in spots
            if self.is_clear(start, vec3(c)) and all(np.linalg.norm(c[:2] - o) >= LAND_CLEAR_M for o in others)
        ]
        if not clear:
            self.log("land_beside", below=[n.id for n in below], spot=None)
            return
        spot = clear[0]
        self.log("land_beside", below=[n.id for n in below], spot=[round(float(v), 2) for v in spot])
        self._carrot = vec3(spot)
        end = time.monotonic() + MAX_YIELD_S
        while time.monotonic() < end:
            await self.ap.set_setpoint(self._carrot, self.ap.telemetry.yaw_deg)
            if np.linalg.norm(np.array(self.ap.telemetry.position) - spot) < LAND_SPOT_TOLERANCE_M:
                return
            await asyncio.sleep(SETPOINT_PERIOD_S)

    def _neighbour(self, peer_id: int) -> Neighbour | None:
        return next((n for n in self.neighbours() if n.id == peer_id), None)

    async def _wait(self, seconds: float, stop: asyncio.Event) -> None:
        """Wait on the ground or in the air, still watching for a stop request and for lost telemetry."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            await self._pause(stop)

    async def _land(self) -> Phase:
        if not self.airborne:
            self._set_phase(Phase.LANDED)
            return self.phase
        self._set_phase(Phase.LANDING)
        self.heading_to = None
        try:
            await self.ap.hold()
        except FlightError as exc:
            self.log("flight_error", reason=str(exc))
        await self._wait_for_room_below()
        try:
            await self.ap.land()
            await self._see_landing_through(LAND_TIMEOUT_S)
        except FlightError as exc:
            self.log("flight_error", reason=str(exc))
            self._set_phase(Phase.FAILED)
            return self.phase
        self.airborne = False
        self._set_phase(Phase.LANDED)
        return self.phase

    async def _see_landing_through(self, timeout_s: float, blind_s: float = math.inf) -> None:
        """Wait until the drone is on the ground and disarmed, commanding land again whenever fresh telemetry
        shows it airborne in another mode for `RELAND_AFTER_S`; raises FlightError after `timeout_s`, or once
        no telemetry has come for `blind_s`."""
        deadline = time.monotonic() + timeout_s
        not_landing_since: float | None = None
        while True:
            t = self.ap.telemetry
            if t.landed_state == "ON_GROUND" and not t.armed:
                return
            now = time.monotonic()
            if now > deadline:
                raise FlightError(f"timed out after {timeout_s:.0f} s waiting for landing and disarm")
            if self.ap.telemetry_age_s > blind_s:
                raise FlightError(f"no telemetry for {self.ap.telemetry_age_s:.0f} s: the landing cannot be seen")
            fresh = self.ap.telemetry_age_s < self.settings.telemetry_timeout_s
            if not fresh or t.flight_mode == "LAND" or t.landed_state == "ON_GROUND":
                not_landing_since = None
            elif not_landing_since is None:
                not_landing_since = now
            elif now - not_landing_since > RELAND_AFTER_S:
                self.log("reland", mode=t.flight_mode, height=round(self.ap.height_above_home, 2))
                not_landing_since = None
                try:
                    await self.ap.land()
                except FlightError as exc:
                    self.log("flight_error", reason=str(exc))
            await asyncio.sleep(SETPOINT_PERIOD_S)

    async def _taken_over(self, mode: str, stop: asyncio.Event) -> None:
        """A pilot or PX4's own failsafe has the vehicle: command nothing more, and watch it until it is down and
        disarmed (phase failsafe: the drone is out of the mission, and where it lands is not this agent's)."""
        self.ap.offboard_active = False
        self.log("taken_over", mode=mode, position=[round(v, 2) for v in self.ap.telemetry.position])
        self._set_phase(Phase.FAILSAFE)
        while not (self.ap.telemetry.landed_state == "ON_GROUND" and not self.ap.telemetry.armed):
            if stop.is_set():
                self.log("stop_requested", airborne=True)
                return
            await asyncio.sleep(SETPOINT_PERIOD_S)
        self.airborne = False
        self.log("taken_over_landed", mode=self.ap.telemetry.flight_mode)

    async def _fail_safe(self) -> None:
        """Hold, then land, then watch the landing through if telemetry comes back; without telemetry we cannot
        confirm the landing, and the flight ends in FAILSAFE either way.

        Short timeouts: both commands must leave before MAVSDK declares the link lost (3 s without a heartbeat)
        and stops sending; the vehicle may still hear us even though we no longer hear it.
        """
        self._set_phase(Phase.FAILSAFE)
        for command in (self.ap.hold, self.ap.land):
            try:
                await command(timeout_s=FAILSAFE_COMMAND_TIMEOUT_S)
                self.log("failsafe_command", command=command.__name__, accepted=True)
            except FlightError as exc:
                self.log("failsafe_command", command=command.__name__, accepted=False, reason=str(exc))
        try:
            await self._see_landing_through(LAND_TIMEOUT_S, blind_s=FAILSAFE_BLIND_S)
        except FlightError as exc:
            self.log("failsafe_unconfirmed", reason=str(exc))
            return
        self.airborne = False
        self.log("failsafe_landed")

    # -- helpers -----------------------------------------------------------------------------------------

    async def _pause(self, stop: asyncio.Event) -> None:
        """One setpoint period of a loop that its own clock ends (a look, a yield, a wait): a late wake-up (this
        process starved for seconds on a loaded machine) ends that loop, not the flight, so no deadline here."""
        self._check(stop)
        await asyncio.sleep(SETPOINT_PERIOD_S)
        self._check(stop)

    async def _tick(self, stop: asyncio.Event, deadline: float, what: str) -> None:
        self._check(stop)
        if time.monotonic() > deadline:
            raise FlightError(f"timed out flying to {what}")
        await asyncio.sleep(SETPOINT_PERIOD_S)
        self._check(stop)

    def _check(self, stop: asyncio.Event) -> None:
        if stop.is_set():
            raise StopRequested
        now = time.monotonic()
        if now - self._last_check > STALL_S:
            self.log("stalled", seconds=round(now - self._last_check, 2))  # SIGSTOP, starved, or a long plan
        self._last_check = now
        self._check_battery()
        taken_over_by = self.ap.taken_over_by()
        if taken_over_by is not None:
            raise TakenOver(taken_over_by)
        timeout = self.settings.telemetry_timeout_s
        if self.airborne and self.ap.telemetry_age_s > timeout:
            # Telemetry is old; but while this process did not run (SIGSTOP, starved) samples queued up unread,
            # so only the silence it was awake to hear counts (swarm.agent.watchdog).
            last_sample = self.ap.telemetry.updated
            heard = self.loop_monitor.heard_silence(now, last_sample)
            if heard > timeout:
                raise TelemetryLost(
                    f"no position telemetry for {self.ap.telemetry_age_s:.1f} s ({heard:.1f} s of it heard)"
                )
            if self._excused_sample != last_sample:
                self._excused_sample = last_sample
                self.log("telemetry_gap_unheard", age=round(self.ap.telemetry_age_s, 2), heard=round(heard, 2))

    def _check_battery(self) -> None:
        """In the mission or the hover after it, once: a battery below agent.battery_home_fraction raises
        BatteryLow (NaN, no battery telemetry, never does)."""
        if self.battery_low or self.phase not in (Phase.FLYING, Phase.HOVERING):
            return
        fraction, threshold = self.ap.telemetry.battery, self.settings.battery_home_fraction
        if fraction < threshold:
            self.battery_low = True
            here = [round(v, 2) for v in self.ap.telemetry.position]
            self.log("battery_low", fraction=round(fraction, 3), threshold=threshold, airborne=True, position=here)
            raise BatteryLow

    def way_back(self) -> list[Vec3]:
        """Back through the waypoints reached since take-off to the point above home it took off to (`way_back`)."""
        home = self.ap.home_world
        above = [] if home is None else [(home[0], home[1], home[2] + self.settings.altitude_m)]
        return way_back([*above, *self.reached], self.settings.waypoint_tolerance_m)

    def setpoint_periods(self) -> dict[str, float]:
        """Seconds between two setpoints along segments (the last TICKS_KEPT), at the median, 95th percentile and
        worst: how late this process's loop ticked while it led the drone (SETPOINT_PERIOD_S when on time)."""
        if not self.tick_periods:
            return {}
        p50, p95 = np.percentile(self.tick_periods, [50, 95])
        return {"p50": round(float(p50), 3), "p95": round(float(p95), 3), "max": round(max(self.tick_periods), 3)}

    def update_distance(self) -> None:
        """Accumulate travelled distance from telemetry; called at the heartbeat rate."""
        p = self.ap.telemetry.position
        if not all(math.isfinite(c) for c in p):
            return
        current = np.array(p)
        if self._last_position is not None:
            self.distance_m += float(np.linalg.norm(current - self._last_position))
        self._last_position = current


def route_mission(route: list[Vec3]) -> Mission:
    """A mission that flies a fixed route (the harness's scripted routes, or waypoints given in the config)."""

    async def fly(flight: Flight, stop: asyncio.Event) -> None:
        await flight.fly_path(route, stop)

    return fly


async def retrace(flight: Flight, stop: asyncio.Event) -> None:
    """The way home without a map (a scripted route): back through the waypoints reached, loops cut out, to
    above home."""
    if not await flight.fly_path(flight.way_back(), stop):
        flight.log("land_in_place", reason="kept giving way")


def way_back(flown: list[Vec3], tolerance: float) -> list[Vec3]:
    """The way from the last point of a flown path back to its first: its points in reverse, each loop cut out
    (from a point the path came through before, on from where it first left it). Every leg was flown, one way."""
    back: list[Vec3] = []
    j = len(flown) - 1
    while j >= 0:
        back.append(flown[j])
        j = next(i for i in range(j + 1) if math.dist(flown[i], flown[j]) <= tolerance) - 1
    return back


def carried_lead(here: Vec3, carrot: Vec3 | None, first_waypoint: Vec3) -> float:
    """How far along a new path's first segment (from `here` to `first_waypoint`) its carrot starts: the old
    carrot's lead on the drone in that direction, within the look-ahead and the segment; 0 without an old carrot or
    when it led elsewhere (a U-turn starts from the drone)."""
    if carrot is None:
        return 0.0
    first = np.subtract(first_waypoint, here)
    length = float(np.linalg.norm(first))
    if length < 1e-6:
        return 0.0
    along = float(np.dot(np.subtract(carrot, here), first)) / length
    return min(max(along, 0.0), lookahead_before(length), length)


def gentle_turns(start: Vec3, path: list[Vec3]) -> tuple[list[bool], list[float]]:
    """For each segment of `path` (the one ending at each waypoint, the first from `start`, where the drone is):
    whether it starts with a turn of at most GENTLE_TURN_DEG (the first never does: the drone's way in is not
    on the path), and how far the path runs on from its end through such turns (up to the distance at which the
    carrot's lead starts to taper, beyond which it makes no difference)."""
    legs = np.diff(np.asarray([start, *path], dtype=float), axis=0)  # legs[i]: segment i
    lengths = np.linalg.norm(legs, axis=1)
    n = len(path)
    gentle = [i > 0 and _turn_deg(legs[i - 1], legs[i]) <= GENTLE_TURN_DEG for i in range(n)]
    run_on = [0.0] * n
    for i in range(n - 2, -1, -1):
        if gentle[i + 1]:
            run_on[i] = min(float(lengths[i + 1]) + run_on[i + 1], LOOKAHEAD_NEAR_M + LOOKAHEAD_TAPER_M)
    return gentle, run_on


def _turn_deg(incoming: np.ndarray, outgoing: np.ndarray) -> float:
    """The angle between two legs' directions; 0 when either has no length (no direction to turn from)."""
    a, b = float(np.linalg.norm(incoming)), float(np.linalg.norm(outgoing))
    if a < 1e-9 or b < 1e-9:
        return 0.0
    cosine = float(np.dot(incoming, outgoing)) / (a * b)
    return math.degrees(math.acos(min(1.0, max(-1.0, cosine))))


def lookahead_before(remaining: float) -> float:
    """How far the carrot may lead a drone `remaining` metres from its segment's end."""
    taper = min(max(remaining - LOOKAHEAD_NEAR_M, 0.0) / LOOKAHEAD_TAPER_M, 1.0)
    return LOOKAHEAD_M + (LOOKAHEAD_OPEN_M - LOOKAHEAD_M) * taper


def still_since(since: float | None, velocity: np.ndarray, now: float) -> float | None:
    """When the drone came to rest (slower than SLOW_M_S) and has stayed at rest since, else None (moving)."""
    if float(np.linalg.norm(velocity)) >= SLOW_M_S:
        return None
    return now if since is None else since


def carrot_may_advance(
    position: np.ndarray,
    rest_s: float,
    carrot: np.ndarray,
    start: np.ndarray,
    target: np.ndarray,
    cut_is_clear: bool = False,
    lookahead: float = LOOKAHEAD_M,
) -> bool:
    """The carrot may run on along the segment start-target: it is less than `lookahead` ahead of the drone,
    and the drone is on the segment's line (within CROSS_TRACK_M of it: a drone short of a waypoint on the
    straight way on is on it, one short of a corner is not), or the map shows the straight way from the drone to
    the carrot's next place clear (`cut_is_clear`: the drone may cut the corner), or it has been at rest off the
    line for REST_S (`rest_s`: it will get no closer, and a steady offset must not stall the segment).

    At rest for a while, not for a moment: a drone turning back passes through rest, and a carrot that ran on then
    drew it along a chord from where its momentum had taken it, past the corner: a drone carried 0.3 m beside a
    door's jamb by its last path turned at rest there onto the next segment and touched the jamb (gen:1).

    Why the drone must be on the segment first: a waypoint counts as reached within `waypoint_tolerance_m`
    (0.3 m), and planned paths keep only `clearance_m` (5 cm more than the airframe) from obstacles. A carrot
    that ran on from the corner at once drew the drone along a chord from where it was, inside the corner: a
    drone arriving at a doorway from above entered it 0.1 m higher than planned, 0.04 m under the lintel."""
    if float(np.linalg.norm(carrot - position)) >= lookahead:
        return False
    on_track = distance_to_line(position, start, target) <= CROSS_TRACK_M
    return on_track or cut_is_clear or rest_s >= REST_S


def resume_from(here: Vec3, left_at: Vec3, target: Vec3, is_clear: Callable[[Vec3, Vec3], bool]) -> Vec3:
    """Where a drone that stepped aside takes up its segment to `target` again: from `here` when the straight way
    on is clear, else from `left_at`, where it left the segment (flying back along the step it took)."""
    return here if is_clear(here, target) else left_at


def refuge_candidates(here: np.ndarray, peer: Neighbour) -> list[np.ndarray]:
    """Points STEP_ASIDE_M, then twice that, from `here`: vertically away from the peer then towards it, straight
    away from it horizontally, and to either side of its way (its segment, else its velocity)."""
    away = here - np.asarray(peer.position, dtype=float)
    up = np.array([0.0, 0.0, 1.0 if away[2] >= 0 else -1.0])
    directions = [up, -up, np.array([away[0], away[1], 0.0])]
    way = np.asarray(peer.velocity, dtype=float)
    if peer.heading_to is not None:
        way = np.asarray(peer.heading_to, dtype=float) - np.asarray(peer.position, dtype=float)
    directions += [np.array([-way[1], way[0], 0.0]), np.array([way[1], -way[0], 0.0])]
    units = [d / np.linalg.norm(d) for d in directions if np.linalg.norm(d) > 1e-6]
    return [here + u * step for step in (STEP_ASIDE_M, 2 * STEP_ASIDE_M) for u in units]


def off_the_others_ways(candidates: list[np.ndarray], others: list[Neighbour]) -> list[np.ndarray]:
    """The refuges at least REFUGE_CLEAR_M off every other drone's way: stepping aside for one drone must not
    put us in the path of another (a drone leaving a doorway for one behind it met a third in the corridor)."""
    return [c for c in candidates if all(distance_to_track(c, n) >= REFUGE_CLEAR_M for n in others)]


def moves_clear_of(here: np.ndarray, candidates: list[np.ndarray], neighbours: list[Neighbour]) -> list[np.ndarray]:
    """The refuges reached without passing within PASS_CLEARANCE_M of a drone: a drone under us must not be
    stepped down onto (with the ceiling above, "down" was the only vertical step left, and it went through the
    drone it gave way to)."""
    return [
        c
        for c in candidates
        if all(
            distance_to_segment(np.asarray(n.position, dtype=float), here, c) >= PASS_CLEARANCE_M for n in neighbours
        )
    ]


def parked(peer: Neighbour) -> bool:
    """A live drone with no segment to fly and no horizontal speed: hovering (no target, or waiting at home) or
    coming straight down to land. It will not move off for us. Stepping aside for it, the way a drone gives way
    to a lower id, only ends when the yield times out, and the same path then meets it again (box, 3 drones:
    drone 3 gave way to idle drone 2 for 200 s; a drone whose home is next to a landing one's waited for it to
    touch down)."""
    return peer.heading_to is None and math.hypot(peer.velocity[0], peer.velocity[1]) < SLOW_M_S


def where_it_will_be(peer: Neighbour, horizon_s: float = TRACK_HORIZON_S) -> list[np.ndarray]:
    """Where a parked `peer` is and will be over `horizon_s` at its velocity, a second apart: a drone coming
    down to land sweeps the column under it, and a segment under it is in its way."""
    here, velocity = np.asarray(peer.position, dtype=float), np.asarray(peer.velocity, dtype=float)
    return [here + velocity * t for t in np.arange(0.0, horizon_s + 1e-9, 1.0)]


def waiting_aside(peer: Neighbour) -> bool:
    """A live drone hovering where it is heading (a refuge it stepped aside to): it waits for someone to pass."""
    if peer.heading_to is None or float(np.linalg.norm(peer.velocity)) >= SLOW_M_S:
        return False
    return float(np.linalg.norm(np.subtract(peer.position, peer.heading_to))) < WAITING_AT_M


def choose_refuge(candidates: list[np.ndarray], peer: Neighbour, here: np.ndarray) -> np.ndarray:
    """The first candidate at least REFUGE_CLEAR_M off the peer's way (the nearest steps come first), else, of
    those no closer to the peer than `here`, the one farthest off its way, else `here`. A hovering peer going
    nowhere has no way: the first candidate (up or down) it is.

    Why never closer: in a cramped spot none is clear of the peer's way, and the one farthest off its segment of
    the moment lay on its next one, 0.6 m towards it (gen:1, two drones leaving their take-off pocket head-on
    touched there). Waiting where it is, the drone is an obstacle the peer holds for or passes."""
    if parked(peer):
        return candidates[0]
    clear = [c for c in candidates if distance_to_track(c, peer) >= REFUGE_CLEAR_M]
    if clear:
        return clear[0]
    peer_at = np.asarray(peer.position, dtype=float)
    now_apart = float(np.linalg.norm(here - peer_at))
    backing_off = [c for c in candidates if float(np.linalg.norm(c - peer_at)) >= now_apart]
    return max(backing_off, key=lambda c: distance_to_track(c, peer)) if backing_off else here


def refuge_in_the_way(refuge: np.ndarray, peer: Neighbour) -> bool:
    """The peer's way comes closer than REFUGE_CLEAR_M to `refuge`, and it is going somewhere (a parked peer has
    no way; `choose_refuge` takes the nearest step for it)."""
    return not parked(peer) and distance_to_track(refuge, peer) < REFUGE_CLEAR_M


def distance_to_track(point: np.ndarray, peer: Neighbour) -> float:
    """Distance from `point` to the peer's way: the segment it is flying (to `heading_to`), else the one it
    covers in TRACK_HORIZON_S at its current velocity."""
    start = np.asarray(peer.position, dtype=float)
    if peer.heading_to is not None:
        return distance_to_segment(point, start, np.asarray(peer.heading_to, dtype=float))
    return distance_to_segment(point, start, start + np.asarray(peer.velocity, dtype=float) * TRACK_HORIZON_S)


def closest_approach(offset: np.ndarray, relative_velocity: np.ndarray, horizon_s: float) -> float:
    """The least distance between two drones over the next `horizon_s`, the other at `offset` from us and moving
    at `relative_velocity` relative to us, both at constant velocity (the distance now when they move apart)."""
    speed2 = float(np.dot(relative_velocity, relative_velocity))
    soonest = 0.0 if speed2 <= 0.0 else min(max(-float(np.dot(offset, relative_velocity)) / speed2, 0.0), horizon_s)
    return float(np.linalg.norm(offset + relative_velocity * soonest))


def _in_the_way(peer: np.ndarray, position: np.ndarray, target: np.ndarray, clearance: float) -> bool:
    """`peer` is ahead of us on the way to `target` and closer than `clearance` to that segment."""
    ahead = float(np.dot(peer - position, target - position)) > 0
    return ahead and distance_to_segment(peer, position, target) < clearance


def distance_to_segment(point: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    return _distance_along(point, a, b, clamped=True)


def distance_to_line(point: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    """Distance from `point` to the infinite line through `a` and `b` (to `a` when they coincide)."""
    return _distance_along(point, a, b, clamped=False)


def _distance_along(point: np.ndarray, a: np.ndarray, b: np.ndarray, clamped: bool) -> float:
    """Distance from `point` to its projection on the line a-b, kept between a and b when `clamped`."""
    ab = np.asarray(b, dtype=float) - a
    span = float(np.dot(ab, ab))
    along = 0.0 if span < 1e-12 else float(np.dot(point - a, ab)) / span
    if clamped:
        along = min(max(along, 0.0), 1.0)
    return float(np.linalg.norm(point - (a + along * ab)))
