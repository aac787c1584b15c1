"""Zenoh: session configuration, key expressions, message codec and the asyncio bridge.

The bus moves validated messages; it knows nothing about mapping or flight.
"""

from swarm.bus.bridge import AsyncBus
from swarm.bus.codec import SCHEMA_VERSION, ArraySpec, DecodeError, NDArray, WireMessage, decode, encode
from swarm.bus.counters import TrafficCounters
from swarm.bus.keys import Keys
from swarm.bus.messages import AgentState
from swarm.bus.session import open_session, zenoh_config

__all__ = [
    "SCHEMA_VERSION",
    "AgentState",
    "ArraySpec",
    "AsyncBus",
    "DecodeError",
    "Keys",
    "NDArray",
    "TrafficCounters",
    "WireMessage",
    "decode",
    "encode",
    "open_session",
    "zenoh_config",
]
