"""The agent process: one drone's flight, map, presence and peer table, supervised under one asyncio loop.

Tasks: the flight (MAVSDK), the mapping task (depth frames into patches while airborne, in a worker thread),
the patch sync (push on seal, pull what is missing, serve what is held), the heartbeat publisher (AgentState
with the patch holdings at `heartbeat_hz`, and soon after the holdings change, best effort), and the
membership upkeep (expire silent peers, re-elect). A liveliness token announces the agent. SIGINT/SIGTERM ask
the flight to land and the process to exit at once after it; a second signal exits immediately. After a normal
landing the open patch is sealed and pushed, and the agent lingers on the bus until every peer has finished
(landed, last patch sealed) and holds the same patches (bounded by `sync.linger_max_s`); then its mesh and
summary are written and the bus is closed. These are the process stages flight, lingering and exiting
(`swarm.agent.lifecycle.Stage`); the heartbeat keeps the flight's final phase through them.
"""

from __future__ import annotations

import asyncio
import faulthandler
import math
import os
import signal
import sys
import time
from collections.abc import Coroutine
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, NoReturn

import numpy as np
import zenoh

from swarm.agent.autopilot import Autopilot, local_frame
from swarm.agent.epoch import next_epoch
from swarm.agent.events import EventLog, log_if_failed
from swarm.agent.exploration import Exploration
from swarm.agent.flight import Flight, Mission, Neighbour, parked, retrace, route_mission
from swarm.agent.lifecycle import Stage, next_stage
from swarm.agent.mapping import MappingTask
from swarm.agent.sensing import StreamSource
from swarm.agent.summary import NO_MAPPING, SCRIPTED_EXPLORATION, AgentSummary
from swarm.aio import wait_event
from swarm.bus.bridge import AsyncBus
from swarm.bus.messages import AgentState
from swarm.bus.phase import AIRBORNE_PHASES, Phase
from swarm.config import ConfigError, SwarmConfig, vec3
from swarm.errors import BusError
from swarm.files import write_model
from swarm.patches.lattice import Lattice
from swarm.patches.patch import PatchId
from swarm.patches.sealer import patch_block_limit
from swarm.patches.signing import load_signing
from swarm.patches.wire import decode_expected
from swarm.roles.membership import PeerTable
from swarm.sensing.frames import camera_mount
from swarm.sensing.peers import PeerSighting
from swarm.sensing.replay_source import BagReplaySource
from swarm.sensing.ros2_source import Ros2SensorSource
from swarm.sensing.zenoh_source import ZenohSensorSource
from swarm.stages import StageClock
from swarm.sync.service import PatchSync

EXIT_OK, EXIT_FLIGHT_FAILED, EXIT_FAILSAFE = 0, 1, 3
LINGER_POLL_S = 0.2
MIN_HEARTBEAT_GAP_S = 0.05
TIMELINE_PERIOD_S = 1.0
# A peer whose token is alive and heartbeats silent this long (heartbeats come at 5 Hz or more) is one we have
# gone deaf to: our subscriptions are declared again, at most every ROUTE_REFRESH_GAP_S (swarm.roles.membership).
DEAF_AFTER_S = 1.5
ROUTE_REFRESH_GAP_S = 2.0
NEIGHBOUR_FRESH_S = 1.0  # a peer heard longer ago than this is not extrapolated: it is taken to hover there


def agent_command(config: SwarmConfig) -> NoReturn:
    faulthandler.register(signal.SIGUSR1, all_threads=True)  # `kill -USR1 <pid>`: every thread's stack to the log
    zenoh.init_log_from_env_or("error")  # Zenoh's own errors to the log; RUST_LOG=zenoh=debug for more
    code = asyncio.run(Agent(config).run())
    # Everything is written and every session closed by now. Leave without the interpreter's teardown: about one
    # agent in eight office runs exited 1 after a clean landing and a logged `exit`, with no Python traceback,
    # while the native libraries (MAVSDK, Zenoh, Open3D) were unloading.
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


