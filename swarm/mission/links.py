"""Drive a link scenario during a netns mission, and measure what it did: impairments, partitions, heals.

`swarm run --network netns --links FILE` holds one `LinkController`; the run's supervision loop calls `tick()`
about four times a second with the mission clock, the simulator's truth (positions, who is airborne) and the
observer's snapshot (each agent's phase and patch holdings, from its heartbeats).

- Scenario time starts at take-off: the first tick at which any vehicle has left the ground.
- Scripted events (`swarm.netem.scenario.timeline`) set each pair's profile; with a `[radio]` model the
  distance between the two drones (simulator truth, re-evaluated every second, loss rounded to whole percent so
  the rules are not reloaded for centimetres) is combined in. Only changes reach the network, in one rule load.
- `impairments`: every change of a pair's profile, with the mission time, the scenario time and the backend.
- `partitions`: the intervals during which the radio graph (pairs that are not cut) had more than one
  connected component, with the components. This is the network's truth; the swarm's own view of its clusters
  is the observer's leader timeline.
- `convergence_after_heal_s`: per heal (a cut pair joined again), the members of the joined component that are
  still flying, and the seconds until every one of them that still syncs (flying, or landed and lingering: its
  heartbeats still heard) holds every patch that any of them held at the heal.
  Holdings come from the heartbeats via the observer, sampled every half second, so the figure is +-0.5 s.
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.sparse.csgraph import connected_components

from swarm.mission.observer import FRESH_S
from swarm.netem.network import SwarmNetwork
from swarm.netem.profile import LinkProfile
from swarm.netem.scenario import CLEAN, Pair, Profiles, Scenario, combine, radio_profile, timeline
from swarm.patches.digest import PatchDigest
from swarm.roles.membership import RETIRED_PHASES

RADIO_PERIOD_S = 1.0
BACKEND = "nftables (bridge table in the hub: random drop, cut = drop all)"


def components(drones: int, profiles: Mapping[Pair, LinkProfile]) -> list[list[int]]:
    """Connected components of the drones 1..`drones` over the pairs that are not cut, each sorted, in order."""
    linked = np.zeros((drones, drones), dtype=bool)
    for a, b in itertools.combinations(range(1, drones + 1), 2):
        linked[a - 1, b - 1] = not profiles.get((a, b), CLEAN).cut
    _, labels = connected_components(linked, directed=False)
    groups: dict[int, list[int]] = {}
    for k, label in enumerate(labels, start=1):
        groups.setdefault(int(label), []).append(k)
    return sorted(groups.values())


def holdings_of(observer: Mapping[str, Any] | None) -> dict[int, set[str]]:
    """Each agent's patch ids from the observer snapshot (agents whose holdings cannot be read are left out)."""
    held: dict[int, set[str]] = {}
    for key, entry in ((observer or {}).get("agents") or {}).items():
        wire = entry.get("holdings")
        if wire is None:
            continue
        try:
            held[int(key)] = {str(pid) for pid in PatchDigest.from_wire(wire).ids()}
        except (ValueError, TypeError, KeyError):
            continue
    return held


def syncing_agents(observer: Mapping[str, Any] | None, now_wall: float, fresh_s: float = FRESH_S) -> set[int]:
    """Agents heard within fresh_s (observer wall-clock `last_heard`), in the air or landed and lingering: a
    landed agent keeps serving and pulling patches until it leaves."""
    agents = (observer or {}).get("agents") or {}
    return {int(k) for k, e in agents.items() if now_wall - float(e.get("last_heard", -math.inf)) < fresh_s}


def active_agents(observer: Mapping[str, Any] | None) -> set[int]:
    """Agents that have reported and are not on the ground for good."""
    agents = (observer or {}).get("agents") or {}
    return {int(k) for k, e in agents.items() if "phase" in e and e.get("phase") not in RETIRED_PHASES}


@dataclass
class HealWatch:
    heal_t: float
    members: list[int]
    target: set[str]
    s: float | None = None

    def as_dict(self) -> dict[str, Any]:
        return {
            "heal_t": round(self.heal_t, 2),
            "members": self.members,
            "patches": len(self.target),
            "s": None if self.s is None else round(self.s, 2),
        }


def any_vehicle_airborne(sim: Mapping[str, Any] | None) -> bool:
    """Whether the simulator's status shows a vehicle off the ground: time 0 of scenarios and faults."""
    return any(v.get("landed_state") not in (None, "on_ground") for v in (sim or {}).get("vehicles") or [])


