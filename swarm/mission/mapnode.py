"""`swarm mapnode`: a map-sharing node without a vehicle, for sync experiments, tests and benchmarks.

It is an agent minus the flight: a real Zenoh session, a liveliness token, heartbeats with its holdings, a
real mapper integrating simulated depth frames (ray-cast in the mission world along a circle around the world's
centre) into patches, and the same `PatchSync` an agent runs. It seals `patches` patches, one every
`seal_period_s` after `start_delay_s`, then keeps syncing until SIGINT/SIGTERM. The position it announces (what
"nearest holder" measures) is `position`, or the camera's when not given.

Its status JSON (rewritten every 0.2 s and at exit) says what it sealed and when, what it holds and since
when, its sync counters, its bus traffic, and the hash of its fused map (`FusedMap.digest`), so a test or a
benchmark can compare nodes.
"""

from __future__ import annotations

import asyncio
import math
import signal
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from swarm.aio import wait_event
from swarm.bus.bridge import AsyncBus
from swarm.bus.messages import AgentState
from swarm.bus.phase import Phase
from swarm.config import SwarmConfig, Vec3
from swarm.files import write_model
from swarm.mission.files import MapNodeStatus
from swarm.patches.mapper import Mapper
from swarm.patches.patch import PatchId
from swarm.patches.sealer import patch_block_limit
from swarm.patches.signing import load_signing
from swarm.roles.membership import PeerTable
from swarm.sim.camera import DepthCamera
from swarm.sim.worlds import load_world, mission_volume
from swarm.sync.service import PatchSync

STATUS_PERIOD_S = 0.2


@dataclass(frozen=True)
class NodePlan:
    patches: int = 3
    seal_period_s: float = 0.5
    start_delay_s: float = 0.0
    position: Vec3 | None = None


