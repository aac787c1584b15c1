"""Shared by the bus tests and their child processes."""

from __future__ import annotations

import asyncio
import socket
import time
from collections.abc import Callable
from typing import Any

from swarm.bus.bridge import AsyncBus
from swarm.bus.messages import AgentState
from swarm.bus.phase import Phase
from swarm.config import BusSettings
from swarm.errors import BusError

LEASE_MS = 1000


def make_state(agent_id: int, seq: int, epoch: int = 0) -> AgentState:
    """A deterministic heartbeat, so two processes can agree on what was sent."""
    return AgentState(
        id=agent_id,
        epoch=epoch,
        seq=seq,
        t=1_700_000_000.0 + seq * 0.05,
        position=(1.5 * agent_id, -0.25 * seq, 1.5),
        velocity=(0.1, -0.2, 0.0),
        yaw_deg=-90.0 + seq % 180,
        flight_mode="OFFBOARD",
        phase=Phase.FLYING,
        role="leader" if agent_id == 1 else "explorer",
        leader=1,
    )


def free_tcp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


async def open_listening_bus(mission: str, attempts: int = 5, **settings: Any) -> tuple[AsyncBus, str]:
    """A bus listening on a free loopback port; retried because other test runs share this machine."""
    for _ in range(attempts):
        endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
        try:
            bus = await AsyncBus.open(BusSettings(listen=[endpoint], lease_ms=LEASE_MS, **settings), mission)
            return bus, endpoint
        except BusError as exc:
            if "address already in use" not in str(exc):
                raise
    raise AssertionError(f"no free loopback port after {attempts} attempts")


async def open_connecting_bus(
    mission: str, endpoint: str | list[str], listen: str = "tcp/127.0.0.1:0", **settings: Any
) -> AsyncBus:
    """A bus dialing `endpoint` (or each of a list); by default it listens on a port nobody needs to know."""
    connect = [endpoint] if isinstance(endpoint, str) else endpoint
    bus = BusSettings(listen=[listen], connect=connect, lease_ms=LEASE_MS, **settings)
    return await AsyncBus.open(bus, mission)


async def wait_until(condition: Callable[[], bool], timeout_s: float, what: str, poll_s: float = 0.01) -> float:
    """Poll `condition` on the loop until it holds; return the time it took, fail after `timeout_s`."""
    start = time.monotonic()
    while not condition():
        if time.monotonic() - start > timeout_s:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
        await asyncio.sleep(poll_s)
    return time.monotonic() - start
