"""A hostile member for mission tests: the real agent flies its drone (it holds a valid certificate and signing key)
while a second Zenoh session with the same certificate attacks the swarm, every ATTACK_PERIOD_S:

- forges the victims' next patches (free space where they fly), signed with its own key posing as them, pushed as
  its own, advertised in its agent's every heartbeat (the holdings it announces are patched to include them) and
  in extra heartbeats, and served from its store to every pull;
- sends a patch of its own with no observed voxel and blocks far beyond a real patch;
- floods its keys with nested msgpack arrays;
- lies as an explorer: looks from everywhere in the volume, huge gains, arrived and in a pocket on every report;
- asks the victims' stores for everything they hold, under other requesters' names.

Run by the harness in place of `swarm agent` (tests/mission/test_hostile_member_e2e.py): python -m
tests.mission.hostile_agent --config AGENT.toml. Not part of the product.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import itertools
import os
import random
import sys
import threading
import time
from pathlib import Path

import numpy as np
import zenoh

from swarm.agent.main import Agent
from swarm.bus.codec import DecodeError, decode, encode
from swarm.bus.holdings import DigestWire
from swarm.bus.messages import AgentState
from swarm.bus.phase import Phase
from swarm.bus.session import open_session
from swarm.config import SwarmConfig, load_config
from swarm.patches.digest import PatchDigest
from swarm.patches.lattice import Lattice
from swarm.patches.patch import FrameSpan, Patch, PatchId, VoxelBlocks
from swarm.patches.signing import PatchSigner, load_signing
from swarm.patches.wire import encode_patch
from swarm.roles.messages import FrontierReport, as_points
from swarm.sync.chunks import split_patch
from swarm.sync.requests import request_parameters
from swarm.sync.service import PatchSync
from tests.bus.helpers import make_state

ATTACK_PERIOD_S = 0.25
GIANT_BLOCKS = 40_000
FORGED_AHEAD = 8


class Attacker:
    def __init__(self, config: SwarmConfig, agent: Agent) -> None:
        self.config = config
        self.agent = agent
        self.id = config.agent.id
        self.lattice = Lattice.from_settings(config.mapping)
        signing_dir = config.signing_dir()
        assert signing_dir is not None, "the hostile member needs its signing key"
        signer = load_signing(signing_dir, self.id).signer
        assert signer is not None
        self.signer = signer
        self.victims: dict[int, AgentState] = {}
        self.forged: dict[PatchId, bytes] = {}
        self.rng = random.Random(self.id)
        self.sent: dict[str, int] = {}
        self.stop = threading.Event()

    def count(self, what: str, n: int = 1) -> None:
        self.sent[what] = self.sent.get(what, 0) + n

    def run(self) -> None:
        """A thread: a session of its own with the agent's certificate, dialling the agent's peers."""
        bus = self.config.agent_bus().model_copy(update={"listen": []})
        session = open_session(bus)
        keys = self.agent.keys
        try:
            session.declare_subscriber(keys.all_states, self._on_state)
            session.declare_queryable(keys.store(self.id), self._serve)
            while not self.stop.wait(ATTACK_PERIOD_S):
                self._attack(session)
                self.count("rounds")
        finally:
            session.close()
            print(f"hostile member: sent {self.sent}", file=sys.stderr, flush=True)

    def _on_state(self, sample: zenoh.Sample) -> None:
        try:
            state = decode(sample.payload.to_bytes(), AgentState, 1 << 20)
        except DecodeError:
            return
        if state.id != self.id:
            self.victims[state.id] = state

    def _serve(self, query: zenoh.Query) -> None:
        for pid, data in list(self.forged.items())[-16:]:
            for chunk in split_patch(self.id, pid, data, self.config.sync.chunk_bytes):
                query.reply(query.key_expr, encode(chunk))
        self.count("forged_served")

    def _attack(self, session: zenoh.Session) -> None:
        keys = self.agent.keys
        for victim, state in list(self.victims.items()):
            self._forge(session, victim, state)
            held = list(itertools.islice(PatchDigest.from_wire_model(state.holdings).ids(), 64))
            if held:
                asker = self.rng.choice([k for k in range(1, 10) if k != victim])
                for _ in session.get(f"{keys.store(victim)}?{request_parameters(held, asker)}", timeout=0.2):
                    pass
                self.count("store_queries")
        self._lying_heartbeat(session)
        self._giant_empty_patch(session)
        nested = b"\x91" * 2000 + b"\xc0"
        for key in (keys.state(self.id), keys.frontiers(self.id), keys.patch(self.id)):
            session.put(key, nested)
        self.count("nested", 3)
        self._lying_report(session)

    def _forge(self, session: zenoh.Session, victim: int, state: AgentState) -> None:
        """The victim's next FORGED_AHEAD ids, as free space around where it is, signed with our key in its name: the
        farther ones are advertised for seconds before the victim seals them, so the other drones pull them."""
        digest = PatchDigest.from_wire_model(state.holdings)
        own = [pid.seq for pid in digest.ids() if pid.producer == victim and pid.epoch == state.epoch]
        start = max(own) + 1 if own else 0
        centre = self.lattice.point_to_block(np.array([state.position]))[0]
        keys = np.array([centre + offset for offset in ((0, 0, 0), (1, 0, 0), (0, 1, 0))], dtype=np.int32)
        n = self.lattice.voxels_per_block
        blocks = VoxelBlocks(keys, np.full((3, n), 127, np.int8), np.ones((3, n), self.lattice.weight_dtype))
        posing = PatchSigner(victim, self.signer.key, self.signer.cert_der)
        for seq in range(start, start + FORGED_AHEAD):
            pid = PatchId(victim, state.epoch, seq)
            if pid not in self.forged:
                patch = Patch(
                    pid, self.lattice, FrameSpan(0, 0, 1.0, 1.0), np.eye(4), self.lattice.block_bounds(keys), blocks
                )
                self.forged[pid] = encode_patch(patch, signer=posing)
            for chunk in split_patch(self.id, pid, self.forged[pid], self.config.sync.chunk_bytes):
                session.put(self.agent.keys.patch(self.id), encode(chunk))
            self.count("forged_pushed")

    def _lying_heartbeat(self, session: zenoh.Session) -> None:
        ids = list(self.forged)[-200:]
        sync = getattr(self.agent, "sync", None)
        if not ids or sync is None:
            return
        claim = PatchDigest.of(ids).union(PatchDigest.from_wire_model(sync.holdings).ids())
        here = self.agent._position()
        lie = {
            "t": time.time(),
            "position": here,
            "phase": Phase.MAPPING,
            "holdings": claim.announced().to_wire_model(),
        }
        state = make_state(self.id, 10**9 + self.sent.get("heartbeats", 0), epoch=self.agent.epoch).model_copy(
            update=lie
        )
        for _ in range(3):  # more often than the real agent's own heartbeats on the same key
            session.put(self.agent.keys.state(self.id), encode(state))
        self.count("heartbeats", 3)

    def _giant_empty_patch(self, session: zenoh.Session) -> None:
        if self.sent.get("giant", 0) >= 20:
            return
        n = self.lattice.voxels_per_block
        keys = np.stack(np.unravel_index(np.arange(GIANT_BLOCKS), (40, 40, 25)), axis=1).astype(np.int32)
        blocks = VoxelBlocks(
            keys, np.zeros((GIANT_BLOCKS, n), np.int8), np.zeros((GIANT_BLOCKS, n), self.lattice.weight_dtype)
        )
        pid = PatchId(self.id, self.agent.epoch, 10**6 + self.sent.get("giant", 0))
        patch = Patch(pid, self.lattice, FrameSpan(0, 0, 1.0, 1.0), np.eye(4), self.lattice.block_bounds(keys), blocks)
        data = encode_patch(patch, signer=self.signer)
        for chunk in split_patch(self.id, pid, data, self.config.sync.chunk_bytes):
            session.put(self.agent.keys.patch(self.id), encode(chunk))
        self.count("giant")

    def _lying_report(self, session: zenoh.Session) -> None:
        volume = self.config.mission.volume
        assert volume is not None
        lo, hi = np.array(volume.min), np.array(volume.max)
        everywhere = lo + (hi - lo) * np.random.default_rng(self.sent.get("reports", 0)).random((1000, 3))
        report = FrontierReport(
            id=self.id,
            epoch=self.agent.epoch,
            seq=10**9 + self.sent.get("reports", 0),
            position=self.agent._position(),
            viewpoints=as_points(everywhere[:32]),
            points=as_points(everywhere[32:64]),
            gains=np.full(32, 3e38, dtype=np.float32),
            visited=as_points(everywhere),
            arrived=True,
            in_pocket=True,
        )
        for _ in range(10):
            session.put(self.agent.keys.frontiers(self.id), encode(report))
        self.count("reports", 10)


def lie_in_every_heartbeat(attacker: Attacker) -> None:
    """The agent's own heartbeats announce the forgeries too: a claim that came and went with every honest
    heartbeat would restart the victims' grace before they pull, so the pull attack would land only by chance."""
    honest = PatchSync.holdings

    def holdings(sync: PatchSync) -> DigestWire:
        real = honest.fget(sync)  # type: ignore[attr-defined]
        forged = list(attacker.forged)[-200:]
        if not forged:
            return real
        return PatchDigest.of(forged).union(PatchDigest.from_wire_model(real).ids()).announced().to_wire_model()

    PatchSync.holdings = property(holdings)  # type: ignore[method-assign,assignment]


async def fly_and_attack(config: SwarmConfig) -> int:
    agent = Agent(config)
    attacker = Attacker(config, agent)
    lie_in_every_heartbeat(attacker)
    thread = threading.Thread(target=_attack_when_ready, args=(agent, attacker), daemon=True)
    thread.start()
    try:
        return await agent.run()
    finally:
        attacker.stop.set()
        with contextlib.suppress(Exception):
            await asyncio.to_thread(thread.join, 10)


def _attack_when_ready(agent: Agent, attacker: Attacker) -> None:
    while not attacker.stop.is_set() and getattr(agent, "keys", None) is None:
        time.sleep(0.1)  # the agent opens its bus first: its keys are the mission's
    if not attacker.stop.is_set():
        attacker.run()


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--config", type=Path, required=True)
    args = parser.parse_args()
    code = asyncio.run(fly_and_attack(load_config(args.config)))
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


if __name__ == "__main__":
    main()
