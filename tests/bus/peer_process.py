"""A bus peer in its own OS process, for the cross-process tests.

Run as ``python -m tests.bus.peer_process --mission M --id N --connect tcp/127.0.0.1:P [--connect ...]
[--listen tcp/127.0.0.1:Q]``. It declares its
liveliness token, publishes `make_state(id, seq)` at 20 Hz, and prints one JSON line per event on stdout:
{"event": "ready"} once set up, {"event": "state", "key": ..., "msg": {...}} for each heartbeat of another id.
With --repair-routes it also watches liveliness and, as an agent does, re-declares its subscriptions when a
peer's token is alive but its heartbeats are not arriving ({"event": "routes_refreshed", "deaf_to": [...]}).
SIGTERM closes the bus and exits 0.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import signal
import sys
import time

from swarm.agent.main import DEAF_AFTER_S, ROUTE_REFRESH_GAP_S
from swarm.bus.bridge import AsyncBus
from swarm.bus.messages import AgentState
from swarm.roles.membership import PeerTable
from tests.bus.helpers import make_state, open_connecting_bus


def emit(event: dict) -> None:
    sys.stdout.write(json.dumps(event) + "\n")
    sys.stdout.flush()


async def run(mission: str, agent_id: int, connect: list[str], listen: str, repair_routes: bool) -> None:
    stop = asyncio.Event()
    asyncio.get_running_loop().add_signal_handler(signal.SIGTERM, stop.set)
    bus: AsyncBus = await open_connecting_bus(mission, connect, listen=listen)
    try:

        def on_state(key: str, msg: AgentState) -> None:
            if msg.id != agent_id:
                emit({"event": "state", "key": key, "msg": msg.model_dump(mode="json")})

        peers = PeerTable(agent_id)
        bus.subscribe(bus.keys.all_states, AgentState, on_state)
        bus.subscribe(bus.keys.all_states, AgentState, lambda key, msg: peers.heard(msg.id, msg.position, msg.phase, 0))
        if repair_routes:
            bus.watch_liveliness(
                bus.keys.all_alive,
                lambda key: peers.token_appeared(bus.keys.agent_id_of(key) or 0),
                lambda key: peers.token_vanished(bus.keys.agent_id_of(key) or 0),
            )
        bus.declare_token(bus.keys.alive(agent_id))
        refreshed_at = 0.0
        emit({"event": "ready"})
        seq = 0
        while not stop.is_set():
            bus.publish(bus.keys.state(agent_id), make_state(agent_id, seq))
            seq += 1
            deaf = peers.deaf(DEAF_AFTER_S) if repair_routes else []
            if deaf and time.monotonic() - refreshed_at >= ROUTE_REFRESH_GAP_S:
                refreshed_at = time.monotonic()
                bus.refresh_routes()
                emit({"event": "routes_refreshed", "deaf_to": deaf})
            try:
                await asyncio.wait_for(stop.wait(), 0.05)
            except TimeoutError:
                pass
    finally:
        await bus.close()


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--mission", required=True)
    parser.add_argument("--id", type=int, required=True)
    parser.add_argument("--connect", action="append", required=True)
    parser.add_argument("--listen", default="tcp/127.0.0.1:0")
    parser.add_argument("--repair-routes", action="store_true")
    args = parser.parse_args()
    asyncio.run(run(args.mission, args.id, args.connect, args.listen, args.repair_routes))


if __name__ == "__main__":
    main()
