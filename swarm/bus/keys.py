"""Every Zenoh key expression of a mission, in one place.

All keys live under ``swarm/<mission>/`` so that several missions can share one Zenoh network without
seeing each other's traffic. Layout (``<id>`` is a drone id, 1..250, in plain decimal):

===============================  ====================  ==========================================
key                              Zenoh entity          carries
===============================  ====================  ==========================================
swarm/<m>/agent/<id>/state       publisher (periodic)  `AgentState` heartbeat: pose, role, leader
swarm/<m>/alive/<id>             liveliness token      presence; vanishes when the lease expires
swarm/<m>/agent/<id>/patch       publisher (on seal)   a sealed patch (chunks) pushed to peers
swarm/<m>/agent/<id>/store       queryable             serves the patches this agent holds
                                                       (`AsyncBus.declare_queryable` / `get`)
swarm/<m>/agent/<id>/frontiers   publisher (per loop)  `FrontierReport`: an explorer's candidate targets
swarm/<m>/agent/<id>/targets     publisher (leader)    `TargetAssignment`: the leader's targets for its
                                                       cluster, or "done"
===============================  ====================  ==========================================

Per-agent data sits under ``agent/<id>/`` so one wildcard (``agent/*/<topic>``) subscribes to everyone's.
"""

from __future__ import annotations

import re

MIN_AGENT_ID = 1
MAX_AGENT_ID = 250

_MISSION_RE = re.compile(r"^[A-Za-z0-9_-]{1,64}$")
# Canonical decimal only (no sign, no leading zero), so each id has exactly one key.
_ID_RE = r"([1-9][0-9]{0,2})"


def check_agent_id(agent_id: int) -> int:
    """Return `agent_id` if it is a valid drone id, else raise ValueError."""
    if isinstance(agent_id, bool) or not isinstance(agent_id, int):
        raise ValueError(f"agent id must be an int, got {agent_id!r}")
    if not MIN_AGENT_ID <= agent_id <= MAX_AGENT_ID:
        raise ValueError(f"agent id must be in {MIN_AGENT_ID}..{MAX_AGENT_ID}, got {agent_id}")
    return agent_id


class Keys:
    """The key expressions of one mission."""

    def __init__(self, mission: str) -> None:
        if not isinstance(mission, str) or not _MISSION_RE.match(mission):
            raise ValueError(f"mission name {mission!r} must be 1-64 characters of letters, digits, '_' or '-'")
        self.mission = mission
        self.root = f"swarm/{mission}"
        self.all_states = f"{self.root}/agent/*/state"
        self.all_alive = f"{self.root}/alive/*"
        self.all_patches = f"{self.root}/agent/*/patch"
        self.all_stores = f"{self.root}/agent/*/store"
        self.all_frontiers = f"{self.root}/agent/*/frontiers"
        self.all_targets = f"{self.root}/agent/*/targets"
        root = re.escape(self.root)
        self._id_patterns = (
            re.compile(rf"^{root}/agent/{_ID_RE}/(?:state|patch|store|frontiers|targets)$"),
            re.compile(rf"^{root}/alive/{_ID_RE}$"),
        )

    def state(self, agent_id: int) -> str:
        return f"{self.root}/agent/{check_agent_id(agent_id)}/state"

    def alive(self, agent_id: int) -> str:
        return f"{self.root}/alive/{check_agent_id(agent_id)}"

    def patch(self, agent_id: int) -> str:
        """Where drone `agent_id` pushes the patches it seals."""
        return f"{self.root}/agent/{check_agent_id(agent_id)}/patch"

    def store(self, agent_id: int) -> str:
        """The queryable of drone `agent_id` that serves the patches it holds."""
        return f"{self.root}/agent/{check_agent_id(agent_id)}/store"

    def frontiers(self, agent_id: int) -> str:
        return f"{self.root}/agent/{check_agent_id(agent_id)}/frontiers"

    def targets(self, agent_id: int) -> str:
        return f"{self.root}/agent/{check_agent_id(agent_id)}/targets"

    def agent_id_of(self, key: str) -> int | None:
        """The drone id in a per-agent key (state, patch, store) or liveliness key of this mission; None for
        any other or malformed key."""
        if not isinstance(key, str):
            return None
        for pattern in self._id_patterns:
            match = pattern.match(key)
            if match:
                agent_id = int(match.group(1))
                return agent_id if MIN_AGENT_ID <= agent_id <= MAX_AGENT_ID else None
        return None

    def __repr__(self) -> str:
        return f"Keys({self.mission!r})"
