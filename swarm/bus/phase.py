"""What a drone's process is doing, as its heartbeat (`AgentState.phase`) says it: the one spelling of a phase.

The wire carries the value string ("flying"); a received heartbeat whose phase is not one of these is malformed
and dropped like any invalid message (`swarm.bus.codec`). Which phase may follow which in a flight is the
agent's business (`swarm.agent.lifecycle`); what the sets below mean to the rest of the swarm is said here, so
membership, the observer and the agent read a heartbeat the same way.
"""

from __future__ import annotations

from enum import StrEnum


class Phase(StrEnum):
    CONNECTING = "connecting"  # no autopilot telemetry yet: the heartbeat's position is (0, 0, 0)
    READY = "ready"
    TAKEOFF = "takeoff"
    FLYING = "flying"
    HOVERING = "hovering"
    RETURNING = "returning"  # a low battery ended its mission early: flying home, out of exploration
    LANDING = "landing"
    LANDED = "landed"  # also while the landed agent lingers on the bus to finish the map
    FAILSAFE = "failsafe"  # telemetry lost in the air: the autopilot was told to land where it was
    FAILED = "failed"
    MAPPING = "mapping"  # a map node (`swarm.mission.mapnode`): never flies, a cluster member to the end


# Out of exploration for good: in no cluster (swarm.roles.membership). A returning drone is one: its leader must
# not wait for it or give it targets, and, as the lowest id, it must not stay the leader of drones still exploring.
RETIRED_PHASES = frozenset({Phase.RETURNING, Phase.LANDED, Phase.FAILED, Phase.FAILSAFE})
# The drone may be in the air, or (failsafe) came down where it was rather than at its home: kept clear of.
AIRBORNE_PHASES = frozenset(
    {Phase.TAKEOFF, Phase.FLYING, Phase.HOVERING, Phase.RETURNING, Phase.LANDING, Phase.FAILSAFE}
)
