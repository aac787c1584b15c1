"""A certified but hostile member (it holds drone 3's signing key) forges the other producers' patches, in real Zenoh
sessions: it pushes them as relays, pushes them on the victim's own key, pre-empts the ids the victims have yet to
seal, and advertises and serves them to every pull. Every forgery is counted by kind and none is fused, held or
served: each victim ends holding exactly the real patches, byte for byte what their producers sealed, and its fused
map is the one the same two nodes build with no attacker about."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import zenoh

from swarm.bus.codec import encode
from swarm.bus.holdings import DigestWire
from swarm.bus.keys import Keys
from swarm.bus.messages import AgentState
from swarm.bus.phase import Phase
from swarm.config import MappingSettings
from swarm.deploy.certs import make_signing_authority
from swarm.patches.lattice import Lattice
from swarm.patches.patch import FrameSpan, Patch, PatchId, VoxelBlocks
from swarm.patches.signing import PatchSigner, load_signing
from swarm.patches.wire import encode_patch
from swarm.sync.chunks import split_patch
from tests.bus.helpers import make_state
from tests.sync.nodes import NodeSpec, NodeSwarm, holds_all

pytestmark = pytest.mark.bus

ATTACKER = 3
VICTIMS = (1, 2)
PATCHES = 4
FORGED_SEQS = range(8)  # every id the victims will seal, and more


@pytest.fixture
def keys(tmp_path: Path) -> Path:
    directory = tmp_path / "keys"
    make_signing_authority(directory, drones=3)
    return directory


@pytest.fixture
def swarm(tmp_path: Path) -> Iterator[NodeSwarm]:
    nodes = NodeSwarm(tmp_path, mission="forgery")
    try:
        yield nodes
    finally:
        nodes.close()


@pytest.fixture
def quiet_swarm(tmp_path: Path) -> Iterator[NodeSwarm]:
    (tmp_path / "quiet").mkdir()
    nodes = NodeSwarm(tmp_path / "quiet", mission="no-forgery")
    try:
        yield nodes
    finally:
        nodes.close()


def start_victims(swarm: NodeSwarm, keys: Path) -> None:
    # Every observation in every patch: a changes-only patch depends on what its producer had received when it
    # sealed, so the attacked and the quiet swarms' maps could differ for timing alone.
    extra = [f"sync.signing_dir={keys}", "mapping.patch_changes_only=false"]
    for k in VICTIMS:
        swarm.start(NodeSpec(k, patches=PATCHES, period_s=0.4, delay_s=3.0, extra=extra))


def free_space(pid: PatchId, lattice: Lattice) -> Patch:
    """A small valid patch that says 'all free' in the middle of the box world."""
    keys = np.array([[2, 2, 1], [3, 2, 1], [2, 3, 1]], dtype=np.int32)
    n = lattice.voxels_per_block
    blocks = VoxelBlocks(keys, np.full((3, n), 127, np.int8), np.ones((3, n), lattice.weight_dtype))
    lo, hi = lattice.block_bounds(keys)
    return Patch(pid, lattice, FrameSpan(0, 0, 1.0, 1.0), np.eye(4), (lo, hi), blocks)


def forgeries(epochs: dict[int, int], keys_dir: Path, lattice: Lattice) -> dict[PatchId, bytes]:
    """Producer 1's ids signed with drone 3's key and certificate; producer 2's ids unsigned."""
    drone_3 = load_signing(keys_dir, ATTACKER).signer
    assert drone_3 is not None
    out = {}
    for seq in FORGED_SEQS:
        one = PatchId(1, epochs[1], seq)
        out[one] = encode_patch(free_space(one, lattice), signer=PatchSigner(1, drone_3.key, drone_3.cert_der))
        two = PatchId(2, epochs[2], seq)
        out[two] = encode_patch(free_space(two, lattice))
    return out


def attacker_state(seq: int, epochs: dict[int, int]) -> AgentState:
    holdings = DigestWire.model_validate(
        {"entries": [{"producer": k, "epoch": epochs[k], "ranges": [[0, max(FORGED_SEQS)]]} for k in VICTIMS]}
    )
    state = make_state(ATTACKER, seq, epoch=1)
    return state.model_copy(update={"t": time.time(), "phase": Phase.MAPPING, "holdings": holdings})


