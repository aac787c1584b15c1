"""Convergence after a heal counts the members that still sync: landed ones while they linger, not ones gone."""

from __future__ import annotations

import time

from swarm.bus.phase import Phase
from swarm.mission.files import ObserverStatus
from swarm.mission.links import HealWatch, LinkController
from swarm.netem.scenario import Scenario
from swarm.patches.digest import PatchDigest
from swarm.patches.patch import PatchId
from tests.file_models import observer_status


def _observer(agents: dict[int, tuple[Phase, list[int], float]]) -> ObserverStatus:
    """agents: id -> (phase, the seqs it holds of producer 1, seconds since it was last heard)."""
    now = time.time()
    return observer_status(
        agents={
            str(k): {
                "heartbeats": 1,
                "alive": True,
                "phase": phase,
                "last_heard": now - age,
                "holdings": PatchDigest.of(PatchId(1, 1, s) for s in seqs).to_wire(),
            }
            for k, (phase, seqs, age) in agents.items()
        }
    )


def _watching(target: list[int]) -> LinkController:
    links = LinkController(net=None, scenario=Scenario(name="heal"), drones=3)  # type: ignore[arg-type]
    watch = HealWatch(10.0, [1, 2, 3], {str(PatchId(1, 1, s)) for s in target})
    links.heals.append(watch)
    links._pending.append(watch)
    return links


def test_landed_members_that_still_linger_must_hold_everything_and_are_then_converged() -> None:
    links = _watching([0, 1, 2])
    links._follow_heals(
        12.0,
        _observer(
            {1: (Phase.LANDED, [0, 1, 2], 0.1), 2: (Phase.LANDED, [0, 1], 0.1), 3: (Phase.FLYING, [0, 1, 2], 0.1)}
        ),
    )
    assert links.heals[0].s is None  # agent 2 landed but lingers, and still lacks a patch
    links._follow_heals(
        13.5,
        _observer(
            {1: (Phase.LANDED, [0, 1, 2], 0.1), 2: (Phase.LANDED, [0, 1, 2], 0.1), 3: (Phase.LANDED, [0, 1, 2], 0.1)}
        ),
    )
    assert links.heals[0].s == 3.5


def test_a_member_that_left_no_longer_counts() -> None:
    links = _watching([0, 1])
    links._follow_heals(
        11.0, _observer({1: (Phase.LANDED, [0, 1], 0.1), 2: (Phase.LANDED, [0], 30.0), 3: (Phase.FLYING, [0, 1], 0.1)})
    )
    assert links.heals[0].s == 1.0
