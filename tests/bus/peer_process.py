"""A bus peer in its own OS process, for the cross-process tests.

Run as ``python -m tests.bus.peer_process --mission M --id N --connect tcp/127.0.0.1:P``. It declares its
liveliness token, publishes `make_state(id, seq)` at 20 Hz, and prints one JSON line per event on stdout:
{"event": "ready"} once set up, {"event": "state", "key": ..., "msg": {...}} for each heartbeat of another id.
SIGTERM closes the bus and exits 0.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import signal
import sys

from swarm.bus.bridge import AsyncBus
from swarm.bus.messages import AgentState
from tests.bus.helpers import make_state, open_connecting_bus


def emit(event: dict) -> None:
    sys.stdout.write(json.dumps(event) + "\n")
    sys.stdout.flush()


async def run(mission: str, agent_id: int, endpoint: str) -> None:
    stop = asyncio.Event()
    asyncio.get_running_loop().add_signal_handler(signal.SIGTERM, stop.set)
    bus: AsyncBus = await open_connecting_bus(mission, endpoint)
    try:

        def on_state(key: str, msg: AgentState) -> None:
            if msg.id != agent_id:
                emit({"event": "state", "key": key, "msg": msg.model_dump(mode="json")})

        bus.subscribe(bus.keys.all_states, AgentState, on_state)
        bus.declare_token(bus.keys.alive(agent_id))
        emit({"event": "ready"})
        seq = 0
        while not stop.is_set():
            bus.publish(bus.keys.state(agent_id), make_state(agent_id, seq))
            seq += 1
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
    parser.add_argument("--connect", required=True)
    args = parser.parse_args()
    asyncio.run(run(args.mission, args.id, args.connect))


if __name__ == "__main__":
    main()