def test_forged_and_pre_empted_patches_never_enter_a_map(swarm: NodeSwarm, quiet_swarm: NodeSwarm, keys: Path) -> None:
    start_victims(swarm, keys)
    swarm.wait_for(lambda s: all(st.get("epoch") for st in s.values()), 30, "the victims' epochs")
    epochs = {k: int(swarm.status(k)["epoch"]) for k in VICTIMS}
    lattice = Lattice.from_settings(MappingSettings(voxel_size_m=0.2, patch_frames=3))
    forged = forgeries(epochs, keys, lattice)
    bus = Keys("forgery")
    chunk_bytes = 2048

    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("connect/endpoints", str([swarm.endpoint(k) for k in VICTIMS]).replace("'", '"'))
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("scouting/gossip/enabled", "false")
    session = zenoh.open(config)
    try:
        token = session.liveliness().declare_token(bus.alive(ATTACKER))

        def serve(query: zenoh.Query) -> None:  # every pull gets the forgeries, whatever it asked for
            for pid, data in forged.items():
                for chunk in split_patch(ATTACKER, pid, data, chunk_bytes):
                    query.reply(query.key_expr, encode(chunk))

        queryable = session.declare_queryable(bus.store(ATTACKER), serve)
        seq = 0
        done = lambda s: all(len(st.get("sealed", [])) == PATCHES for st in s.values())  # noqa: E731
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            seq += 1
            session.put(bus.state(ATTACKER), encode(attacker_state(seq, epochs)))
            for pid, data in forged.items():
                for chunk in split_patch(ATTACKER, pid, data, chunk_bytes):  # a relay pushed as if its own
                    session.put(bus.patch(ATTACKER), encode(chunk))
                for chunk in split_patch(pid.producer, pid, data, chunk_bytes):  # on the victim's own key
                    session.put(bus.patch(pid.producer), encode(chunk))
            if done(swarm.statuses()) and seq > 20:
                break
            time.sleep(0.2)
        expected = swarm.all_sealed()
        assert len(expected) == PATCHES * len(VICTIMS)
        swarm.wait_for(holds_all(expected), 30, "every victim holds every real patch")
        queryable.undeclare()
        token.undeclare()
    finally:
        session.close()

    statuses = swarm.statuses()
    own_content = {
        pid: digest
        for k, st in statuses.items()
        for pid, digest in st["sync"]["content"].items()
        if pid.startswith(f"{k}.")
    }
    assert len(own_content) == len(expected)
    for k, status in statuses.items():
        assert set(status["held"]) == expected, f"node {k} holds {sorted(set(status['held']) - expected)}"
        assert status["sync"]["content"] == own_content, f"node {k} holds other bytes than the producers sealed"
        rejected, dropped = status["sync"]["rejected"], status["traffic"]["patch_chunk"]["dropped"]
        assert dropped.get("own_id", 0) > 0, dropped  # its own ids, pushed on its own key and served by the liar
        assert dropped.get("pushed_relay", 0) > 0, dropped
        other = 2 if k == 1 else 1
        assert rejected.get("unsigned" if other == 2 else "signer", 0) > 0, rejected
        assert not rejected.get("signature"), rejected
    attacked = {st["fused_digest"] for st in statuses.values()}
    assert len(attacked) == 1

    # the same two nodes with nobody attacking: the same map (camera poses and noise follow the frame count)
    swarm.close()  # its ports are the quiet swarm's
    start_victims(quiet_swarm, keys)
    quiet_swarm.wait_for(lambda s: all(len(st.get("sealed", [])) == PATCHES for st in s.values()), 60, "sealed")
    quiet_swarm.wait_for(holds_all(quiet_swarm.all_sealed()), 30, "every node holds every patch")
    quiet_swarm.wait_for(lambda s: len({st["fused_digest"] for st in s.values()}) == 1, 10, "equal fused maps")
    assert {st["fused_digest"] for st in quiet_swarm.statuses().values()} == attacked
