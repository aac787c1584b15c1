"""Collision events: vehicle spheres against the world mesh and against each other.

An event is a rising edge (a vehicle entering contact with the world, a pair entering contact), not a step in
contact. Contact ends only once the gap exceeds a small hysteresis, so skimming along a wall is one event.
Vehicles are not stopped: the simulator reports collisions, it does not crash anyone.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from swarm.sim.worlds import World

GROUND_GAP_M = 0.02  # the sphere's lowest point sits this far above the feet: standing is not a collision
HYSTERESIS_M = 0.02
MAX_EVENTS_KEPT = 1000


@dataclass
class CollisionEvent:
    t: float
    kind: str  # "world" or "drone"
    vehicles: list[int]
    position: list[float]

    def to_json(self) -> dict:
        return {"t": round(self.t, 3), "kind": self.kind, "vehicles": self.vehicles,
                "position": [round(c, 3) for c in self.position]}


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

    def update(self, t: float, positions: np.ndarray, airborne: np.ndarray) -> list[CollisionEvent]:
        """Check one physics step; positions (N,3) are the vehicles' feet, in the order of `vehicle_ids`."""
        positions = np.asarray(positions, dtype=np.float64)
        centres = positions + self._offset
        new: list[CollisionEvent] = []

        gap = np.full(len(self.ids), np.inf)
        moved = np.linalg.norm(centres - self._gap_origin, axis=1)
        lower_bound = self._gap - moved
        query = airborne & (lower_bound <= HYSTERESIS_M)
        if query.any():
            self._gap[query] = self.world.distance(centres[query]) - self.radius  # one batched query
            self._gap_origin[query] = centres[query]
            gap[query] = self._gap[query]
        skipped = airborne & ~query
        gap[skipped] = lower_bound[skipped]
        contact = np.where(self._in_world_contact, gap <= HYSTERESIS_M, gap < 0.0)
        for i in np.flatnonzero(contact & ~self._in_world_contact):
            new.append(CollisionEvent(t, "world", [self.ids[i]], positions[i].tolist()))
        self._in_world_contact = contact

        pair_gap = np.linalg.norm(centres[:, None, :] - centres[None, :, :], axis=2) - 2 * self.radius
        either_airborne = airborne[:, None] | airborne[None, :]
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
