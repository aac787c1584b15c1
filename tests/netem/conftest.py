"""Fixtures of the swarm.netem tests: one shared 3-node network, and a check that nothing is left behind."""

from __future__ import annotations

import os
from collections.abc import Iterator

import pytest

from swarm.netem import SwarmNetwork, remove_leftovers
from swarm.netem.commands import namespaces
from tests.netem.measure import netem_problem


def own_namespaces() -> list[str]:
    """Namespaces created by swarm networks of this test process."""
    return [name for name in namespaces() if name.startswith("swn-") and f"-{os.getpid()}-" in name]


@pytest.fixture(scope="session", autouse=True)
def no_leftovers() -> Iterator[None]:
    if netem_problem() is not None:
        yield
        return
    remove_leftovers()  # of earlier, killed runs
    yield
    left = own_namespaces()
    assert not left, f"swarm.netem tests left namespaces behind: {left}"


@pytest.fixture(scope="module")
def net3() -> Iterator[SwarmNetwork]:
    with SwarmNetwork(nodes=3) as net:
        yield net


@pytest.fixture
def net(net3: SwarmNetwork) -> Iterator[SwarmNetwork]:
    """The shared 3-node network, clean at the start of each test."""
    net3.restore_all()
    yield net3
    net3.restore_all()
