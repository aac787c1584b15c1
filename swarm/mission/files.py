"""The harness's files: the observer's status (`observer.json`) and the mission report (`report.json`).

`report.json` is the one file meant for programs outside Swarm, so it carries `schema_version` and its JSON
Schema is committed as docs/report.schema.json. `python -m swarm.mission.files` regenerates that file;
`--check` exits 1 when the committed one is stale (a unit test does the same). A change that renames or
removes a key, or changes its type, raises `REPORT_SCHEMA_VERSION`; adding a key does not.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any, Literal

from pydantic import Field

from swarm.agent.summary import GivenUpFrontier, KindTraffic, SyncStats
from swarm.bus.holdings import DigestWire
from swarm.bus.phase import Phase
from swarm.files import FileModel
from swarm.sim.status import CollisionRecord, Stall

REPORT_SCHEMA_VERSION: Literal[1] = 1
SCHEMA_PATH = Path(__file__).resolve().parents[2] / "docs" / "report.schema.json"


# --- observer.json ---------------------------------------------------------------------------------------------


class ObservedAgent(FileModel):
    """What the observer knows of one agent: presence always, the rest from its last heartbeat (None until the
    first one arrives)."""

    heartbeats: int
    alive: bool
    phase: Phase | None = None
    role: str | None = None
    leader: int | None = None
    flight_mode: str | None = None
    position: list[float] | None = None
    epoch: int | None = None
    last_heard: float | None = None  # unix time
    holdings: DigestWire | None = None


class PresenceEvent(FileModel):
    t: float  # seconds on the mission clock
    event: Literal["joined", "left"]
    agent: int


class LeaderEntry(FileModel):
    t: float
    leader: int
    members: list[int]


class UnexploredRegion(FileModel):
    """A connected piece of the reachable space that no map knows (`swarm.mission.coverage`)."""

    volume_m3: float
    lo: tuple[float, float, float]  # the corners of its bounding box, world metres
    hi: tuple[float, float, float]


class ObserverStatus(FileModel):
    done: bool
    t: float
    agents: dict[str, ObservedAgent]  # agent id (as a JSON key) -> what is known of it
    timeline: list[PresenceEvent]
    traffic: dict[str, KindTraffic]
    trajectories: dict[str, list[list[float]]]  # agent id -> [t, x, y, z] samples
    leaders: list[LeaderEntry]
    leader_changes: int
    # coverage (`SwarmCoverage.snapshot`); an observer given no patch directory measures none: zeros
    explored_fraction: float
    explored_timeline: list[tuple[float, float]]
    patches_fused: int
    patches_rejected: dict[str, int]
    reachable_cells: int
    explored_by_agent: dict[str, list[tuple[float, float]]]
    overlap_fraction: float
    unexplored: list[UnexploredRegion]  # the largest first, at most UNEXPLORED_REGIONS_KEPT
    patch_bytes: int = 0  # the wire bytes of every patch fused (each sealed patch once)
    map_bytes: int = 0  # the final fused map's wire size (`FusedMap.wire_size`); 0 until the observer's last look


NO_COVERAGE: dict[str, Any] = {
    "explored_fraction": 0.0,
    "explored_timeline": [],
    "patches_fused": 0,
    "patches_rejected": {},
    "reachable_cells": 0,
    "explored_by_agent": {},
    "overlap_fraction": 0.0,
    "unexplored": [],
    "patch_bytes": 0,
    "map_bytes": 0,
}


# --- map node status (`swarm mapnode --status`) ------------------------------------------------------------------


class SealedPatch(FileModel):
    id: str  # "producer.epoch.seq"
    t: float  # unix time it was sealed
    bytes: int


class MapNodeStatus(FileModel):
    """A map-sharing node's status, rewritten every period while it runs (`swarm.mission.mapnode`)."""

    id: int
    epoch: int
    done: bool
    t: float  # unix time
    sealed: list[SealedPatch]
    held: list[str]
    held_at: dict[str, float]  # patch id -> unix time it was first held
    fused_digest: str  # "" until the node fused a patch
    fused_patches: int
    peers: list[int]
    leader: int
    role: str
    cluster: list[int]
    first_peer_t: float | None
    sync: SyncStats
    traffic: dict[str, KindTraffic]


# --- report.json -----------------------------------------------------------------------------------------------


class ReceivedPatches(FileModel):
    push: int
    pull: int


class Defences(FileModel):
    """What one agent left out or could not do, by reason (issue 25): empty in a healthy mission (and in reports
    written before these counts were). Each is a reason -> count map.

    exploration_rejected: other members' frontier reports and heartbeats not believed; patches_not_sealed: its
    own open patches dropped that receivers would refuse; patch_store_failures: errno name -> sealed patches not
    stored on disk (pushed all the same); assembly_dropped: patch chunks dropped by the reassembler's bounds;
    sync_limits: pull claims over a holder's quota, holdings left unannounced; bus_dropped: received messages
    dropped undecoded or invalid, over every kind."""

    exploration_rejected: dict[str, int] = Field(default_factory=dict)
    patches_not_sealed: dict[str, int] = Field(default_factory=dict)
    patch_store_failures: dict[str, int] = Field(default_factory=dict)
    assembly_dropped: dict[str, int] = Field(default_factory=dict)
    sync_limits: dict[str, int] = Field(default_factory=dict)
    bus_dropped: dict[str, int] = Field(default_factory=dict)


