"""Serving the store (issue 25): a query of 1.2 kB may ask for 64 patches, 4 MiB of replies. Per requester and
for all requesters together, queries and reply bytes are bounded by token buckets, and the chunks are built by
a function the bus runs on a worker thread. The bus is a stand-in (key names and counters); the clock is fake."""

from __future__ import annotations

import random
from types import SimpleNamespace

import pytest

from swarm.bus.codec import decode
from swarm.bus.counters import TrafficCounters
from swarm.bus.keys import Keys
from swarm.config import SyncSettings
from swarm.patches.patch import PatchId
from swarm.sync import service
from swarm.sync.chunks import PatchChunk, Reassembler
from swarm.sync.requests import request_parameters
from swarm.sync.service import STORE_KIND, PatchSync

PATCH_BYTES = 64 << 10
IDS = [PatchId(1, 1_795_340_000_000, seq) for seq in range(64)]  # an epoch is a start time in ms


class Clock:
    def __init__(self) -> None:
        self.now = 50.0

    def __call__(self) -> float:
        return self.now


async def _sink(data: bytes, pid: object) -> None:
    return None


def store(clock: Clock, **settings: float) -> PatchSync:
    """Agent 1 holding 64 patches of 64 kB (4 MiB)."""
    bus = SimpleNamespace(keys=Keys("serve"), counters=TrafficCounters())
    sync = PatchSync(bus, SyncSettings(**settings), 1, _sink, lambda: (0.0, 0.0, 0.0), 4 << 20, clock=clock)  # type: ignore[arg-type]
    rng = random.Random(0)
    for pid in IDS:
        sync.add_recovered(pid, rng.randbytes(PATCH_BYTES))
    return sync


def ask(sync: PatchSync, requester: int | None, ids: list[PatchId] = IDS) -> list[bytes] | None:
    params = dict(part.split("=", 1) for part in request_parameters(ids, requester or 1).split(";"))
    if requester is None:
        del params["from"]
    build = sync._serve(sync.keys.store(1), params)
    return None if build is None else build()


def served_bytes(replies: list[bytes] | None) -> int:
    return sum(len(decode(r, PatchChunk).data) for r in replies or [])


def test_the_review_query_is_1_2_kb_for_4_mib_of_replies_and_replies_are_exact_chunks() -> None:
    sync = store(Clock())
    selector = f"{sync.keys.store(1)}?{request_parameters(IDS, 2)}"
    replies = ask(sync, 2)
    assert 1200 <= len(selector.encode()) <= 1300
    assert served_bytes(replies) == 64 * PATCH_BYTES
    reassembler = Reassembler(8 << 20, 5.0, 1 << 20)
    done = [out for r in replies or [] if (out := reassembler.add(decode(r, PatchChunk))) is not None]
    assert done == [sync._held[pid] for pid in IDS]


def test_one_requester_gets_its_byte_budget_then_nothing_until_it_refills() -> None:
    clock = Clock()
    sync = store(clock)  # 8 MiB a second, burst 8 MiB
    budget = SyncSettings().serve_bytes_per_s
    total = sum(served_bytes(ask(sync, 2)) for _ in range(10))
    assert budget <= total <= budget + PATCH_BYTES  # in debt by one patch at most
    assert ask(sync, 2) is None
    assert sync.bus.counters.dropped_count(STORE_KIND, "budget") >= 1
    assert sync.counters.requests_limited >= 1
    clock.now += 0.25  # a quarter of the budget back: a reply left short
    assert 0 < served_bytes(ask(sync, 2)) <= budget // 4 + PATCH_BYTES
    assert sync.counters.patches_withheld > 0 and sync.bus.counters.dropped_count(STORE_KIND, "withheld") == 1
    clock.now += 2.0
    assert served_bytes(ask(sync, 2)) == 64 * PATCH_BYTES


def test_another_requester_has_a_budget_of_its_own() -> None:
    sync = store(Clock())
    while ask(sync, 2) is not None:
        pass
    assert served_bytes(ask(sync, 3)) == 64 * PATCH_BYTES


def test_a_requester_changing_its_name_is_bounded_by_the_total() -> None:
    sync = store(Clock())
    settings = SyncSettings()
    total = sum(served_bytes(ask(sync, requester)) for requester in [None, *range(2, 200)] for _ in range(3))
    limit = settings.serve_total_factor * settings.serve_bytes_per_s
    assert limit <= total <= limit + PATCH_BYTES
    assert sync.bus.counters.dropped_count(STORE_KIND, "rate_total") > 0


def test_queries_past_the_rate_are_refused_before_anything_is_built(monkeypatch: pytest.MonkeyPatch) -> None:
    sync = store(Clock(), serve_requests_hz=5.0)
    outcomes = [ask(sync, 2, IDS[:1]) is not None for _ in range(6)]
    assert outcomes == [True] * 5 + [False]
    assert sync.bus.counters.dropped_count(STORE_KIND, "rate") == 1


def test_serving_encodes_nothing_until_the_builder_runs(monkeypatch: pytest.MonkeyPatch) -> None:
    sync = store(Clock())
    calls: list[int] = []
    real = service.encode
    monkeypatch.setattr(service, "encode", lambda msg: calls.append(1) or real(msg))
    params = dict(part.split("=", 1) for part in request_parameters(IDS[:2], 2).split(";"))
    build = sync._serve(sync.keys.store(1), params)
    assert callable(build) and calls == []
    assert len(build()) == len(calls) == 2 * 8  # 64 kB in 8 kB chunks
    assert sync.counters.served == 2 and sync.served_to == {2: 2}


def test_nothing_held_and_malformed_queries_cost_no_budget() -> None:
    sync = store(Clock(), serve_requests_hz=1.0)
    assert ask(sync, 2, [PatchId(3, 0, 0)]) is None
    assert sync._serve(sync.keys.store(1), {"ids": "garbage"}) is None
    assert ask(sync, 2, IDS[:1]) is not None
