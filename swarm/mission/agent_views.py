"""Each drone's own view of the mission, as a Rerun recording per agent (`OUT/agents/agent-K.rrd`).

`run.rrd` shows what the swarm did as the observer saw it (the map of every patch sealed). A drone flies on what
*it* held: the patches that had reached it, the targets it was given or chose, the paths it planned, the
leader it followed. Agents never import Rerun (it costs 100 MB and an import second, and an agent must run on a
companion computer without it), so this view is written by the harness after the mission, from what each
agent wrote itself: its summary (`sync.held_at`: when each patch was first held, own or received), the sealed
patches in `OUT/agents/patches/` and its event log (`logs/agent-K*.log`: one JSON object per line). The files
share the run's recording id, so the viewer shows them beside `run.rrd`; every entity lives under `agents/K/`.

=================================  ==========================================================================
agents/K/map/tI_J_K                the map drone K held (every patch it held by then, fused), refreshed
                                   every `BELIEF_PERIOD_S` of mission time, the tiles its new patches reach
agents/K/path                      the last path it planned (its "path" events)
agents/K/target                    its current target: the viewpoint and the line to the point it looks at
agents/K/log                       every event of its log (phase, leader, target, give way, done, ...)
series/belief_patches/K            how many patches it held
=================================  ==========================================================================
"""

from __future__ import annotations

import json
import multiprocessing
import os
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr

from swarm.agent.summary import AgentSummary
from swarm.config import SwarmConfig
from swarm.mission.recording import TIMELINE, MapTiles, blocks_in_tiles, drone_color, open_stream, tiles_near_blocks
from swarm.patches import Lattice
from swarm.patches.fused import FusedMap
from swarm.patches.wire import PatchDecodeError, decode_patch

BELIEF_PERIOD_S = 15.0  # a drone's map every 15 s of the mission: enough to see who knew what (office: 4 s an agent)
WARN_EVENTS = frozenset({"give_way", "blocked_by", "no_path", "in_pocket", "path_blocked", "unreachable_given_up"})
ERROR_EVENTS = frozenset(
    {"failsafe", "flight_error", "taken_over", "illegal_transition", "patch_store_failed", "task_failed"}
)
TARGET_ENDS = frozenset({"exploration_done", "target_explored"})  # the drone has no target after these
FLIGHT_ENDS = frozenset({"landing", "landed", "failsafe"})


@dataclass(frozen=True)
class LogEvent:
    t: float  # mission seconds
    event: str
    fields: dict[str, Any]


def agent_events(logs_dir: Path, agent_id: int, started_at: float) -> list[LogEvent]:
    """The agent's JSON events from its log and its restarts' logs, on the mission clock, in time order; lines
    that are not its events (stderr, a torn last line) are skipped."""
    events = []
    for path in sorted(logs_dir.glob(f"agent-{agent_id}.*log")):
        for line in path.read_text(errors="replace").splitlines():
            if not line.startswith("{"):
                continue
            try:
                record = json.loads(line)
            except json.JSONDecodeError:
                continue
            if not isinstance(record, dict) or record.get("agent") != agent_id or "event" not in record:
                continue
            t = record.pop("t", None)
            if not isinstance(t, int | float):
                continue
            record.pop("agent")
            events.append(LogEvent(float(t) - started_at, str(record.pop("event")), record))
    return sorted(events, key=lambda e: e.t)


def _text(event: LogEvent) -> str:
    return f"{event.event} " + " ".join(f"{k}={v}" for k, v in event.fields.items())


def _level(event: str) -> str:
    return "ERROR" if event in ERROR_EVENTS else "WARN" if event in WARN_EVENTS else "INFO"


def _points(value: Any) -> np.ndarray | None:
    try:
        points = np.asarray(value, dtype=np.float32).reshape(-1, 3)
    except (TypeError, ValueError):
        return None
    return points if len(points) and np.all(np.isfinite(points)) else None