class Agent:
    def __init__(self, config: SwarmConfig) -> None:
        self.config = config
        self.id = config.agent.id
        self.log = EventLog(self.id)
        # never one an earlier process of this drone used, and larger (swarm.agent.epoch)
        self.epoch = next_epoch(config.agent.state_dir, self.id, time.time_ns() // 1_000_000, self.log)
        self.lattice = Lattice.from_settings(config.mapping)
        signing_dir = config.signing_dir()
        self.signing = load_signing(signing_dir, self.id) if signing_dir is not None else None
        self.peers = PeerTable(self.id, timeout_s=config.agent.peer_timeout_s, on_change=self._on_membership)
        self.route_refreshes = 0  # times the bus's subscriptions were declared again for a peer we were deaf to
        self.peer_events: list[dict[str, Any]] = []
        self.stop = asyncio.Event()
        self.started = time.time()
        self._seq = 0
        self._last_leader = self.id
        self._announce = asyncio.Event()
        self.finished = False
        self.stage = Stage.FLIGHT  # the process around the flight (swarm.agent.lifecycle): flight, lingering, exiting
        self.keys_mismatch = 0
        self.exploration: Exploration | None = None
        self.timeline: list[list[float]] = []  # [t since start, bytes sent, bytes received], once a second
        self.sharing = config.explore.strategy != "frontier-only"
        self._last_seen: dict[int, tuple[Phase, tuple[float, float, float]]] = {}  # peer -> (phase, position)
        self.lost_in_air: dict[int, tuple[float, float, float]] = {}  # peers that vanished while flying
        self.clock = StageClock()  # what each stage costs, for the summary (swarm.stages)

    async def run(self) -> int:
        loop = asyncio.get_running_loop()
        # MAVSDK runs every plugin call in the default executor: size it so telemetry never starves.
        loop.set_default_executor(ThreadPoolExecutor(self.config.agent.mavsdk_threads, thread_name_prefix="mavsdk"))
        self._install_signal_handlers(loop)
        self.log("starting", epoch=self.epoch, autopilot=self.config.agent.autopilot, pid=os.getpid())
        mapping = await self._start_mapping(loop)
        try:
            bus = await AsyncBus.open(self.config.agent_bus(), self.config.mission.name)
        except BaseException:
            if mapping is not None:
                await mapping.abandon()
            raise
        autopilot = Autopilot(
            self.config.agent.autopilot,
            self.config.mission.origin,
            self.config.agent.command_timeout_s,
            local_frame(self.config.agent),
        )
        exploring = self.config.explore.strategy != "scripted"
        self.flight = Flight(
            autopilot,
            self.config.agent,
            self.log,
            separation_m=self.config.explore.separation_m if exploring else 0.0,
            neighbours=self._neighbours,
            is_clear=self._is_clear,
            is_roomy=self._is_roomy,
            crew_size=self.config.mission.drones,
            peers_heard=self.peers.last_heartbeat.keys,
        )
        keys = self.keys = bus.keys
        mapping_stop = asyncio.Event()
        self.sync = PatchSync(
            bus,
            self.config.sync,
            self.id,
            sink=mapping.receive if mapping is not None else self._validate_only,
            position=self._position,
            max_patch_bytes=self.config.mapping.max_patch_bytes,
            on_holdings_changed=self._announce.set,
            share=self.sharing,
            own_epoch=self.epoch,
        )
        mission: Mission = route_mission(list(self.config.agent.waypoints))
        homeward: Mission = retrace  # a low battery ends the mission: back the way the route came
        if exploring and mapping is not None:
            self.exploration = Exploration(
                self.config,
                self.epoch,
                bus,
                self.peers,
                mapping,
                self._position,
                lambda: autopilot.home_world,
                float(mapping.bounds[1][2]),
                self.log,
                obstacles=self._obstacles,
                clock=self.clock,
                patches_to_come=self.sync.scheduler.missing_from,
            )
            self.exploration.start()
            mission, homeward = self.exploration.fly, self.exploration.fly_home
        if mapping is not None:
            found = await mapping.recover()
            for pid, data in found.patches:
                self.sync.add_recovered(pid, data)
            if found.patches or found.rejected or found.stale_temp:
                self.log(
                    "recovered",
                    patches=len(found.patches),
                    rejected=sum(found.rejected.values()),
                    reasons=found.rejected,
                    stale_temp_removed=found.stale_temp,
                    state_dir=str(mapping.state_dir),
                )
        bus.declare_token(keys.alive(self.id))
        bus.subscribe(keys.all_states, AgentState, self._on_state)
        bus.watch_liveliness(keys.all_alive, self._on_token_join, self._on_token_leave)
        self.sync.start()
        background = [
            self._background(self._heartbeat(bus), "heartbeat"),
            self._background(self._upkeep(bus), "upkeep"),
        ]
        if mapping is not None:
            self._run_mapping(mapping, autopilot, mapping_stop, background)
        final = Phase.FAILED
        released = False
        try:
            final = await self.flight.run(mission, self.stop, homeward)
            self.log("flight_ended", phase=final.value, setpoint_period_s=self.flight.setpoint_periods())
        finally:
            mapping_stop.set()
            released = await autopilot.close()
            if mapping is not None:
                await mapping.seal_last()
            self.finished = True  # the last own patch is held now: heartbeats say our holdings are final
            self._announce.set()
            if self.exploration is not None:
                await self.exploration.close()
            if not self.stop.is_set() and self.sharing:
                self.stage = next_stage(self.stage, Stage.LINGERING)
                await self._linger()
            self.stage = next_stage(self.stage, Stage.EXITING)
            self._publish_state(bus)  # the last phase and holdings go out before we leave
            for task in background:
                task.cancel()
            await asyncio.gather(*background, return_exceptions=True)
            await self.sync.stop()
            if mapping is not None:
                await mapping.close()
            self._write_summary(bus, final, released, mapping)
            await bus.close()
        self.log("exit", phase=final.value)
        return {Phase.LANDED: EXIT_OK, Phase.FAILSAFE: EXIT_FAILSAFE}.get(final, EXIT_FLIGHT_FAILED)

    async def _start_mapping(self, loop: asyncio.AbstractEventLoop) -> MappingTask | None:
        """The mapping task with its camera started (None with camera.source = "none"). A camera that cannot be
        used is a ConfigError or SwarmError of one line, raised before the agent opens the bus or connects to its
        autopilot: the drone does not take off without it."""
        mapping = self._make_mapping(loop)
        if mapping is not None:
            await mapping.start()
        return mapping

    def _make_mapping(self, loop: asyncio.AbstractEventLoop) -> MappingTask | None:
        camera = self.config.camera
        if camera.source == "none":
            return None

        def on_sealed(pid: PatchId, data: bytes) -> None:  # the mapping thread: hand over to the loop
            loop.call_soon_threadsafe(self.sync.add_own, pid, data)

        # The agent never loads a world: it learns the building only from its camera (DESIGN section 11).
        volume = self.config.mission.volume
        if volume is None:
            raise ConfigError(
                f'camera.source = "{camera.source}" needs mission.volume (the agent loads no world to '
                "take it from; `swarm sim` prints its world's)"
            )
        if camera.record is not None and camera.record.exists():
            raise ConfigError(f"camera.record: {camera.record} already exists (a bag is never overwritten)")
        bounds = (np.array(volume.min, dtype=float), np.array(volume.max, dtype=float))
        source: StreamSource
        if camera.source == "replay":
            if camera.replay_bag is None:
                raise ConfigError('camera.source = "replay" needs camera.replay_bag (the bag to play)')
            source = BagReplaySource(camera.replay_bag, camera.stream, camera_mount(camera))
        elif camera.source == "ros2":
            source = Ros2SensorSource(
                camera.stream, camera_mount(camera), camera.record, node_name=f"swarm_agent_{self.id}"
            )
        else:  # zenoh, or sim: the simulator's cameras, each vehicle's topics under /drone<k>
            stream = camera.stream.under_vehicle(self.id) if camera.source == "sim" else camera.stream
            source = ZenohSensorSource(stream, camera_mount(camera), record=camera.record)
        return MappingTask(
            self.config,
            self.epoch,
            source,
            bounds,
            self.log,
            self.config.agent.out_dir,
            on_sealed,
            peers=self._sightings,
            signing=self.signing,
            clock=self.clock,
        )

    def _sightings(self) -> list[PeerSighting]:
        """Every peer's last heartbeat, its receive time on the wall clock of the sensor stamps."""
        wall_minus_monotonic = time.time() - time.monotonic()
        return [
            PeerSighting(p.position, p.velocity, p.last_heard + wall_minus_monotonic) for p in self.peers.peers.values()
        ]

    def _run_mapping(
        self, mapping: MappingTask, autopilot: Autopilot, stop: asyncio.Event, background: list[asyncio.Task[None]]
    ) -> None:
        def home_z() -> float | None:
            return autopilot.home_world[2] if autopilot.home_world is not None else None

        background.append(self._background(mapping.run(autopilot.telemetry, home_z, stop), "mapping"))
        background.append(self._background(mapping.measure_baseline(stop), "baseline"))

    def _background(self, work: Coroutine[Any, Any, None], name: str) -> asyncio.Task[None]:
        """A task that runs beside the flight until the agent exits; logged if it dies of an error."""
        return log_if_failed(asyncio.create_task(work, name=name), self.log)

    async def _validate_only(self, data: bytes, pid: PatchId) -> None:
        """The sync's sink without a map (camera "none"): validate, hold and relay, fuse nothing; the same checks
        as the mapper's (the mission volume when the config has one)."""
        volume = self.config.mission.volume
        await asyncio.to_thread(
            decode_expected,
            data,
            pid,
            self.lattice,
            self.config.mapping.max_patch_bytes,
            patch_block_limit(self.config.mapping, self.config.camera),
            (volume.min, volume.max) if volume is not None else None,
            self.signing.verifier if self.signing is not None else None,
        )

    async def _linger(self) -> None:
        """After landing, stay until every present peer has finished (flight over, last patch sealed) and holds
        what we hold (so the swarm ends with one map), or `sync.linger_max_s` passes, or a signal asks us to go."""
        deadline = time.monotonic() + self.config.sync.linger_max_s
        self.log("linger", peers=sorted(self.peers.peers))
        while time.monotonic() < deadline and not self.stop.is_set():
            if self.sync.heard_from() >= set(self.peers.peers) and self.sync.settled():
                self.log("in_step", patches=len(self.sync.held_ids()))
                return
            await wait_event(self.stop, LINGER_POLL_S)
        self.log("linger_ended", reason="signal" if self.stop.is_set() else "timeout")

    def _obstacles(self) -> list[tuple[float, float, float]]:
        """What the planner must route around that the map does not hold (peers are masked out of it): drones
        whose agents died in the air, and peers parked in the air (no segment to fly: they will not move off)."""
        return [*self.lost_in_air.values(), *(n.position for n in self._neighbours() if not n.silent and parked(n))]

    def _position(self) -> tuple[float, float, float]:
        tel = self.flight.ap.telemetry
        return tel.position if tel.samples > 0 else (0.0, 0.0, 0.0)

    def _neighbours(self) -> list[Neighbour]:
        """Other drones in the air where their last heartbeats put them now (position + velocity x age); one
        whose heartbeats stopped, or whose agent vanished while flying, is where it was last heard, hovering
        (a vehicle whose agent died holds its position, and peers are masked out of the map); so is one whose agent
        lost its telemetry (failsafe): silent, an obstacle that gives way to nobody."""
        now = time.monotonic()
        found = []
        for p in self.peers.peers.values():
            if p.phase not in AIRBORNE_PHASES:
                continue
            age = now - p.last_heard
            if age < NEIGHBOUR_FRESH_S and p.phase != Phase.FAILSAFE:
                position = vec3(x + v * age for x, v in zip(p.position, p.velocity))
                found.append(Neighbour(p.id, position, p.velocity, p.heading_to))
            else:  # no recent heartbeat, or its agent lost its drone (failsafe): it will not give way or move off
                found.append(Neighbour(p.id, p.position, (0.0, 0.0, 0.0), silent=True))
        found.extend(
            Neighbour(k, position, (0.0, 0.0, 0.0), silent=True)
            for k, position in self.lost_in_air.items()
            if k not in self.peers.peers
        )
        return found

    def _is_clear(self, a: tuple[float, float, float], b: tuple[float, float, float]) -> bool:
        grid = self.exploration.grid if self.exploration is not None else None
        return grid is not None and grid.planning_grid.segment_is_free(a, b)

    def _is_roomy(self, a: tuple[float, float, float], b: tuple[float, float, float]) -> bool:
        grid = self.exploration.grid if self.exploration is not None else None
        return grid is not None and grid.roomy_grid.segment_is_free(a, b)

    # -- presence ----------------------------------------------------------------------------------------

    async def _heartbeat(self, bus: AsyncBus) -> None:
        """Every heartbeat period, and soon after the holdings change (at most every MIN_HEARTBEAT_GAP_S)."""
        period = 1.0 / self.config.agent.heartbeat_hz
        while True:
            self.flight.update_distance()
            self._announce.clear()
            self._publish_state(bus)
            await asyncio.sleep(min(MIN_HEARTBEAT_GAP_S, period))
            await wait_event(self._announce, max(0.0, period - MIN_HEARTBEAT_GAP_S))

    def _publish_state(self, bus: AsyncBus) -> None:
        tel = self.flight.ap.telemetry
        known = tel.samples > 0
        self._seq += 1
        state = AgentState(
            id=self.id,
            epoch=self.epoch,
            seq=self._seq,
            t=time.time(),
            position=tel.position if known else (0.0, 0.0, 0.0),
            velocity=tel.velocity,
            heading_to=self.flight.heading_to,
            yaw_deg=tel.yaw_deg,
            flight_mode=tel.flight_mode,
            phase=self.flight.phase,
            role=self.peers.role,
            leader=self.peers.leader,
            finished=self.finished,
            holdings=self.sync.holdings,
        )
        bus.publish(bus.keys.state(self.id), state)

    async def _upkeep(self, bus: AsyncBus) -> None:
        next_sample = 0.0
        refreshed_at = -ROUTE_REFRESH_GAP_S
        while True:
            self.peers.expire()
            deaf = self.peers.deaf(DEAF_AFTER_S)
            if deaf and time.monotonic() - refreshed_at >= ROUTE_REFRESH_GAP_S:
                refreshed_at = time.monotonic()
                self.route_refreshes += 1
                try:
                    declared = bus.refresh_routes()
                except BusError as exc:  # the session is closing, or Zenoh refused: try again after the gap
                    self.log("bus_routes_refresh_failed", deaf_to=deaf, reason=str(exc))
                else:
                    self.log("bus_routes_refreshed", deaf_to=deaf, declarations=declared)
            now = time.time() - self.started
            if now >= next_sample:
                self.timeline.append([round(now, 2), bus.counters.bytes_sent, bus.counters.bytes_received])
                next_sample = now + TIMELINE_PERIOD_S
            await asyncio.sleep(0.2)

    def _on_state(self, key: str, state: AgentState) -> None:
        if self.keys.agent_id_of(key) != state.id:
            self.keys_mismatch += 1  # a heartbeat on another drone's key is not that drone's
            return
        if not self.peers.heard(state.id, state.position, state.phase, state.epoch, state.velocity, state.heading_to):
            return  # stale: the peer's token has gone; its holdings must not be pulled from either
        self._last_seen[state.id] = (state.phase, state.position)
        self.sync.on_state(state)
        self._log_leader_change()  # a leader that landed leaves the cluster with no membership event

    def _on_token_join(self, key: str) -> None:
        peer_id = self.keys.agent_id_of(key)
        if peer_id is not None:
            self.peers.token_appeared(peer_id)

    def _on_token_leave(self, key: str) -> None:
        peer_id = self.keys.agent_id_of(key)
        if peer_id is not None:
            self.peers.token_vanished(peer_id)

    def _on_membership(self, event: str, peer_id: int, cause: str) -> None:
        if event == "left":
            self.sync.peer_left(peer_id)
            phase, position = self._last_seen.get(peer_id, (None, (0.0, 0.0, 0.0)))
            if phase in AIRBORNE_PHASES:  # its vehicle may still hover there, unseen by the camera: avoid it
                self.lost_in_air[peer_id] = position
                self.log("peer_lost_in_air", peer=peer_id, position=[round(c, 2) for c in position])
                if self.exploration is not None:
                    self.exploration.wake.set()  # plan around it now, not at the next loop
        else:
            self.lost_in_air.pop(peer_id, None)
        self.peer_events.append({"t": round(time.time(), 3), "event": event, "peer": peer_id, "cause": cause})
        self.log(f"peer_{event}", peer=peer_id, cause=cause, cluster=self.peers.cluster)
        self._log_leader_change()

    def _log_leader_change(self) -> None:
        if self.peers.leader != self._last_leader:
            self._last_leader = self.peers.leader
            self.log("leader", leader=self.peers.leader, role=self.peers.role, cluster=self.peers.cluster)
            if self.exploration is not None:
                self.exploration.wake.set()  # a new leader (maybe this agent) decides now, not at the next loop

    # -- lifecycle ---------------------------------------------------------------------------------------

    def _install_signal_handlers(self, loop: asyncio.AbstractEventLoop) -> None:
        def on_signal(signum: int) -> None:
            if self.stop.is_set():
                os._exit(128 + signum)  # second signal: the operator wants out now
            self.log("signal", signal=signal.Signals(signum).name)
            self.stop.set()

        for signum in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(signum, on_signal, signum)

    def _write_summary(self, bus: AsyncBus, final: Phase, released: bool, mapping: MappingTask | None) -> None:
        out_dir = self.config.agent.out_dir
        if out_dir is None:
            return
        battery = self.flight.ap.telemetry.battery_min
        summary = AgentSummary.model_validate(
            {
                "id": self.id,
                "epoch": self.epoch,
                "phase": final.value,
                "landed": final == Phase.LANDED,
                "distance_m": round(self.flight.distance_m, 3),
                "duration_s": round(time.time() - self.started, 3),
                "bytes_sent": bus.counters.bytes_sent,
                "bytes_received": bus.counters.bytes_received,
                "traffic": bus.counters.snapshot(),
                "peers_seen": sorted(self.peers.ever_seen),
                "peer_events": self.peer_events,
                "mavsdk_released": released,
                "sync": self.sync.stats(),
                "heartbeats_on_wrong_key": self.keys_mismatch,
                "stale_heartbeats": self.peers.stale_heartbeats,
                "bus_route_refreshes": self.route_refreshes,
                "give_way": self.flight.yields,
                "battery_min_fraction": None if math.isnan(battery) else round(battery, 4),
                "timeline": self.timeline,
                **(self.exploration.summary() if self.exploration is not None else SCRIPTED_EXPLORATION),
                **(mapping.summary() if mapping is not None else NO_MAPPING),
                "stages": self.clock.summary(),
            }
        )
        path = Path(out_dir) / f"agent-{self.id}.json"
        path.parent.mkdir(parents=True, exist_ok=True)
        write_model(path, summary)