class MapNode:
    def __init__(self, config: SwarmConfig, plan: NodePlan, status_path: Path) -> None:
        self.config = config
        self.plan = plan
        self.status_path = status_path
        self.id = config.agent.id
        self.epoch = time.time_ns() // 1_000_000
        self.world = load_world(config.mission.world)
        lo, hi = mission_volume(self.world, config.mission.volume)
        signing_dir = config.signing_dir()
        self.mapper = Mapper(
            config.mapping,
            self.id,
            self.epoch,
            (lo, hi),
            known_weight=config.mapping.known_weight,
            max_blocks=patch_block_limit(config.mapping, config.camera),
            signing=load_signing(signing_dir, self.id) if signing_dir is not None else None,
        )
        self.camera = DepthCamera(self.world, config.camera, seed=self.id)
        self.centre = (lo + hi) / 2
        self.radius = 0.25 * float(min(hi[0] - lo[0], hi[1] - lo[1]))
        self.height = float(lo[2]) + 1.0
        self.frames = 0
        self.sealed: list[dict[str, Any]] = []
        self.peers = PeerTable(self.id, timeout_s=config.agent.peer_timeout_s, on_change=self._on_membership)
        self.stop = asyncio.Event()
        self._worker = ThreadPoolExecutor(1, thread_name_prefix="mapnode")
        self._fused_digest = ""
        self._digest_of = -1
        self._seq = 0
        self.first_peer_t: float | None = None

    def _camera_pose(self, frame: int) -> tuple[Vec3, float]:
        angle = 2 * math.pi * frame / max(1, self.plan.patches * self.config.mapping.patch_frames) + self.id
        x = float(self.centre[0]) + self.radius * math.cos(angle)
        y = float(self.centre[1]) + self.radius * math.sin(angle)
        return (x, y, self.height), math.degrees(angle) + 90.0

    def position(self) -> Vec3:
        return self.plan.position if self.plan.position is not None else self._camera_pose(self.frames)[0]

    async def run(self) -> int:
        loop = asyncio.get_running_loop()
        for signum in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(signum, self.stop.set)
        bus = await AsyncBus.open(self.config.agent_bus(), self.config.mission.name)
        self.bus = bus
        self.sync = PatchSync(
            bus,
            self.config.sync,
            self.id,
            self._receive,
            self.position,
            self.config.mapping.max_patch_bytes,
            on_holdings_changed=lambda: self._publish_state(),
            own_epoch=self.epoch,
        )
        bus.declare_token(bus.keys.alive(self.id))
        bus.subscribe(bus.keys.all_states, AgentState, self._on_state)
        bus.watch_liveliness(bus.keys.all_alive, self._on_join, self._on_leave)
        self.sync.start()
        tasks = [asyncio.create_task(self._heartbeat()), asyncio.create_task(self._produce())]
        try:
            while not self.stop.is_set():
                for task in tasks:
                    if task.done() and task.exception() is not None:
                        raise task.exception()  # type: ignore[misc]
                await self._write_status(done=False)
                await wait_event(self.stop, STATUS_PERIOD_S)
        finally:
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
            await self.sync.stop()
            await self._write_status(done=True)
            await bus.close()
            self._worker.shutdown(wait=True)
        return 0

    # --- producing --------------------------------------------------------------------------------------

    async def _produce(self) -> None:
        loop = asyncio.get_running_loop()
        start = time.monotonic() + self.plan.start_delay_s
        for i in range(self.plan.patches):
            await asyncio.sleep(max(0.0, start + i * self.plan.seal_period_s - time.monotonic()))
            sealed = await loop.run_in_executor(self._worker, self._map_one_patch)
            if sealed is not None:
                pid, data = sealed
                self.sealed.append({"id": str(pid), "t": time.time(), "bytes": len(data)})
                self.sync.add_own(pid, data)

    def _map_one_patch(self) -> tuple[PatchId, bytes] | None:
        """Integrate frames until the sealer seals a patch (patch_frames of them, or fewer if it moved far)."""
        patch = None
        while patch is None and self.mapper.sealer.open_frames < self.config.mapping.patch_frames:
            position, yaw = self._camera_pose(self.frames)
            frame = self.camera.frame(self.frames, time.time(), position, yaw)
            self.frames += 1
            patch = self.mapper.integrate(
                frame.depth, frame.K, frame.T_world_cam, frame.t, self.config.camera.max_range_m
            )
        patch = patch or self.mapper.seal()
        if patch is None:
            return None
        data = self.mapper.data(patch.id)
        assert data is not None
        return patch.id, data

    async def _receive(self, data: bytes, pid: PatchId) -> None:
        await asyncio.get_running_loop().run_in_executor(
            self._worker, self.mapper.receive_wire, data, pid, self.config.mapping.max_patch_bytes
        )

    # --- presence ---------------------------------------------------------------------------------------

    async def _heartbeat(self) -> None:
        period = 1.0 / self.config.agent.heartbeat_hz
        while True:
            self.peers.expire()
            self._publish_state()
            await asyncio.sleep(period)

    def _publish_state(self) -> None:
        self._seq += 1
        done = len(self.sealed) >= self.plan.patches
        self.bus.publish(
            self.bus.keys.state(self.id),
            AgentState(
                id=self.id,
                epoch=self.epoch,
                seq=self._seq,
                t=time.time(),
                position=self.position(),
                velocity=(0.0, 0.0, 0.0),
                yaw_deg=0.0,
                flight_mode="NONE",
                phase=Phase.MAPPING,  # never landed: a map node stays a cluster member; `finished` says it is done
                role=self.peers.role,
                leader=self.peers.leader,
                finished=done,
                holdings=self.sync.holdings,
            ),
        )

    def _on_state(self, key: str, state: AgentState) -> None:
        if self.bus.keys.agent_id_of(key) != state.id:
            return
        if self.peers.heard(state.id, state.position, state.phase, state.epoch):
            self.sync.on_state(state)

    def _on_join(self, key: str) -> None:
        peer = self.bus.keys.agent_id_of(key)
        if peer is not None:
            self.peers.token_appeared(peer)

    def _on_leave(self, key: str) -> None:
        peer = self.bus.keys.agent_id_of(key)
        if peer is not None:
            self.peers.token_vanished(peer)

    def _on_membership(self, event: str, peer_id: int, cause: str) -> None:
        if event == "joined" and self.first_peer_t is None:
            self.first_peer_t = time.time()
        if event == "left":
            self.sync.peer_left(peer_id)

    # --- status -----------------------------------------------------------------------------------------

    async def _write_status(self, done: bool) -> None:
        held = len(self.sync.held_ids())
        if held != self._digest_of:
            self._fused_digest = await asyncio.get_running_loop().run_in_executor(
                self._worker, self.mapper.fused.digest
            )
            self._digest_of = held
        status = MapNodeStatus.model_validate(
            {
                "id": self.id,
                "epoch": self.epoch,
                "done": done,
                "t": time.time(),
                "sealed": self.sealed,
                "held": [str(pid) for pid in self.sync.held_ids()],
                "held_at": {str(pid): t for pid, t in self.sync.held_at.items()},
                "fused_digest": self._fused_digest,
                "fused_patches": held,
                "peers": sorted(self.peers.peers),
                "leader": self.peers.leader,
                "role": self.peers.role,
                "cluster": self.peers.cluster,
                "first_peer_t": self.first_peer_t,
                "sync": self.sync.stats(),
                "traffic": self.bus.counters.snapshot(),
            }
        )
        write_model(self.status_path, status, indent=None)


def mapnode_command(config: SwarmConfig, plan: NodePlan, status_path: Path) -> int:
    return asyncio.run(MapNode(config, plan, status_path).run())
