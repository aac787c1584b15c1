"""Cluster leader election over an emulated radio (issue 5): each node in its own network namespace, real Zenoh
sessions in router mode, a real nftables partition. Nodes are `swarm mapnode` processes: an agent's bus side
(token, heartbeats with role and leader, membership) without a vehicle. Needs root; everything is removed even
when the test fails."""

from __future__ import annotations

import os
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from swarm.netem import SwarmNetwork
from tests.sync.nodes import NodeSpec, NodeSwarm

pytestmark = [
    pytest.mark.skipif(os.geteuid() != 0, reason="network namespaces and nftables need root"),
    pytest.mark.netns,
]

NODES = (1, 2, 3, 4)


@pytest.fixture
def radio(tmp_path: Path) -> Iterator[tuple[SwarmNetwork, NodeSwarm]]:
    with SwarmNetwork(nodes=len(NODES)) as net:
        swarm = NodeSwarm(tmp_path, mission="election", mode="router")
        try:
            yield net, swarm
        finally:
            swarm.close()


def _clusters(expected: dict[int, list[int]]):
    """Every node sees exactly its expected cluster and follows its lowest id."""

    def condition(statuses: dict[int, dict]) -> bool:
        return all(
            statuses.get(k, {}).get("cluster") == members and statuses[k].get("leader") == min(members)
            for k, members in expected.items()
        )

    return condition


def test_a_partition_gives_two_leaders_and_the_heal_gives_one(radio: tuple[SwarmNetwork, NodeSwarm]) -> None:
    net, swarm = radio
    for k in NODES:
        spec = NodeSpec(k, patches=0)
        spec.listen = net.address(k)
        swarm.start(spec, wrap=lambda argv, k=k: net.exec_argv(k, argv))
    swarm.wait_for(_clusters({k: list(NODES) for k in NODES}), 20, "one cluster led by node 1")
    assert [swarm.status(k)["role"] for k in NODES] == ["leader", "explorer", "explorer", "explorer"]

    for a in (1, 2):
        for b in (3, 4):
            net.cut_pair(a, b)
    cut_at = time.monotonic()
    halves = {1: [1, 2], 2: [1, 2], 3: [3, 4], 4: [3, 4]}
    split = swarm.wait_for(_clusters(halves), 10, "two clusters: {1, 2} led by 1, {3, 4} by 3")
    assert [swarm.status(k)["role"] for k in NODES] == ["leader", "explorer", "leader", "explorer"]
    print(f"partition: node 3 led its cluster {time.monotonic() - cut_at:.2f} s after the cut (wait {split:.2f} s)")

    net.restore_all()
    healed = swarm.wait_for(_clusters({k: list(NODES) for k in NODES}), 15, "one cluster again after the heal")
    assert [swarm.status(k)["role"] for k in NODES] == ["leader", "explorer", "explorer", "explorer"]
    print(f"heal: node 1 led all four again {healed:.2f} s after the links came back")
