"""Impairments measured with real traffic between node namespaces (one-way UDP counts, TCP goodput).

Loss checks send 3000 datagrams per flow: at 30 % the binomial standard deviation is 0.84 points, so the
+/- 4 point tolerance is about 5 sigma. Clean links and cut links must be exact (all or nothing).
"""

from __future__ import annotations

import re

import pytest

from swarm.netem import LinkProfile, NetemUnavailable, SwarmNetwork
from swarm.netem.commands import run
from tests.netem.measure import netem_problem, tcp_goodput_kbit, udp_one_way

pytestmark = [pytest.mark.skipif(netem_problem() is not None, reason=netem_problem() or ""), pytest.mark.netns]

N = 3000  # datagrams per flow for loss rates
SMALL = 300  # datagrams per flow for all-or-nothing checks
TOLERANCE = 0.04


def loss(received: int, sent: int = N) -> float:
    return 1.0 - received / sent


def assert_loss(got: dict[tuple[int, int], int], flow: tuple[int, int], expected: float) -> None:
    measured = loss(got[flow])
    print(f"flow {flow[0]}->{flow[1]}: expected loss {expected:.3f}, measured {measured:.4f} ({got[flow]}/{N})")
    assert abs(measured - expected) <= TOLERANCE, f"flow {flow}: loss {measured:.3f}, expected {expected:.3f}"


def test_clean_network_connects_every_pair(net: SwarmNetwork) -> None:
    flows = [(a, b) for a in (1, 2, 3) for b in (1, 2, 3) if a != b]
    assert udp_one_way(net, flows, SMALL) == {flow: SMALL for flow in flows}


def test_pair_loss_hits_only_that_pair(net: SwarmNetwork) -> None:
    net.impair_pair(1, 2, LinkProfile(loss=0.3))
    rules = net.rules()
    assert 'iifname "v1" oifname "v2" numgen random mod 1000000 < 300000' in rules
    assert 'iifname "v2" oifname "v1" numgen random mod 1000000 < 300000' in rules
    got = udp_one_way(net, [(1, 2), (2, 1), (3, 1), (1, 3)], N)
    assert_loss(got, (1, 2), 0.3)
    assert_loss(got, (2, 1), 0.3)
    assert got[(3, 1)] == N and got[(1, 3)] == N


def test_cut_pair_then_restore(net: SwarmNetwork) -> None:
    net.cut_pair(2, 1)
    got = udp_one_way(net, [(1, 2), (2, 1), (1, 3), (3, 2)], SMALL)
    assert got == {(1, 2): 0, (2, 1): 0, (1, 3): SMALL, (3, 2): SMALL}
    net.restore_pair(1, 2)
    assert "drop" not in net.rules()
    assert udp_one_way(net, [(1, 2), (2, 1)], SMALL) == {(1, 2): SMALL, (2, 1): SMALL}


def test_node_loss_and_cut(net: SwarmNetwork) -> None:
    net.impair_node(3, LinkProfile(loss=0.3))
    got = udp_one_way(net, [(1, 3), (3, 2), (1, 2)], N)
    assert_loss(got, (1, 3), 0.3)
    assert_loss(got, (3, 2), 0.3)
    assert got[(1, 2)] == N

    net.restore_node(3)
    net.cut_node(2)
    got = udp_one_way(net, [(1, 2), (2, 3), (3, 1)], SMALL)
    assert got == {(1, 2): 0, (2, 3): 0, (3, 1): SMALL}
    net.restore_node(2)
    assert udp_one_way(net, [(1, 2), (2, 3)], SMALL) == {(1, 2): SMALL, (2, 3): SMALL}


def test_all_links_and_layered_profiles(net: SwarmNetwork) -> None:
    net.impair_all(LinkProfile(loss=0.2))
    got = udp_one_way(net, [(1, 2), (2, 3), (3, 1)], N)
    for flow in got:
        assert_loss(got, flow, 0.2)

    # Profiles compose as independent drops: node 1's radio (10 %) then the 1-2 link (30 %).
    net.restore_all()
    net.impair_node(1, LinkProfile(loss=0.1))
    net.impair_pair(1, 2, LinkProfile(loss=0.3))
    got = udp_one_way(net, [(1, 2), (1, 3), (2, 3)], N)
    assert_loss(got, (1, 2), 1 - 0.9 * 0.7)
    assert_loss(got, (1, 3), 0.1)
    assert got[(2, 3)] == N


def test_node_rate_limit_both_directions(net: SwarmNetwork) -> None:
    net.impair_node(1, LinkProfile(rate_kbit=2000))
    assert "# node 1: tbf 2000 kbit/s" in net.rules()
    rates = tcp_goodput_kbit(net, [(1, 2), (2, 1)], seconds=1.5)
    print(f"TCP goodput with node 1 at 2000 kbit/s: up {rates[(1, 2)]:.0f}, down {rates[(2, 1)]:.0f} kbit/s")
    assert 1600 <= rates[(1, 2)] <= 2100 and 1600 <= rates[(2, 1)] <= 2100
    net.restore_node(1)
    assert "tbf" not in net.rules()
    assert "tbf" not in run(["ip", "netns", "exec", net.namespace(1), "tc", "qdisc", "show", "dev", "eth0"])


def test_refused_impairment_changes_nothing(net: SwarmNetwork) -> None:
    net.impair_pair(1, 3, LinkProfile(loss=0.25))
    before_rules, before = net.rules(), net.applied()
    with pytest.raises(NetemUnavailable, match="delay/jitter"):
        net.impair_node(2, LinkProfile(loss=0.5, delay_ms=30.0))
    assert net.applied() == before
    without_counters = re.compile(r"packets \d+ bytes \d+")
    assert without_counters.sub("", net.rules()) == without_counters.sub("", before_rules)
