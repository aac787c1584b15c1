"""Map sharing over an emulated radio: each node in its own network namespace, links cut or lossy by nftables
(issue 4, tests 5 and 6). Needs root; everything created is removed even when a test fails."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest

from swarm.netem import LinkProfile, SwarmNetwork
from tests.sync.nodes import NodeSpec, NodeSwarm, holds_all

pytestmark = [
    pytest.mark.skipif(os.geteuid() != 0, reason="network namespaces and nftables need root"),
    pytest.mark.netns,
]


@pytest.fixture
def radio(tmp_path: Path) -> Iterator[tuple[SwarmNetwork, NodeSwarm]]:
    with SwarmNetwork(nodes=3) as net:
        swarm = NodeSwarm(tmp_path)
        try:
            yield net, swarm
        finally:
            swarm.close()


def _start(net: SwarmNetwork, swarm: NodeSwarm, spec: NodeSpec) -> None:
    spec.listen = net.address(spec.id)
    swarm.start(spec, wrap=lambda argv: net.exec_argv(spec.id, argv))


def _everyone_sees_everyone(statuses: dict[int, dict]) -> bool:
    return all(len(s.get("peers", [])) == 2 for s in statuses.values())


def test_partition_heals_and_all_three_converge_within_10_s(radio: tuple[SwarmNetwork, NodeSwarm]) -> None:
    net, swarm = radio
    for k in (1, 2, 3):
        _start(net, swarm, NodeSpec(k, patches=3, period_s=0.3, delay_s=6.0))
    swarm.wait_for(_everyone_sees_everyone, 15, "the three nodes see each other")
    net.cut_pair(1, 3)
    net.cut_pair(2, 3)
    swarm.wait_for(lambda s: all(len(s[k].get("sealed", [])) == 3 for k in (1, 2, 3)), 30, "all sealed")
    side_ab = swarm.sealed(1) | swarm.sealed(2)
    swarm.wait_for(holds_all(side_ab, [1, 2]), 15, "{1, 2} share their patches during the cut")
    assert set(swarm.status(3)["held"]) == swarm.sealed(3)  # node 3 got nothing across the cut

    net.restore_all()
    healed_in = swarm.wait_for(holds_all(swarm.all_sealed()), 10, "all three hold every patch after the heal")
    print(f"partition healed: all three nodes held all 9 patches {healed_in:.2f} s after the links came back")


def test_three_nodes_converge_with_30_percent_loss_on_every_link(radio: tuple[SwarmNetwork, NodeSwarm]) -> None:
    net, swarm = radio
    net.impair_all(LinkProfile(loss=0.3))
    for k in (1, 2, 3):
        _start(net, swarm, NodeSpec(k, patches=3, period_s=0.3, delay_s=3.0))
    swarm.wait_for(lambda s: all(len(s[k].get("sealed", [])) == 3 for k in (1, 2, 3)), 60, "all sealed")
    took = swarm.wait_for(holds_all(swarm.all_sealed()), 120, "every node holds every patch under 30 % loss")
    print(f"30 % loss on every link: all three nodes held all 9 patches {took:.1f} s after the last seal")
