"""The mission observer: a passive member of the bus that records what the swarm says about itself.

It holds no token and publishes nothing, so the agents never count it as a drone. It follows every agent's
heartbeat and liveliness token, keeps a timeline of joins and leaves, and writes a status snapshot (JSON,
atomically) twice a second for `swarm run`'s live view and report.

With a patch directory it also builds the swarm's map: every sealed patch the agents wrote there is decoded
(validated like any received patch) and fused, and `explored_fraction` (see `swarm.sim.coverage`) is measured
against the world mesh every few seconds; at the end the fused mesh is written. Until patches travel over the
bus, the files are how the observer sees them.

It counts leader changes: each heartbeat whose `leader` differs from the same agent's previous one (the first
heartbeat is not a change; clusters forming at take-off are). Each agent's latest holdings digest is kept in its
entry, so `swarm run` can time how fast patch sets converge after a link heals.

For the exploration report it also keeps each drone's trajectory (heartbeat positions, thinned to one sample per
half second) and the leader timeline: the clusters as the heartbeats describe them (who follows whom), recorded
each time they change, so splits and merges of the swarm can be seen after the run.

With a recording (`swarm observe --record`, which `swarm run` passes by default) it also writes all of this to a
Rerun recording as it goes (`swarm.mission.recording`): the world, the map every few seconds, poses, clusters,
explored fraction; and, heard only for the recording, the explorers' frontier reports and the leaders' target
assignments (without a recording it does not subscribe to them).
"""

from __future__ import annotations

import asyncio
import signal
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from swarm.aio import wait_event
from swarm.bus.bridge import AsyncBus
from swarm.bus.messages import AgentState
from swarm.bus.phase import RETIRED_PHASES, Phase
from swarm.config import SwarmConfig
from swarm.files import write_model
from swarm.mission.coverage import SwarmCoverage
from swarm.mission.files import NO_COVERAGE, ObserverStatus
from swarm.roles.messages import FrontierReport, TargetAssignment

if TYPE_CHECKING:
    from swarm.mission.recording import MissionRecording  # imports rerun (0.5 s, 100 MB): only when recording

SNAPSHOT_PERIOD_S = 0.5
COVERAGE_PERIOD_S = 2.0
NO_POSITION_PHASE = Phase.CONNECTING  # before its autopilot's telemetry, an agent's heartbeat says (0, 0, 0)
TRAJECTORY_PERIOD_S = 0.5  # at most one trajectory sample per agent this often: enough for a plot, small JSON
FRESH_S = 2.0  # a heartbeat older than this no longer says which cluster the agent is in

Cluster = tuple[int, tuple[int, ...]]  # (leader, sorted member ids)


def clusters_of(agents: Mapping[int, Mapping[str, Any]], now: float, fresh_s: float = FRESH_S) -> list[Cluster]:
    """The clusters the heartbeats describe: active agents heard within fresh_s, grouped by their `leader`.

    Uses what each agent says about itself rather than re-deriving membership, because the point is to see the
    swarm's own view of who leads whom (a split shows as two leaders). Sorted by leader.
    """
    groups: dict[int, list[int]] = {}
    for agent_id, entry in agents.items():
        if "leader" not in entry or entry.get("phase") in RETIRED_PHASES:
            continue
        if now - float(entry.get("last_heard", -float("inf"))) >= fresh_s:
            continue
        groups.setdefault(int(entry["leader"]), []).append(int(agent_id))
    return [(leader, tuple(sorted(members))) for leader, members in sorted(groups.items())]


class LeaderTimeline:
    """Cluster entries {"t", "leader", "members"}, appended for every cluster whenever the clustering changes."""

    def __init__(self) -> None:
        self.entries: list[dict[str, Any]] = []
        self._last: frozenset[Cluster] = frozenset()

    def update(self, t: float, clusters: Sequence[Cluster]) -> bool:
        """Record the new state if it differs from the last one; True when entries were appended or the swarm
        dissolved (every agent landed or went silent, which has no cluster to write)."""
        state = frozenset(clusters)
        if state == self._last:
            return False
        self._last = state
        for leader, members in sorted(state):
            self.entries.append({"t": round(t, 2), "leader": leader, "members": list(members)})
        return True