def log_events(stream: rr.RecordingStream, k: int, events: list[LogEvent]) -> None:
    """Paths, targets and the text log of one agent's events."""
    color = drone_color(k)
    for e in events:
        stream.set_time(TIMELINE, duration=max(0.0, e.t))
        stream.log(f"agents/{k}/log", rr.TextLog(_text(e), level=_level(e.event)))
        if e.event == "path" and (path := _points(e.fields.get("waypoints"))) is not None and len(path) >= 2:
            stream.log(f"agents/{k}/path", rr.LineStrips3D([path], colors=[color]))
        elif e.event == "target":
            viewpoint, point = _points(e.fields.get("viewpoint")), _points(e.fields.get("point"))
            if viewpoint is not None and point is not None:
                stream.log(
                    f"agents/{k}/target",
                    rr.Points3D(viewpoint, colors=[color], radii=0.12, labels=[f"{e.fields.get('source')}"]),
                    rr.LineStrips3D([np.vstack([viewpoint, point])], colors=[color]),
                )
        elif e.event in TARGET_ENDS or (e.event == "phase" and e.fields.get("phase") in FLIGHT_ENDS):
            stream.log(f"agents/{k}/target", rr.Clear(recursive=False))


def belief_snapshots(
    held_at: dict[str, float], started_at: float, period_s: float
) -> Iterator[tuple[float, list[str]]]:
    """(mission time, the patch ids first held in the period ending then), every `period_s`, up to the last."""
    order = sorted(((t - started_at, pid) for pid, t in held_at.items()), key=lambda item: item[0])
    i, t = 0, period_s
    while i < len(order):
        batch = []
        while i < len(order) and order[i][0] <= t:
            batch.append(order[i][1])
            i += 1
        if batch:
            yield t, batch
        t += period_s


def log_belief(
    stream: rr.RecordingStream,
    k: int,
    summary: AgentSummary,
    patches_dir: Path,
    fused: FusedMap,
    started_at: float,
    max_patch_bytes: int,
    period_s: float = BELIEF_PERIOD_S,
) -> int:
    """The map drone k held over the mission, from the sealed patch files and the times it first held each;
    returns the patches fused (a patch file missing or not decoding is left out, as its agent would have)."""
    tiles = MapTiles(stream, f"agents/{k}/map")
    lattice = fused.lattice
    fused_count = 0
    for t, ids in belief_snapshots(summary.sync.held_at, started_at, period_s):
        changed = []
        for pid in ids:
            path = patches_dir / f"{pid}.patch"
            try:
                patch = decode_patch(path.read_bytes(), lattice, max_patch_bytes)
            except (OSError, PatchDecodeError):
                continue
            fused.add(patch)
            changed.append(patch.blocks.keys)
            fused_count += 1
        stream.set_time(TIMELINE, duration=t)
        stream.log(f"series/belief_patches/{k}", rr.Scalars(float(fused_count)))
        if changed:  # only the tiles the new patches reach are meshed again
            near = tiles_near_blocks(np.vstack(changed), lattice)
            blocks = blocks_in_tiles(fused.block_keys(), near, lattice)
            vertices, triangles = fused.mesh(within=blocks)
            tiles.log(vertices, triangles, only=near)
    return fused_count


def record_agent_view(
    out: Path,
    k: int,
    recording_id: str,
    started_at: float,
    config: SwarmConfig,
    bounds: tuple[np.ndarray, np.ndarray],
    summary: AgentSummary,
    stream_to: str | None = None,
) -> Path:
    """Write OUT/agents/agent-K.rrd (and send it to the live viewer at `stream_to`); returns its path."""
    path = out / "agents" / f"agent-{k}.rrd"
    stream = open_stream(path, recording_id, stream_to)
    try:
        fused = FusedMap(Lattice.from_settings(config.mapping), bounds, config.mapping.known_weight)
        log_belief(stream, k, summary, out / "agents" / "patches", fused, started_at, config.mapping.max_patch_bytes)
        log_events(stream, k, agent_events(out / "logs", k, started_at))
    finally:
        stream.flush()
        stream.disconnect()
    return path


def record_agent_views(
    out: Path,
    recording_id: str,
    started_at: float,
    config: SwarmConfig,
    bounds: tuple[np.ndarray, np.ndarray],
    summaries: dict[int, AgentSummary],
    stream_to: str | None = None,
) -> list[Path]:
    """Write OUT/agents/agent-K.rrd for every agent with a summary, a process per core (the swarm has landed:
    the machine is the harness's; each agent's view is its own file); returns the files written."""
    jobs = [(out, k, recording_id, started_at, config, bounds, s, stream_to) for k, s in sorted(summaries.items())]
    if len(jobs) <= 1:
        return [record_agent_view(*job) for job in jobs]
    workers = min(len(jobs), os.cpu_count() or 1)
    with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
        return list(pool.map(record_agent_view, *zip(*jobs)))
