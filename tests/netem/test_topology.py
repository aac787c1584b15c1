"""Namespaces come and go with SwarmNetwork: created by up(), all removed by down(), on errors too."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from swarm.netem import NetemUnavailable, SwarmNetwork, remove_leftovers, topology
from swarm.netem.commands import namespaces, run, tool
from tests.netem.measure import netem_problem

pytestmark = [pytest.mark.skipif(netem_problem() is not None, reason=netem_problem() or ""), pytest.mark.netns]


def with_prefix(prefix: str) -> list[str]:
    return [name for name in namespaces() if name.startswith(prefix + "-")]


def test_up_creates_and_down_removes_the_namespaces() -> None:
    with SwarmNetwork(nodes=3) as net:
        assert sorted(with_prefix(net.prefix)) == sorted([f"{net.prefix}-hub", *(net.namespace(k) for k in (1, 2, 3))])
        assert net.is_up
        assert net.exec_argv(2, ["true"]) == [tool("ip"), "netns", "exec", net.namespace(2), "true"]
        eth0 = run(["ip", "-n", net.namespace(2), "-d", "addr", "show", "dev", "eth0"])
        assert f"inet {net.address(2)}/24" in eth0
        assert "gso_max_size 1500 gso_max_segs 1" in eth0
        assert "PERMANENT" in run(["ip", "-n", net.namespace(2), "neigh", "show", net.address(1)])
        radio_route = run(["ip", "-n", net.namespace(2), "route", "show", "dev", "eth0"])
        assert f"rto_min lock {topology.RADIO_RTO_MIN}" in radio_route, radio_route
    assert with_prefix(net.prefix) == []
    assert not net.is_up


@pytest.mark.parametrize("error", [RuntimeError, KeyboardInterrupt])
def test_exception_inside_with_still_removes_everything(error: type[BaseException]) -> None:
    prefix = ""
    with pytest.raises(error, match="test body failed"):
        with SwarmNetwork(nodes=2) as net:
            prefix = net.prefix
            assert len(with_prefix(prefix)) == 3
            raise error("test body failed")
    assert prefix and with_prefix(prefix) == []


def test_up_and_down_are_idempotent() -> None:
    net = SwarmNetwork(nodes=2)
    net.down()  # never up: nothing to do
    try:
        net.up()
        net.up()
        assert len(with_prefix(net.prefix)) == 3
        run(["ip", "netns", "delete", net.namespace(1)])  # someone else removed a part
    finally:
        net.down()
    net.down()
    assert with_prefix(net.prefix) == []


def test_instances_do_not_collide() -> None:
    with SwarmNetwork(nodes=1) as a, SwarmNetwork(nodes=1) as b:
        assert a.prefix != b.prefix and a.address(1) != b.address(1)
        assert a.prefix.startswith("swn-") and len(with_prefix(a.prefix)) == len(with_prefix(b.prefix)) == 2


def test_failing_up_removes_what_it_made(monkeypatch: pytest.MonkeyPatch) -> None:
    real_add_node = topology.add_node

    def add_node(layout: topology.NetworkLayout, k: int) -> None:
        if k == 3:
            raise NetemUnavailable("'ip netns add' failed: injected")
        real_add_node(layout, k)

    monkeypatch.setattr(topology, "add_node", add_node)
    net = SwarmNetwork(nodes=4)
    with pytest.raises(NetemUnavailable, match="injected"):
        net.up()
    assert with_prefix(net.prefix) == [] and not net.is_up


def test_not_root_is_refused_before_anything_is_created(monkeypatch: pytest.MonkeyPatch) -> None:
    before = namespaces()
    monkeypatch.setattr(os, "geteuid", lambda: 1000)
    with pytest.raises(NetemUnavailable, match="needs root") as info:
        SwarmNetwork(nodes=2).up()
    assert "\n" not in str(info.value)
    monkeypatch.undo()
    assert namespaces() == before


def test_down_ends_processes_left_inside() -> None:
    with SwarmNetwork(nodes=1) as net:
        proc = subprocess.Popen(net.exec_argv(1, [sys.executable, "-c", "import time; time.sleep(60)"]))
        try:
            net.down()
            assert proc.wait(timeout=5) != 0
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()


def test_remove_leftovers_only_removes_dead_instances() -> None:
    # A process that brings a network up and dies without down() (os._exit skips atexit, like SIGKILL).
    script = (
        "import os; from swarm.netem import SwarmNetwork; net = SwarmNetwork(nodes=2); net.up(); "
        "print(net.prefix, flush=True); os._exit(0)"
    )
    dead_prefix = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, check=True, timeout=30
    ).stdout.strip()
    foreign = "swn-1234-999999999-other"  # dead pid, but not a name swarm.netem creates
    run(["ip", "netns", "add", foreign])
    try:
        with SwarmNetwork(nodes=1) as live:
            dead = with_prefix(dead_prefix)
            assert len(dead) == 3
            removed = remove_leftovers()
            assert set(dead) <= set(removed)  # (plus those of any other dead run)
            assert with_prefix(dead_prefix) == []
            assert len(with_prefix(live.prefix)) == 2
            assert foreign in namespaces() and foreign not in removed
    finally:
        run(["ip", "netns", "delete", foreign])
