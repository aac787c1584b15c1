"""Map sharing between separate processes over real Zenoh sessions on loopback (issue 4, tests 1-4)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.sync.nodes import NodeSpec, NodeSwarm, holds_all

pytestmark = pytest.mark.bus

CHUNK_BYTES = 512  # the smallest allowed: these patches are 1-3 kB, so each travels in several chunks


@pytest.fixture
def swarm(tmp_path: Path) -> Iterator[NodeSwarm]:
    nodes = NodeSwarm(tmp_path)
    try:
        yield nodes
    finally:
        nodes.close()


def _sealed_everything(swarm: NodeSwarm, per_node: dict[int, int]) -> set[str]:
    swarm.wait_for(lambda s: all(len(s[k].get("sealed", [])) == n for k, n in per_node.items()), 60, "all sealed")
    return swarm.all_sealed()


def test_three_nodes_end_with_every_patch_and_identical_fused_maps(swarm: NodeSwarm) -> None:
    for k in (1, 2, 3):
        swarm.start(NodeSpec(k, patches=4, period_s=0.3, delay_s=1.5, extra=[f"sync.chunk_bytes={CHUNK_BYTES}"]))
    expected = _sealed_everything(swarm, {1: 4, 2: 4, 3: 4})
    assert len(expected) == 12
    swarm.wait_for(holds_all(expected), 30, "every node holds all 12 patches")
    swarm.wait_for(
        lambda s: (
            len({st.get("fused_digest") for st in s.values()}) == 1
            and all(st.get("fused_patches") == 12 for st in s.values())
        ),
        10,
        "equal fused-map hashes",
    )
    statuses = swarm.statuses()
    for k, status in statuses.items():
        sync = status["sync"]
        assert sync["rejected"] == {}
        assert sync["received_by_push"] + sync["received_by_pull"] == 8, (k, sync)
        others = [p["bytes"] for j, st in statuses.items() if j != k for p in st["sealed"]]
        assert min(others) > CHUNK_BYTES  # so every patch travelled in several chunks, and every chunk arrived:
        assert status["traffic"]["patch_chunk"]["recv_msgs"] >= sum(-(-n // CHUNK_BYTES) for n in others), k


def test_pushes_lost_on_purpose_are_recovered_by_pulls(swarm: NodeSwarm) -> None:
    drop_all = ["sync.push_drop_fraction=1.0"]
    for k in (1, 2, 3):
        swarm.start(NodeSpec(k, patches=3, period_s=0.3, delay_s=1.5, extra=drop_all))
    expected = _sealed_everything(swarm, {1: 3, 2: 3, 3: 3})
    swarm.wait_for(holds_all(expected), 30, "pulls recover every patch")
    for k, status in swarm.statuses().items():
        sync = status["sync"]
        assert sync["received_by_push"] == 0
        assert sync["received_by_pull"] == 6
        assert sync["push_chunks_dropped_on_purpose"] >= 3
        assert sync["patches_served"] > 0, k  # every node served someone


def test_missing_patch_is_served_by_the_nearest_holder_not_the_producer(swarm: NodeSwarm) -> None:
    swarm.start(NodeSpec(1, patches=4, period_s=0.2, delay_s=1.0, position=(100.0, 0.0, 1.0)))
    swarm.start(NodeSpec(2, patches=0, position=(0.0, 0.0, 1.0)))
    produced = _sealed_everything(swarm, {1: 4})
    swarm.wait_for(holds_all(produced, [2]), 20, "node 2 holds node 1's patches")
    # node 3 joins late next to node 2: node 1's patches reach it only by pulls, and node 2 is nearer
    swarm.start(NodeSpec(3, patches=0, position=(1.0, 0.0, 1.0)))
    swarm.wait_for(holds_all(produced, [3]), 20, "node 3 holds node 1's patches")
    # each node writes its status on its own 0.2 s beat: the servers' may not show the serving yet
    swarm.wait_for(
        lambda s: sum(s[k]["sync"]["served_to"].get("3", 0) for k in (1, 2)) >= 4, 5, "the servers' statuses"
    )
    s1, s2, s3 = (swarm.status(k)["sync"] for k in (1, 2, 3))
    assert s3["received_from"] == {"2": 4}
    assert s3["received_by_pull"] == 4
    assert s2["served_to"].get("3") == 4
    assert "3" not in s1["served_to"]


@pytest.mark.parametrize("mode", ["peer", "router"])
def test_chain_relays_patches_between_nodes_that_cannot_reach_each_other(tmp_path: Path, mode: str) -> None:
    swarm = NodeSwarm(tmp_path, mode=mode)
    try:
        # 1 <-> 2 <-> 3: node 3 dials only node 2, node 1 dials nobody, gossip and multicast are off
        swarm.start(NodeSpec(1, patches=3, period_s=0.3, delay_s=2.0, connect=[]))
        swarm.start(NodeSpec(2, patches=0, connect=[1]))
        swarm.start(NodeSpec(3, patches=0, connect=[2]))
        produced = _sealed_everything(swarm, {1: 3})
        took = swarm.wait_for(holds_all(produced, [3]), 30, "node 1's patches reach node 3")
        s3 = swarm.status(3)
        print(f"chain ({mode}): node 3 held all 3 patches {took:.2f} s after they were sealed")
        if mode == "peer":
            # peers do not forward: node 3 never hears node 1, and gets its patches from node 2's store
            assert 1 not in s3["peers"]
            assert s3["sync"]["received_from"] == {"2": 3}
        else:
            assert 1 in s3["peers"]  # routers forward node 1's heartbeats to node 3
    finally:
        swarm.close()
