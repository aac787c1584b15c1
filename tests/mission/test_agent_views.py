"""Each drone's own view as a recording (`swarm.mission.agent_views`), and the depth images a camera driver
records (`DepthRecording`), unit tier: real patches and logs written to files, read back through Rerun's reader.
A real mission's are checked in tests/mission/test_explore_e2e.py (the leader-kill mission)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from swarm.config import load_config
from swarm.mission.agent_views import BELIEF_PERIOD_S, agent_events, belief_snapshots, record_agent_views
from swarm.mission.recording import (
    DepthRecording,
    blocks_in_tiles,
    entity_rows,
    entity_spans,
    map_tiles,
    recording_ids,
    tile_fingerprint,
    tiles_near_blocks,
)
from swarm.patches import Lattice
from swarm.patches.fused import FusedMap
from swarm.patches.wire import decode_patch
from swarm.sim.worlds import load_world
from tests.file_models import agent_summary
from tests.mission.spin_patches import spin_patches

pytestmark = pytest.mark.unit

STARTED = 1_000_000.0  # the mission clock's zero, unix seconds


def test_agent_events_are_its_json_lines_on_the_mission_clock_restarts_included(tmp_path: Path) -> None:
    lines = [
        json.dumps({"t": STARTED + 2.0, "agent": 2, "event": "phase", "phase": "flying"}),
        "Traceback (most recent call last):",  # stderr in the same file
        json.dumps({"t": STARTED + 1.0, "agent": 2, "event": "starting", "epoch": 7}),
        json.dumps({"t": STARTED + 3.0, "agent": 3, "event": "phase"}),  # not this agent's
        '{"t": 1000004.0, "agent": 2, "event": "pa',  # a torn last line
    ]
    (tmp_path / "agent-2.log").write_text("\n".join(lines))
    (tmp_path / "agent-2.restart1.log").write_text(json.dumps({"t": STARTED + 9.5, "agent": 2, "event": "exit"}))
    (tmp_path / "agent-12.log").write_text(json.dumps({"t": STARTED, "agent": 12, "event": "starting"}))
    events = agent_events(tmp_path, 2, STARTED)
    assert [(e.t, e.event) for e in events] == [(1.0, "starting"), (2.0, "phase"), (9.5, "exit")]
    assert events[0].fields == {"epoch": 7} and events[1].fields == {"phase": "flying"}


def test_belief_snapshots_batch_patches_by_the_period_they_were_first_held_in() -> None:
    held_at = {"1.1.0": STARTED + 1.0, "2.1.0": STARTED + 12.0, "1.1.1": STARTED + 10.0, "2.1.1": STARTED + 35.0}
    assert list(belief_snapshots(held_at, STARTED, 10.0)) == [
        (10.0, ["1.1.0", "1.1.1"]),
        (20.0, ["2.1.0"]),
        (40.0, ["2.1.1"]),  # nothing new by 30 s: no snapshot
    ]
    assert list(belief_snapshots({}, STARTED, 10.0)) == []


def test_each_agent_gets_a_recording_of_the_map_it_held_its_paths_targets_and_log(tmp_path: Path) -> None:
    config = load_config(overrides={"mission.world": "box"})
    out = tmp_path / "run"
    patches = out / "agents" / "patches"
    patches.mkdir(parents=True)
    (out / "logs").mkdir()
    own = spin_patches(config, producer=1, yaws=range(0, 360, 60))
    other = spin_patches(config, producer=2, yaws=range(30, 360, 60))
    lattice = Lattice.from_settings(config.mapping)
    ids = []
    for data in own + other:
        pid = str(decode_patch(data, lattice, config.mapping.max_patch_bytes).id)
        (patches / f"{pid}.patch").write_bytes(data)
        ids.append(pid)
    # drone 1 held its own patches within the first period and drone 2's only in the third; one id it held has no
    # file (a patch it could not have fused either) and is left out
    held_at = {pid: STARTED + (3.0 if pid.startswith("1.") else 2.5 * BELIEF_PERIOD_S) for pid in ids}
    held_at["3.1.0"] = STARTED + 5.0
    summary = agent_summary(1)
    summary.sync.held_at = held_at
    log = [
        {
            "t": STARTED + 4.0,
            "agent": 1,
            "event": "target",
            "viewpoint": [2, 2, 1],
            "point": [3, 2, 1],
            "source": "self",
        },
        {"t": STARTED + 4.1, "agent": 1, "event": "path", "waypoints": [[1, 1, 1], [2, 1, 1], [2, 2, 1]]},
        {"t": STARTED + 6.0, "agent": 1, "event": "give_way", "to": 2, "refuge": [1.0, 1.0, 1.0]},
        {"t": STARTED + 8.0, "agent": 1, "event": "exploration_done", "reason": "no frontier"},
    ]
    (out / "logs" / "agent-1.log").write_text("\n".join(json.dumps(e) for e in log))
    world = load_world("box")
    [path] = record_agent_views(out, "run-9", STARTED, config, world.bounds, {1: summary})
    assert path == out / "agents" / "agent-1.rrd" and recording_ids(path) == ["run-9"]
    spans = entity_spans([path])
    tiles = {e: s for e, s in spans.items() if e.startswith("/agents/1/map/")}
    assert tiles and min(s.first_s for s in tiles.values()) == BELIEF_PERIOD_S
    assert max(s.last_s for s in tiles.values()) == 3 * BELIEF_PERIOD_S  # drone 2's patches changed it at 30 s
    held = entity_rows([path], "/series/belief_patches/1", "Scalars:scalars")
    assert held == [(BELIEF_PERIOD_S, [float(len(own))]), (3 * BELIEF_PERIOD_S, [float(len(own) + len(other))])]
    [(t, [viewpoint])] = entity_rows([path], "/agents/1/target", "Points3D:positions")
    assert t == pytest.approx(4.0) and viewpoint == pytest.approx([2.0, 2.0, 1.0])
    [(t, [strip])] = entity_rows([path], "/agents/1/path", "LineStrips3D:strips")
    assert t == pytest.approx(4.1) and np.asarray(strip).tolist() == [[1, 1, 1], [2, 1, 1], [2, 2, 1]]
    texts = entity_rows([path], "/agents/1/log", "TextLog:text")
    assert [text for _, [text] in texts][2] == "give_way to=2 refuge=[1.0, 1.0, 1.0]"
    levels = [level for _, [level] in entity_rows([path], "/agents/1/log", "TextLog:level")]
    assert levels == ["INFO", "INFO", "WARN", "INFO"]
    assert spans["/agents/1/target"].last_s == pytest.approx(8.0)  # cleared when exploration ended


def test_a_depth_recording_holds_each_drones_camera_pose_and_depth_once_per_period(tmp_path: Path) -> None:
    path = tmp_path / "cameras.rrd"
    K = np.array([[80.0, 0, 80], [0, 80.0, 60], [0, 0, 1]])
    recording = DepthRecording(path, "run-3", STARTED, K, (160, 120), period_s=1.0)
    T = np.eye(4)
    T[:3, 3] = (1.0, 2.0, 1.5)
    depth = np.full((120, 160), 2.5, dtype=np.float32)
    depth[0, 0] = np.nan
    for i in range(21):  # 10 Hz for 2 s: one every second kept
        recording.frame(1, STARTED + 0.1 * i, T, depth)
    recording.frame(2, STARTED + 0.5, T, depth)
    recording.close()
    spans = entity_spans([path])
    assert spans["/drones/1/camera/depth"].rows == 3 and spans["/drones/2/camera/depth"].rows == 1
    [(_, [translation]), *_] = entity_rows([path], "/drones/1/camera", "Transform3D:translation")
    assert translation == pytest.approx([1.0, 2.0, 1.5])
    [(_, [buffer]), *_] = entity_rows([path], "/drones/1/camera/depth", "DepthImage:buffer")
    millimetres = np.frombuffer(bytes(buffer), dtype=np.uint16)
    assert millimetres[0] == 0 and set(millimetres[1:].tolist()) == {2500}


def test_a_surface_meshed_from_the_blocks_near_new_patches_is_the_full_surface_in_their_tiles() -> None:
    config = load_config(overrides={"mission.world": "box"})
    world = load_world("box")
    lattice = Lattice.from_settings(config.mapping)
    fused = FusedMap(lattice, world.bounds, config.mapping.known_weight)
    first = spin_patches(config, producer=1, yaws=range(0, 180, 30))
    later = spin_patches(config, producer=2, yaws=[200])  # one look: a part of the room
    for data in first:
        fused.add(decode_patch(data, lattice, config.mapping.max_patch_bytes))
    new_keys = []
    for data in later:
        patch = decode_patch(data, lattice, config.mapping.max_patch_bytes)
        fused.add(patch)
        new_keys.append(patch.blocks.keys)
    near = tiles_near_blocks(np.vstack(new_keys), lattice)
    everything = map_tiles(*fused.mesh())
    assert near and set(everything) - near, "the later patches should reach some tiles and not others"
    blocks = blocks_in_tiles(fused.block_keys(), near, lattice)
    assert 0 < len(blocks) < len(fused.block_keys())
    partial = map_tiles(*fused.mesh(within=blocks))
    for tile in near & set(everything):
        assert tile_fingerprint(*partial[tile]) == tile_fingerprint(*everything[tile]), tile
    assert set(everything) & near == set(partial) & near
