"""The agent process: one drone's flight, map, presence and peer table, supervised under one asyncio loop.

Tasks: the flight (MAVSDK), the mapping task (depth frames into patches while airborne, in a worker thread),
the heartbeat publisher (AgentState at `heartbeat_hz` on the drone's state key, best effort), and the
membership upkeep (expire silent peers, re-elect). A liveliness token announces the agent. SIGINT/SIGTERM ask
the flight to land and the process to exit; a second signal exits at once. After the flight the open patch is
sealed, the agent's mesh and summary are written, and the bus is closed.
"""

from __future__ import annotations

import asyncio
import os
import signal
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from swarm.agent.autopilot import Autopilot
from swarm.agent.events import EventLog
from swarm.agent.flight import Flight, Phase
from swarm.agent.mapping import MappingTask
from swarm.agent.sensing import make_depth_source
from swarm.bus.bridge import AsyncBus
from swarm.bus.messages import AgentState
from swarm.config import SwarmConfig
from swarm.files import write_json_atomic
from swarm.roles.membership import PeerTable
from swarm.sim.worlds import load_world, mission_volume

EXIT_OK, EXIT_FLIGHT_FAILED, EXIT_FAILSAFE = 0, 1, 3


def agent_command(config: SwarmConfig) -> int:
    return asyncio.run(Agent(config).run())


class Agent:
    def __init__(self, config: SwarmConfig) -> None:
        self.config = config
        self.id = config.agent.id
        self.epoch = time.time_ns() // 1_000_000  # changes every time the process starts
        self.log = EventLog(self.id)
        self.peers = PeerTable(self.id, timeout_s=config.agent.peer_timeout_s, on_change=self._on_membership)
        self.peer_events: list[dict[str, Any]] = []
        self.stop = asyncio.Event()
        self.started = time.time()
        self._seq = 0
        self._last_leader = self.id

    async def run(self) -> int:
        loop = asyncio.get_running_loop()
        # MAVSDK runs every plugin call in the default executor: size it so telemetry never starves.
        loop.set_default_executor(ThreadPoolExecutor(self.config.agent.mavsdk_threads, thread_name_prefix="mavsdk"))
        self._install_signal_handlers(loop)
        self.log("starting", epoch=self.epoch, autopilot=self.config.agent.autopilot, pid=os.getpid())
        bus = await AsyncBus.open(self.config.bus, self.config.mission.name)
        autopilot = Autopilot(self.config.agent.autopilot, self.config.mission.origin, self.config.agent.command_timeout_s)
        self.flight = Flight(autopilot, self.config.agent, self.log)
        keys = self.keys = bus.keys
        bus.declare_token(keys.alive(self.id))
        bus.subscribe(keys.all_states, AgentState, self._on_state)
        bus.watch_liveliness(keys.all_alive, self._on_token_join, self._on_token_leave)
        background = [asyncio.create_task(self._heartbeat(bus)), asyncio.create_task(self._upkeep())]
        mapping, mapping_stop = self._start_mapping(autopilot, background)
        final = Phase.FAILED
        try:
            final = await self.flight.run(list(self.config.agent.waypoints), self.stop)
        finally:
            self._publish_state(bus)  # the last phase goes out before we leave
            mapping_stop.set()
            for task in background:
                task.cancel()
            await asyncio.gather(*background, return_exceptions=True)
            if mapping is not None:
                await mapping.finish()
            released = await autopilot.close()
            self._write_summary(bus, final, released, mapping)
            await bus.close()
        self.log("exit", phase=final.value)
        return {Phase.LANDED: EXIT_OK, Phase.FAILSAFE: EXIT_FAILSAFE}.get(final, EXIT_FLIGHT_FAILED)

    def _start_mapping(
        self, autopilot: Autopilot, background: list[asyncio.Task[None]]
    ) -> tuple[MappingTask | None, asyncio.Event]:
        stop = asyncio.Event()
        if self.config.camera.source == "none":
            return None, stop
        world = load_world(self.config.mission.world)  # once: the camera ray-casts it, the map spans its volume
        mapping = MappingTask(
            self.config, self.epoch, make_depth_source(self.config, world),
            mission_volume(world, self.config.mission.volume), self.log, self.config.agent.out_dir,
        )

        def home_z() -> float | None:
            return autopilot.home_world[2] if autopilot.home_world is not None else None

        background.append(asyncio.create_task(mapping.run(autopilot.telemetry, home_z, stop)))
        return mapping, stop

    # -- presence ----------------------------------------------------------------------------------------

    async def _heartbeat(self, bus: AsyncBus) -> None:
        period = 1.0 / self.config.agent.heartbeat_hz
        while True:
            self.flight.update_distance()
            self._publish_state(bus)
            await asyncio.sleep(period)

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
            yaw_deg=tel.yaw_deg,
            flight_mode=tel.flight_mode,
            phase=self.flight.phase.value,
            role=self.peers.role,
            leader=self.peers.leader,
        )
        bus.publish(bus.keys.state(self.id), state)

    async def _upkeep(self) -> None:
        while True:
            self.peers.expire()
            await asyncio.sleep(0.2)

    def _on_state(self, key: str, state: AgentState) -> None:
        self.peers.heard(state.id, state.position, state.phase, state.epoch)

    def _on_token_join(self, key: str) -> None:
        peer_id = self.keys.agent_id_of(key)
        if peer_id is not None:
            self.peers.token_appeared(peer_id)

    def _on_token_leave(self, key: str) -> None:
        peer_id = self.keys.agent_id_of(key)
        if peer_id is not None:
            self.peers.token_vanished(peer_id)

    def _on_membership(self, event: str, peer_id: int, cause: str) -> None:
        self.peer_events.append({"t": round(time.time(), 3), "event": event, "peer": peer_id, "cause": cause})
        self.log(f"peer_{event}", peer=peer_id, cause=cause, cluster=self.peers.cluster)
        if self.peers.leader != self._last_leader:
            self._last_leader = self.peers.leader
            self.log("leader", leader=self.peers.leader, role=self.peers.role, cluster=self.peers.cluster)

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
        summary = {
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
            **(mapping.summary() if mapping is not None else {"patches_sealed": 0}),
        }
        path = Path(out_dir) / f"agent-{self.id}.json"
        path.parent.mkdir(parents=True, exist_ok=True)
        write_json_atomic(path, summary, indent=2)

