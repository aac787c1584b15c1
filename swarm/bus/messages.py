"""Bus-level messages (presence and heartbeats), and field types shared by every message module."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, StringConstraints

from swarm.bus.codec import WireMessage
from swarm.bus.holdings import EMPTY_DIGEST, DigestWire
from swarm.bus.keys import MAX_AGENT_ID, MIN_AGENT_ID
from swarm.bus.phase import Phase
from swarm.config import Vec3

AgentId = Annotated[int, Field(ge=MIN_AGENT_ID, le=MAX_AGENT_ID)]
Counter = Annotated[int, Field(ge=0, le=2**63 - 1)]
# Floats, Vec3's too, are finite by WireMessage's config; these only name and bound them.
# Printable ASCII only: these end up in logs and reports.
ShortText = Annotated[str, StringConstraints(max_length=32, pattern=r"^[\x20-\x7e]*$")]

Role = Literal["leader", "explorer"]


class AgentState(WireMessage):
    """An agent's heartbeat: who it is, where it is, what it does, whom it follows and which patches it holds."""

    KIND = "state"

    id: AgentId
    epoch: Counter = Field(description="changes each time the agent process restarts")
    seq: Counter = Field(description="heartbeat number within the epoch")
    t: float = Field(ge=0.0, description="sender wall clock, seconds since the Unix epoch")
    position: Vec3 = Field(description="world frame (z up), metres")
    velocity: Vec3 = Field(description="world frame, m/s")
    heading_to: Vec3 | None = Field(
        default=None, description="the end of the straight segment the drone is flying, if any (for separation)"
    )
    yaw_deg: float = Field(ge=-360.0, le=360.0)
    flight_mode: ShortText = Field(description="autopilot flight mode, e.g. OFFBOARD")
    phase: Phase = Field(description="what the agent is doing (swarm.bus.phase); an unknown one is malformed")
    role: Role
    leader: AgentId
    finished: bool = Field(
        default=False, description="flight over and its last patch sealed: its own patches are all in holdings"
    )
    holdings: DigestWire = Field(
        default=EMPTY_DIGEST, description="every patch id the agent holds, own and received (ranges of seq)"
    )
