"""Which drones an agent keeps clear of (`Agent._neighbours`, one function; peers are fed by hand, nothing runs)."""

from __future__ import annotations

import time

import pytest

from swarm.agent.main import Agent
from swarm.bus.phase import Phase
from swarm.config import SwarmConfig


def _agent() -> Agent:
    config = SwarmConfig()
    config.agent.id = 2
    return Agent(config)


def test_fresh_peers_are_extrapolated_stale_ones_hover_where_last_heard_and_landed_ones_do_not_count() -> None:
    agent = _agent()
    agent.peers.heard(1, (0.0, 0.0, 1.5), Phase.FLYING, 1, velocity=(1.0, 0.0, 0.0))
    agent.peers.heard(3, (4.0, 0.0, 1.5), Phase.FLYING, 1, velocity=(0.0, 2.0, 0.0))
    agent.peers.heard(4, (8.0, 0.0, 0.0), Phase.LANDED, 1)
    now = time.monotonic()
    agent.peers.peers[1].last_heard = now - 0.5
    agent.peers.peers[3].last_heard = now - 3.0  # heartbeats stopped (agent frozen or killed, token not yet gone)
    found = {n.id: n for n in agent._neighbours()}
    assert set(found) == {1, 3}
    assert found[1].position[0] == pytest.approx(0.5, abs=0.05)
    assert found[3].position == (4.0, 0.0, 1.5) and found[3].velocity == (0.0, 0.0, 0.0)
    assert found[3].silent and not found[1].silent


def test_a_peer_lost_in_the_air_stays_a_neighbour_until_it_is_back() -> None:
    agent = _agent()
    agent.lost_in_air[3] = (3.5, 3.0, 1.36)
    (lost,) = agent._neighbours()
    assert (lost.id, lost.position, lost.velocity, lost.silent) == (3, (3.5, 3.0, 1.36), (0.0, 0.0, 0.0), True)
    agent.peers.heard(3, (3.5, 3.0, 0.0), Phase.LANDED, 2)  # back (restarted, on the ground): its heartbeat rules
    assert agent._neighbours() == []


def test_a_peer_in_failsafe_is_a_silent_obstacle_where_it_last_reported() -> None:
    agent = _agent()
    agent.peers.heard(1, (2.0, 0.0, 0.4), Phase.FAILSAFE, 1, velocity=(0.0, 0.0, -0.5))  # heartbeats still come
    (peer,) = agent._neighbours()
    assert (peer.id, peer.position, peer.velocity, peer.silent) == (1, (2.0, 0.0, 0.4), (0.0, 0.0, 0.0), True)
