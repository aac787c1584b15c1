"""Collision events: vehicle spheres against the world mesh and against each other.

An event is a rising edge (a vehicle entering contact with the world, a pair entering contact), not a step in
contact. Contact ends only once the gap exceeds a small hysteresis, so skimming along a wall is one event.
Vehicles are not stopped: the simulator reports collisions, it does not crash anyone.

Near misses are measured too: each vehicle's smallest gap to the world while cruising (airborne and higher than
CRUISE_HEIGHT_M above home, so that taking off and landing, which graze the floor, do not count; exact once it is
under NEAR_GAP_M, above which the distance field is not queried every step), and to any other vehicle while
either is airborne.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from swarm.sim.worlds import World

GROUND_GAP_M = 0.02  # the sphere's lowest point sits this far above the feet: standing is not a collision
HYSTERESIS_M = 0.02
MAX_EVENTS_KEPT = 1000
NEAR_GAP_M = 0.15  # world gaps below this are measured every step (closest_world)
CRUISE_HEIGHT_M = 0.3  # closest_world counts above this height over home (the lowest planned flight is 0.6 m)


@dataclass
class CollisionEvent:
    t: float
    kind: str  # "world" or "drone"
    vehicles: list[int]
    position: list[float]

    def to_json(self) -> dict:
        return {
            "t": round(self.t, 3),
            "kind": self.kind,
            "vehicles": self.vehicles,
            "position": [round(c, 3) for c in self.position],
        }


class CollisionMonitor:
    def __init__(self, world: World, vehicle_ids: list[int], radius: float) -> None:
        self.world = world
        self.ids = list(vehicle_ids)
        self.radius = radius
        self.total = 0
        self.counts = {vid: 0 for vid in self.ids}
        self.events: deque[CollisionEvent] = deque(maxlen=MAX_EVENTS_KEPT)  # the most recent ones
        self._offset = np.array([0.0, 0.0, radius + GROUND_GAP_M])
        self._in_world_contact = np.zeros(len(self.ids), dtype=bool)
        # the world gap measured at _gap_origin: the distance field is 1-Lipschitz, so a vehicle that moved less
        # than that gap since cannot touch the world yet, and needs no query
        self._gap = np.full(len(self.ids), -np.inf)
        self._gap_origin = np.zeros((len(self.ids), 3))
        self._in_pair_contact = np.zeros((len(self.ids), len(self.ids)), dtype=bool)
        self._upper = np.triu(np.ones((len(self.ids), len(self.ids)), dtype=bool), k=1)
        self._closest_world = np.full(len(self.ids), np.inf)
        self._closest_world_at = np.zeros((len(self.ids), 3))
        self._closest_drone = np.full(len(self.ids), np.inf)

    def closest_world(self, vid: int) -> float | None:
        """The smallest gap (m) between vehicle `vid`'s sphere and the world while cruising; None when it never
        came within NEAR_GAP_M (negative: it was inside a surface)."""
        gap = self._closest_world[self.ids.index(vid)]
        return float(gap) if gap < NEAR_GAP_M else None

    def closest_world_at(self, vid: int) -> list[float] | None:
        """Where (the vehicle's feet) `closest_world` was measured."""
        i = self.ids.index(vid)
        return self._closest_world_at[i].tolist() if self._closest_world[i] < NEAR_GAP_M else None

    def closest_drone(self, vid: int) -> float | None:
        """The smallest gap (m) between vehicle `vid`'s sphere and another's while either was airborne."""
        gap = self._closest_drone[self.ids.index(vid)]
        return float(gap) if np.isfinite(gap) else None

    def update(
        self, t: float, positions: np.ndarray, airborne: np.ndarray, cruising: np.ndarray | None = None
    ) -> list[CollisionEvent]:
        """Check one physics step; positions (N,3) are the vehicles' feet, in the order of `vehicle_ids`;
        `cruising` (default: `airborne`) selects the vehicles whose world gap counts for closest_world."""
        positions = np.asarray(positions, dtype=np.float64)
        cruising = airborne if cruising is None else cruising & airborne
        centres = positions + self._offset
        new: list[CollisionEvent] = []

        gap = np.full(len(self.ids), np.inf)
        moved = np.linalg.norm(centres - self._gap_origin, axis=1)
        lower_bound = self._gap - moved
        query = airborne & (lower_bound <= NEAR_GAP_M)
        if query.any():
            self._gap[query] = self.world.distance(centres[query]) - self.radius  # one batched query
            self._gap_origin[query] = centres[query]
            gap[query] = self._gap[query]
        skipped = airborne & ~query
        gap[skipped] = lower_bound[skipped]
        closer = query & cruising & (gap < self._closest_world)
        self._closest_world[closer] = gap[closer]
        self._closest_world_at[closer] = positions[closer]
        contact = np.where(self._in_world_contact, gap <= HYSTERESIS_M, gap < 0.0)
        for i in np.flatnonzero(contact & ~self._in_world_contact):
            new.append(CollisionEvent(t, "world", [self.ids[i]], positions[i].tolist()))
        self._in_world_contact = contact

        pair_gap = np.linalg.norm(centres[:, None, :] - centres[None, :, :], axis=2) - 2 * self.radius
        either_airborne = airborne[:, None] | airborne[None, :]
        watched = np.where(either_airborne & ~np.eye(len(self.ids), dtype=bool), pair_gap, np.inf)
        if len(self.ids) > 1:
            np.minimum(self._closest_drone, watched.min(axis=1), out=self._closest_drone)
        touching = np.where(self._in_pair_contact, pair_gap <= HYSTERESIS_M, pair_gap < 0.0)
        touching &= either_airborne & self._upper
        for i, j in zip(*np.nonzero(touching & ~self._in_pair_contact)):
            middle = (positions[i] + positions[j]) / 2
            new.append(CollisionEvent(t, "drone", [self.ids[i], self.ids[j]], middle.tolist()))
        self._in_pair_contact = touching

        for event in new:
            self.total += 1
            self.events.append(event)
            for vid in event.vehicles:
                self.counts[vid] += 1
        return new