class Trajectories:
    """Each agent's positions [t, x, y, z], at most one every `period_s` (heartbeats come at 5 Hz or more)."""

    def __init__(self, period_s: float = TRAJECTORY_PERIOD_S) -> None:
        self.period_s = period_s
        self.samples: dict[int, list[list[float]]] = {}
        self._last_t: dict[int, float] = {}

    def add(self, agent_id: int, t: float, position: Sequence[float]) -> bool:
        """Keep the sample if the agent's previous one is at least period_s older; True when kept."""
        last = self._last_t.get(agent_id)
        if last is not None and t - last < self.period_s:
            return False
        self._last_t[agent_id] = t
        x, y, z = (round(float(c), 3) for c in position)
        self.samples.setdefault(agent_id, []).append([round(t, 2), x, y, z])
        return True

    def snapshot(self) -> dict[str, list[list[float]]]:
        return {str(k): list(v) for k, v in sorted(self.samples.items())}


class Observer:
    def __init__(
        self,
        config: SwarmConfig,
        status_path: Path,
        patches_dir: Path | None = None,
        map_path: Path | None = None,
        since: float | None = None,
        recording: MissionRecording | None = None,
    ) -> None:
        self.config = config
        self.recording = recording
        self.status_path = status_path
        self.coverage = SwarmCoverage(config, patches_dir) if patches_dir is not None else None
        self.map_path = map_path
        self.started = time.time() if since is None else since  # `swarm run` passes its own clock's zero
        self.leader_changes = 0
        self.agents: dict[int, dict[str, Any]] = {}
        self.timeline: list[dict[str, Any]] = []
        self.trajectories = Trajectories()
        self.leaders = LeaderTimeline()
        self.stop = asyncio.Event()

    async def run(self) -> int:
        loop = asyncio.get_running_loop()
        for signum in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(signum, self.stop.set)
        bus = await AsyncBus.open(self.config.bus, self.config.mission.name)
        self.keys = bus.keys
        bus.subscribe(bus.keys.all_states, AgentState, self._on_state)
        bus.watch_liveliness(bus.keys.all_alive, self._on_join, self._on_leave)
        if self.recording is not None:
            bus.subscribe(bus.keys.all_frontiers, FrontierReport, self._on_frontiers)
            bus.subscribe(bus.keys.all_targets, TargetAssignment, self._on_targets)
            if self.coverage is not None:
                self.recording.world(self.coverage.world.vertices, self.coverage.world.triangles)
        coverage_task = asyncio.create_task(self._follow_coverage()) if self.coverage is not None else None
        try:
            while not self.stop.is_set():
                self._follow_leaders()
                self._write(bus, done=False)
                await wait_event(self.stop, SNAPSHOT_PERIOD_S)
        finally:
            if coverage_task is not None:
                coverage_task.cancel()
                await asyncio.gather(coverage_task, return_exceptions=True)
                await asyncio.get_running_loop().run_in_executor(None, self._final_map)
            self._write(bus, done=True)
            await bus.close()
            if self.recording is not None:
                self.recording.close()
        return 0

    async def _follow_coverage(self) -> None:
        assert self.coverage is not None
        loop = asyncio.get_running_loop()
        while True:
            await loop.run_in_executor(None, self._measure, time.time() - self.started, False)
            await asyncio.sleep(COVERAGE_PERIOD_S)

    def _measure(self, t: float, final: bool) -> None:
        """Fuse the new patches and measure (coverage thread); record the fraction, and the map when due."""
        assert self.coverage is not None
        self.coverage.update(t, final=final)
        if self.recording is None:
            return
        try:
            self.recording.explored(t, self.coverage.fraction, self.coverage.by_producer_now())
            version = len(self.coverage.seen)
            if final or self.recording.map_due(t, version):
                started = time.thread_time()
                vertices, triangles = self.coverage.mesh()
                self.recording.map(t, vertices, triangles, version, time.thread_time() - started, exact=final)
        except Exception as exc:  # noqa: BLE001 - the recording must never stop the coverage measurement
            print(f"observer: recording the map failed: {type(exc).__name__}: {exc}", file=sys.stderr, flush=True)

    def _final_map(self) -> None:
        assert self.coverage is not None
        self._measure(time.time() - self.started, True)
        if self.map_path is not None:
            self.coverage.write_mesh(self.map_path)

    def _on_state(self, key: str, state: AgentState) -> None:
        entry = self.agents.setdefault(state.id, {"heartbeats": 0, "alive": True})
        if "leader" in entry and entry["leader"] != state.leader:
            self.leader_changes += 1
        entry.update(
            phase=state.phase,
            role=state.role,
            leader=state.leader,
            flight_mode=state.flight_mode,
            position=list(state.position),
            epoch=state.epoch,
            last_heard=time.time(),
            holdings=state.holdings.model_dump(mode="json"),
        )
        entry["heartbeats"] += 1
        if state.phase != NO_POSITION_PHASE:
            self.trajectories.add(state.id, time.time() - self.started, state.position)
        if self.recording is not None:
            self.recording.state(time.time() - self.started, state, has_position=state.phase != NO_POSITION_PHASE)

    def _on_frontiers(self, key: str, report: FrontierReport) -> None:
        assert self.recording is not None
        self.recording.frontiers(time.time() - self.started, report)

    def _on_targets(self, key: str, assignment: TargetAssignment) -> None:
        assert self.recording is not None
        self.recording.targets(time.time() - self.started, assignment)

    def _follow_leaders(self) -> None:
        now = time.time()
        clusters = clusters_of(self.agents, now)
        if self.leaders.update(now - self.started, clusters) and self.recording is not None:
            self.recording.clusters(now - self.started, clusters)

    def _on_join(self, key: str) -> None:
        self._presence(key, alive=True)

    def _on_leave(self, key: str) -> None:
        self._presence(key, alive=False)

    def _presence(self, key: str, alive: bool) -> None:
        agent_id = self.keys.agent_id_of(key)
        if agent_id is None:
            return
        self.agents.setdefault(agent_id, {"heartbeats": 0})["alive"] = alive
        event = "joined" if alive else "left"
        self.timeline.append({"t": round(time.time() - self.started, 3), "event": event, "agent": agent_id})
        if self.recording is not None:
            self.recording.event(time.time() - self.started, f"agent {agent_id} {event}", "INFO" if alive else "WARN")

    def _write(self, bus: AsyncBus, done: bool) -> None:
        snapshot = ObserverStatus.model_validate(
            {
                "done": done,
                "t": round(time.time() - self.started, 3),
                "agents": {str(k): v for k, v in sorted(self.agents.items())},
                "timeline": self.timeline,
                "traffic": bus.counters.snapshot(),
                "trajectories": self.trajectories.snapshot(),
                "leaders": self.leaders.entries,
                "leader_changes": self.leader_changes,
                **(self.coverage.snapshot() if self.coverage is not None else NO_COVERAGE),
            }
        )
        write_model(self.status_path, snapshot, indent=None)


def observe_command(
    config: SwarmConfig,
    status_path: Path,
    patches_dir: Path | None = None,
    map_path: Path | None = None,
    since: float | None = None,
    record: Path | None = None,
    recording_id: str | None = None,
    stream_to: str | None = None,
) -> int:
    """Observe until SIGINT/SIGTERM; with `record`, write the Rerun recording there (`recording_id`: the run's,
    so other processes' recordings of the same run merge with it; default a fresh one), and with `stream_to`
    stream it to that viewer too."""
    recording = None
    if record is not None:
        from swarm.mission.recording import MissionRecording

        recording_id = recording_id or f"{record.parent.name}-{round(time.time() * 1000)}"
        recording = MissionRecording(record, recording_id, stream_to)
    return asyncio.run(Observer(config, status_path, patches_dir, map_path, since, recording).run())