class AgentRow(FileModel):
    """One drone in the report: truth from the simulator, the rest from the agent's own summary."""

    id: int
    distance_m: float
    closest_world_m: float | None
    closest_world_at: list[float] | None
    closest_drone_m: float | None
    bytes_sent: int
    bytes_received: int
    landed: bool
    phase: Phase | Literal["unknown"]  # "unknown" when the agent wrote no summary
    exit_code: int | None
    route_length_m: float | None
    peers_seen: list[int]
    patches_sealed: int
    frames: int
    mapping_ms_per_frame: float | None
    frame_rate_hz: float | None
    sensor_stream: dict[str, int] | None
    patches_held: int
    patches_requested: int
    patches_served: int
    patches_received: ReceivedPatches
    patches_rejected: dict[str, int]
    duration_s: float
    traffic: dict[str, KindTraffic]
    targets_assigned: int
    targets_self_selected: int
    exploration_done_reason: str | None
    frontiers_given_up: list[GivenUpFrontier]
    defences: Defences = Field(default_factory=Defences)


class Bandwidth(FileModel):
    bytes_per_agent_s: float
    whole_map_baseline_bytes_per_agent_s: float
    baseline_ratio: float | None
    baseline_loop_s: float | None
    agent_seconds: float
    # every sealed patch's bytes once, against the final map's (observer): how much the patches repeat the map
    patch_bytes: int = 0
    map_bytes: int = 0
    patch_to_map_ratio: float | None = None


class PhantomCheck(FileModel):
    vertices: int
    near_paths: int
    phantoms: int
    examples: list[list[float]]


class NicenessAsked(FileModel):
    sim: int
    agents: int


class NicenessGot(FileModel):
    sim: int | None  # None: the process was not started
    agents: dict[str, int | None]  # agent id -> niceness


class Priority(FileModel):
    """The niceness asked for the simulator and the agents, what each got, and whether every one got it."""

    asked: NicenessAsked
    got: NicenessGot
    granted: bool


class Volume(FileModel):
    min: list[float]
    max: list[float]


class MissionInfo(FileModel):
    name: str
    seed: int
    max_time_s: float
    volume: Volume
    spawns: list[list[float]]
    world: str
    strategy: str | None


class MissionReport(FileModel):
    """`report.json`. Nested entries the harness records as it goes (faults, link impairments, partitions,
    heals, the scenario) are kept as JSON objects: their keys are documented where they are written
    (`swarm.mission.faults`, `swarm.mission.links`)."""

    schema_version: Literal[1] = REPORT_SCHEMA_VERSION
    status: str  # "complete", "incomplete", "failed", "timeout", "interrupted"...
    reason: str
    world: str
    run_dir: str
    drones: int
    duration_s: float
    started_at: float  # unix time of the mission clock's zero
    collisions: int
    explored_fraction: float
    explored_timeline: list[tuple[float, float]]
    time_to: dict[str, float | None]  # threshold ("0.95") -> first mission time it was reached
    explored_by_agent: dict[str, list[tuple[float, float]]]
    overlap_fraction: float
    leaders: list[LeaderEntry]
    faults: list[dict[str, Any]]
    leader_changes: int
    network: str
    scenario: dict[str, Any] | None
    impairments: list[dict[str, Any]]
    partitions: list[dict[str, Any]]
    convergence_after_heal_s: list[dict[str, Any]]
    map: str | None
    phantoms: PhantomCheck | None
    converged: bool
    bandwidth: Bandwidth
    collision_events: list[CollisionRecord]
    sim_stalls: list[Stall]
    priority: Priority
    agents: list[AgentRow]
    presence_timeline: list[PresenceEvent]
    mission: MissionInfo
    plots: list[str]
    report_page: str | None
    plots_error: str | None = None  # written only when a figure failed
    swarm_version: str

    def to_json(self) -> str:
        """The file's text: `plots_error` only when there is one."""
        return self.model_dump_json(indent=2, exclude={"plots_error"} if self.plots_error is None else None)


def report_schema() -> dict[str, Any]:
    return MissionReport.model_json_schema(mode="serialization")


def schema_text() -> str:
    return json.dumps(report_schema(), indent=2) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=f"write {SCHEMA_PATH.name}, the JSON Schema of report.json")
    parser.add_argument("--check", action="store_true", help="exit 1 if the committed file is not current")
    args = parser.parse_args(argv)
    if args.check:
        current = SCHEMA_PATH.exists() and SCHEMA_PATH.read_text() == schema_text()
        if not current:
            print(f"{SCHEMA_PATH} is stale: run python -m swarm.mission.files", file=sys.stderr)
        return 0 if current else 1
    SCHEMA_PATH.write_text(schema_text())
    print(f"wrote {SCHEMA_PATH}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
