"""The agent's summary file (`agents/agent-K.json`): what one agent says about its run when it exits.

Written by the agent (`swarm.agent.main`), read by the mission harness for `report.json`. Every key is always
written: an agent that flew a scripted route or mapped nothing writes zero counts and `None` for figures it has
no data for, so a missing key is always an error, never a zero.
"""

from __future__ import annotations

from swarm.bus.holdings import DigestWire
from swarm.bus.phase import Phase
from swarm.files import FileModel


class KindTraffic(FileModel):
    """Bus traffic of one message kind (`swarm.bus.counters.TrafficCounters.snapshot`)."""

    sent_msgs: int
    sent_bytes: int
    recv_msgs: int
    recv_bytes: int
    dropped: dict[str, int]


class PeerEvent(FileModel):
    t: float  # unix time
    event: str  # "joined" or "left"
    peer: int
    cause: str


class SyncStats(FileModel):
    """The patch-sharing counters (`swarm.sync.service.SyncService.stats`)."""

    patches_held: int
    patches_requested: int
    patches_served: int
    patches_pushed: int
    received_by_push: int
    received_by_pull: int
    duplicate_chunks: int
    requests_served: int
    requests_refused: int
    request_timeouts: int
    push_chunks_dropped_on_purpose: int
    rejected: dict[str, int]
    assembly_dropped: dict[str, int]
    received_from: dict[str, int]  # peer id (as a JSON key) -> patches
    served_to: dict[str, int]
    holdings: DigestWire  # what it announced (`PatchDigest.announced`: all it held unless beyond the wire bounds)
    limits: dict[str, int]  # bounds that cut hostile or excessive input: pull claims, unannounced holdings
    content: dict[str, str] = {}  # patch id -> SHA-256 of the bytes held (PatchSync.content_hashes)
    held_at: dict[str, float] = {}  # patch id -> unix time it was first held (sealed, or received and fused)


class GivenUpFrontier(FileModel):
    viewpoint: list[float]
    point: list[float]
    reason: str
    at_s: float


class WholeMapBaseline(FileModel):
    """What sending the whole fused map every exploration loop would have cost (the bandwidth comparison)."""

    loop_s: float
    loops: int
    bytes: int


class StageCost(FileModel):
    """One stage's cost over the run (`swarm.stages.StageClock.summary`)."""

    calls: int
    total_ms: float
    p50_ms: float
    max_ms: float


class AgentSummary(FileModel):
    id: int
    epoch: int
    phase: Phase  # the final flight phase
    landed: bool
    distance_m: float
    duration_s: float
    bytes_sent: int
    bytes_received: int
    traffic: dict[str, KindTraffic]
    peers_seen: list[int]
    peer_events: list[PeerEvent]
    mavsdk_released: bool
    sync: SyncStats
    heartbeats_on_wrong_key: int
    stale_heartbeats: int  # from a peer whose token had gone, left out (swarm.roles.membership)
    bus_route_refreshes: int  # subscriptions declared again for a peer heard by token only (swarm.roles)
    give_way: int
    battery_min_fraction: float | None  # the lowest remaining battery the autopilot reported; None: it reported none
    timeline: list[tuple[float, int, int]]  # (t since start, bytes sent, bytes received), once a second
    # exploration (`ExplorationTask.summary`; a scripted agent: zeros and None)
    strategy: str
    targets_assigned: int
    targets_self_selected: int
    exploration_loops: int
    exploration_done: bool
    exploration_done_reason: str
    targets_visited: int
    frontiers_given_up: list[GivenUpFrontier]
    # other members' input left out, by kind (swarm.roles.protocol.REJECTED_KINDS, and heartbeat_jump)
    exploration_rejected: dict[str, int]
    decision_ms_p50: float | None  # decisions on a new map view
    decision_ms_max: float | None
    decisions_on_last_view: int  # decisions within explore.view_reuse_s of the last view, made on it
    # mapping (`MappingTask.summary`; an agent without a camera: zeros and None)
    patches_sealed: int
    frames: int
    frames_skipped: int
    mapping_ms_per_frame: float
    frame_rate_hz: float
    sensor_stream: dict[str, int] | None  # a streamed camera's frames, drops by reason, masked pixels, silences
    patch_store_failures: dict[str, int]  # errno name -> sealed patch files not stored (pushed and fused all the same)
    patches_not_sealed: dict[
        str, int
    ]  # reason -> open patches dropped that receivers would refuse (too many blocks, ...)
    voxels_held_back: int  # observed voxels of own patches not shared at their seal (swarm.patches.unshared)
    patches_held_back: int  # open patches not sealed: none of their voxels changed the map
    known_voxels: int
    # MB before the final mesh (`MappingTask._measure_memory`): rss_at_start, rss_peak_in_flight, fused_map,
    # held_back, patch_bytes, open_patch; empty for an agent without a camera
    memory_mb: dict[str, float]
    patches_received: int
    fused_digest: str | None
    whole_map_baseline: WholeMapBaseline | None
    # stage -> {calls, total_ms, p50_ms, max_ms} (swarm.stages): integrate, fuse_patch, occupancy, frontiers, ...
    stages: dict[str, StageCost]


SCRIPTED_EXPLORATION = {
    "strategy": "scripted",
    "targets_assigned": 0,
    "targets_self_selected": 0,
    "exploration_loops": 0,
    "exploration_done": False,
    "exploration_done_reason": "",
    "targets_visited": 0,
    "frontiers_given_up": [],
    "exploration_rejected": {},
    "decision_ms_p50": None,
    "decision_ms_max": None,
    "decisions_on_last_view": 0,
}

NO_MAPPING: dict[str, object] = {
    "patches_sealed": 0,
    "frames": 0,
    "frames_skipped": 0,
    "mapping_ms_per_frame": 0.0,
    "frame_rate_hz": 0.0,
    "sensor_stream": None,
    "patch_store_failures": {},
    "patches_not_sealed": {},
    "voxels_held_back": 0,
    "patches_held_back": 0,
    "known_voxels": 0,
    "memory_mb": {},
    "patches_received": 0,
    "fused_digest": None,
    "whole_map_baseline": None,
}
