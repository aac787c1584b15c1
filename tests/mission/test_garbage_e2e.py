"""An exploring swarm under a flood of hostile messages (issue 7): 10,000 random and lying messages on every key
the agents listen to, sent while they fly. They keep flying, count and drop every one, and their maps hold only
the patches the swarm really sealed."""

from __future__ import annotations

import json
import random
from pathlib import Path
from typing import Any

import msgpack
import pytest
import zenoh

from swarm.bus.codec import SCHEMA_VERSION
from swarm.bus.keys import Keys
from swarm.config import bus_port, load_config
from swarm.mission.links import any_vehicle_airborne
from swarm.mission.report import held_patch_ids, read_sim_status, read_summary, sealed_patch_ids
from swarm.mission.run import RunState, run_mission
from tests.helpers import SwarmPorts, processes_mentioning

pytestmark = [pytest.mark.timeout(300), pytest.mark.mission]

MESSAGES = 10_000
PER_TICK = 500  # the supervision loop ticks at 4 Hz: the flood lasts about 5 s
FAKE_ID = 9
KINDS = ("state", "patch_chunk", "frontier_report", "target_assignment")


def _random_message(rng: random.Random) -> bytes:
    """Random bytes, or an envelope of the right version and a real kind around random data."""
    choice = rng.random()
    if choice < 0.3:
        return rng.randbytes(rng.randrange(0, 3000))
    if choice < 0.4:
        return rng.choice([b"\xdd\xff\xff\xff\xff", b"\xc6\x7f\xff\xff\xff", b"\x92\x01"])  # lying headers
    data: Any = {
        "sender": rng.choice([1, 2, FAKE_ID]),
        "id": rng.choice([1, 2, FAKE_ID, -1, "x"]),
        "leader": rng.choice([1, FAKE_ID]),
        "epoch": rng.randrange(0, 10**13),
        "seq": rng.randrange(-5, 100),
        "data": rng.randbytes(rng.randrange(0, 2000)),
        "points": [[rng.random()] * 3] * rng.randrange(0, 5),
    }
    for key in rng.sample(sorted(data), rng.randrange(0, len(data))):
        del data[key]
    version = SCHEMA_VERSION if rng.random() < 0.8 else rng.randrange(0, 256)
    return msgpack.packb({"v": version, "k": rng.choice(KINDS), "d": data}, use_bin_type=True)


class Flood:
    def __init__(self, mission: str, endpoints: list[str], run_dir: Path) -> None:
        self.keys = Keys(mission)
        self.run_dir = run_dir
        self.rng = random.Random(11)
        self.sent = 0
        self.endpoints = endpoints
        self.session: zenoh.Session | None = None

    def _targets(self) -> list[str]:
        k = self.keys
        return [
            key
            for agent in (1, 2, FAKE_ID)
            for key in (k.state(agent), k.patch(agent), k.frontiers(agent), k.targets(agent))
        ]

    def tick(self, state: RunState) -> None:
        if self.sent >= MESSAGES or not any_vehicle_airborne(read_sim_status(self.run_dir)):
            return
        if self.session is None:
            config = zenoh.Config()
            config.insert_json5("mode", '"peer"')
            config.insert_json5("connect/endpoints", json.dumps(self.endpoints))
            config.insert_json5("scouting/multicast/enabled", "false")
            config.insert_json5("scouting/gossip/enabled", "false")
            self.session = zenoh.open(config)
        keys = self._targets()
        for _ in range(min(PER_TICK, MESSAGES - self.sent)):
            self.session.put(self.rng.choice(keys), _random_message(self.rng))
            self.sent += 1

    def close(self) -> None:
        if self.session is not None:
            self.session.close()


def test_agents_fed_10000_hostile_messages_keep_flying_and_their_maps_hold_only_real_patches(
    tmp_path: Path, swarm_ports: SwarmPorts
) -> None:
    out = tmp_path / "run"
    config = load_config(
        overrides={
            "mission.world": "box",
            "mission.out": str(out),
            "mission.drones": 2,
            "mission.max_time_s": 200.0,
            **swarm_ports.settings(),
        }
    )
    flood = Flood(config.mission.name, [f"tcp/127.0.0.1:{bus_port(config.bus, k)}" for k in (1, 2)], out)
    try:
        report = run_mission(config, live=False, on_tick=flood.tick)
    finally:
        flood.close()

    assert flood.sent == MESSAGES, f"the mission ended after {flood.sent} messages"
    assert report["status"] == "complete", report["reason"]
    assert report["explored_fraction"] >= 0.95
    sealed = sealed_patch_ids(out / "agents" / "patches")
    assert sealed and all(p.split(".")[0] in ("1", "2") for p in sealed)
    for k in (1, 2):
        summary = read_summary(out, k)
        assert summary is not None
        assert held_patch_ids(summary) == sealed, f"agent {k}'s map holds something the swarm did not seal"
        dropped = sum(sum(kind.dropped.values()) for kind in summary.traffic.values())
        rejected = sum(summary.sync.rejected.values())
        assert dropped + rejected > 1000, (summary.traffic, summary.sync)
    assert report["converged"] is True
    assert not processes_mentioning(str(out)), "swarm run left processes behind"