@dataclass
class LinkController:
    net: SwarmNetwork
    scenario: Scenario
    drones: int
    takeoff_t: float | None = None
    impairments: list[dict[str, Any]] = field(default_factory=list)
    partitions: list[dict[str, Any]] = field(default_factory=list)
    heals: list[HealWatch] = field(default_factory=list)

    def __post_init__(self) -> None:
        self._steps = timeline(self.scenario, self.drones)
        self._next_step = 0
        self._scripted: Profiles = {pair: CLEAN for pair in itertools.combinations(range(1, self.drones + 1), 2)}
        self._radio: Profiles = dict.fromkeys(self._scripted, CLEAN)
        self._in_force: Profiles = dict(self._radio)
        self._last_radio_t = -math.inf
        self._pending: list[HealWatch] = []

    def tick(self, t: float, sim: Mapping[str, Any] | None, observer: Mapping[str, Any] | None) -> None:
        """Apply whatever is due at mission time t; follow heals. Cheap when nothing changes."""
        vehicles = (sim or {}).get("vehicles") or []
        if self.takeoff_t is None:
            if not any_vehicle_airborne(sim):
                return
            self.takeoff_t = t
            self._open_partition(t)
        scenario_t = t - self.takeoff_t
        while self._next_step < len(self._steps) and self._steps[self._next_step][0] <= scenario_t:
            self._scripted = self._steps[self._next_step][1]
            self._next_step += 1
        if self.scenario.radio is not None and t - self._last_radio_t >= RADIO_PERIOD_S:
            self._radio = self._radio_profiles(vehicles)
            self._last_radio_t = t
        wanted = {pair: combine(self._scripted[pair], self._radio[pair]) for pair in self._scripted}
        if wanted != self._in_force:
            self._apply(t, scenario_t, wanted, observer)
        self._follow_heals(t, observer)

    def finish(self, t: float) -> None:
        """Close the open partition interval (call once at the end of the mission)."""
        if self.partitions and self.partitions[-1]["end"] is None:
            self.partitions[-1]["end"] = round(t, 2)
        self.partitions = [p for p in self.partitions if len(p["components"]) > 1]

    def report(self) -> dict[str, Any]:
        return {
            "impairments": self.impairments,
            "partitions": self.partitions,
            "convergence_after_heal_s": [h.as_dict() for h in self.heals],
            "scenario": {"name": self.scenario.name, "takeoff_t": self.takeoff_t, "backend": BACKEND},
        }

    # ----- internals -----

    def _radio_profiles(self, vehicles: Sequence[Mapping[str, Any]]) -> Profiles:
        assert self.scenario.radio is not None
        positions = {int(v["id"]): v["position"] for v in vehicles if v.get("position") is not None}
        profiles: Profiles = {}
        for a, b in self._scripted:
            if a in positions and b in positions:
                profile = radio_profile(self.scenario.radio, math.dist(positions[a], positions[b]))
                profiles[(a, b)] = profile.model_copy(update={"loss": round(profile.loss, 2)})
            else:
                profiles[(a, b)] = self._radio.get((a, b), CLEAN)
        return profiles

    def _apply(self, t: float, scenario_t: float, wanted: Profiles, observer: Mapping[str, Any] | None) -> None:
        before = self._in_force
        self.net.set_pairs(wanted)
        self._in_force = wanted
        for pair in sorted(wanted):
            if wanted[pair] != before[pair]:
                self.impairments.append(
                    {
                        "t": round(t, 2),
                        "at": round(scenario_t, 2),
                        "link": f"{pair[0]}-{pair[1]}",
                        "profile": wanted[pair].describe(),
                        "backend": "nftables",
                    }
                )
        healed = [pair for pair in wanted if before[pair].cut and not wanted[pair].cut]
        if components(self.drones, before) != components(self.drones, wanted):
            self._open_partition(t)
        if healed:
            self._watch_heal(t, healed, observer)

    def _open_partition(self, t: float) -> None:
        if self.partitions and self.partitions[-1]["end"] is None:
            self.partitions[-1]["end"] = round(t, 2)
        split = components(self.drones, self._in_force)
        self.partitions.append({"start": round(t, 2), "end": None, "components": split})

    def _watch_heal(self, t: float, healed: list[Pair], observer: Mapping[str, Any] | None) -> None:
        joined = {k for pair in healed for k in pair}
        component = next(c for c in components(self.drones, self._in_force) if joined & set(c))
        active = active_agents(observer)
        members = [k for k in component if k in active]
        held = holdings_of(observer)
        target = set().union(*(held.get(k, set()) for k in members)) if members else set()
        watch = HealWatch(t, members, target)
        self.heals.append(watch)
        if len(members) < 2:
            watch.s = 0.0  # nobody left to converge with
        else:
            self._pending.append(watch)

    def _follow_heals(self, t: float, observer: Mapping[str, Any] | None) -> None:
        if not self._pending:
            return
        held = holdings_of(observer)
        # one that landed meanwhile counts while it lingers (still syncing); one that left no longer does
        syncing = active_agents(observer) | syncing_agents(observer, time.time())
        for watch in list(self._pending):
            counted = [k for k in watch.members if k in syncing]
            if counted and all(watch.target <= held.get(k, set()) for k in counted):
                watch.s = max(0.0, t - watch.heal_t)
                self._pending.remove(watch)
