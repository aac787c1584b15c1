"""The exploration messages: explorers report frontier candidates to their leader, the leader assigns targets.

Mahdoui's stage 2 and stage 3 (`swarm.roles.assignment`). Both are reliable (drop when congested) and sent once per
loop; a lost one is replaced by the next loop's. Everything is validated as hostile input: arrays have fixed
shapes, finite values and bounded lengths, and an assignment names each drone at most once.
"""

from __future__ import annotations

from typing import Annotated

import numpy as np
from pydantic import Field, model_validator

from swarm.bus.codec import ArraySpec, WireMessage
from swarm.bus.messages import AgentId, Counter
from swarm.config import Vec3

MAX_CANDIDATES = 512
MAX_VISITED = 1024
MAX_MEMBERS = 64

_Points = Annotated[np.ndarray, ArraySpec(max_bytes=MAX_VISITED * 3 * 4, dtypes=frozenset({"float32"}), ndim=2)]
_Gains = Annotated[np.ndarray, ArraySpec(max_bytes=MAX_CANDIDATES * 4, dtypes=frozenset({"float32"}), ndim=1)]

EMPTY_POINTS = np.zeros((0, 3), dtype=np.float32)
EMPTY_GAINS = np.zeros(0, dtype=np.float32)


def _check_points(name: str, points: np.ndarray, limit: int) -> None:
    if points.shape[1:] != (3,):
        raise ValueError(f"{name} must have shape (N, 3), got {points.shape}")
    if len(points) > limit:
        raise ValueError(f"{name} has {len(points)} rows, at most {limit} allowed")
    if not np.isfinite(points).all():
        raise ValueError(f"{name} holds a non-finite value")


class FrontierReport(WireMessage):
    """An agent's candidate targets this loop (each a viewpoint, the frontier point it looks at, and the
    unknown volume around that point), the viewpoints it has already looked from and what it looked at, and
    whether it has just reached its target (which makes the leader assign again without waiting for the loop)."""

    KIND = "frontiers"

    id: AgentId
    epoch: Counter
    seq: Counter
    position: Vec3
    viewpoints: _Points = EMPTY_POINTS
    points: _Points = EMPTY_POINTS
    gains: _Gains = EMPTY_GAINS
    visited: _Points = EMPTY_POINTS
    looked_at: _Points = EMPTY_POINTS  # the point each visited viewpoint looked at (empty: every way)
    unreachable: _Points = EMPTY_POINTS  # viewpoints it recently could not plan a path to: not to be assigned to it
    arrived: bool = False
    in_pocket: bool = False  # its map shuts it in where it is: its empty candidate list says nothing yet
    home: Vec3 | None = None  # where it flies when the cluster is done (None: it lands where it is); tours end there

    @model_validator(mode="after")
    def _shapes(self) -> FrontierReport:
        _check_points("viewpoints", self.viewpoints, MAX_CANDIDATES)
        _check_points("points", self.points, MAX_CANDIDATES)
        _check_points("visited", self.visited, MAX_VISITED)
        _check_points("looked_at", self.looked_at, MAX_VISITED)
        _check_points("unreachable", self.unreachable, MAX_VISITED)
        if len(self.looked_at) not in (0, len(self.visited)):
            raise ValueError("looked_at must be empty or as long as visited")
        if not (len(self.viewpoints) == len(self.points) == len(self.gains)):
            raise ValueError("viewpoints, points and gains must have the same length")
        if not (np.isfinite(self.gains).all() and (self.gains >= 0).all()):
            raise ValueError("gains must be finite and non-negative")
        return self


class TargetAssignment(WireMessage):
    """A leader's decision for its cluster: one target (viewpoint and frontier point) per drone, or `done`:
    no candidate is left, the cluster's part of the mission is over (Mahdoui's acknowledgement)."""

    KIND = "targets"

    leader: AgentId
    epoch: Counter
    round: Counter
    members: Annotated[list[AgentId], Field(max_length=MAX_MEMBERS)]
    done: bool = False
    drones: Annotated[list[AgentId], Field(max_length=MAX_MEMBERS)] = []
    viewpoints: _Points = EMPTY_POINTS
    points: _Points = EMPTY_POINTS

    @model_validator(mode="after")
    def _consistent(self) -> TargetAssignment:
        _check_points("viewpoints", self.viewpoints, MAX_MEMBERS)
        _check_points("points", self.points, MAX_MEMBERS)
        if not (len(self.drones) == len(self.viewpoints) == len(self.points)):
            raise ValueError("drones, viewpoints and points must have the same length")
        if len(set(self.drones)) != len(self.drones) or not set(self.drones) <= set(self.members):
            raise ValueError("each drone is assigned at most once, and only members are assigned")
        if self.leader not in self.members:
            raise ValueError("the leader is a member of its cluster")
        return self

    def target_of(self, drone: int) -> tuple[Vec3, Vec3] | None:
        """(viewpoint, frontier point) assigned to `drone`, or None."""
        if drone not in self.drones:
            return None
        i = self.drones.index(drone)
        return _vec(self.viewpoints[i]), _vec(self.points[i])


def _vec(row: np.ndarray) -> Vec3:
    return float(row[0]), float(row[1]), float(row[2])


def as_points(points: list[Vec3] | np.ndarray) -> np.ndarray:
    """(N, 3) float32 for a message field."""
    return np.asarray(points, dtype=np.float32).reshape(-1, 3)
