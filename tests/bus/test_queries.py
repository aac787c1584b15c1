"""AsyncBus queries (declare_queryable / get) between two real Zenoh sessions in this process, on loopback."""

from __future__ import annotations

import asyncio
import threading
import time

import pytest
import zenoh

from swarm.bus.bridge import AsyncBus
from swarm.errors import BusError

pytestmark = pytest.mark.timeout(60)

KIND = "store"
WARM = "warmup"

Calls = list[tuple[str, dict[str, str], int]]


def serving(calls: Calls, reply: bytes | None = b"held") -> object:
    """A handler that records its calls and answers `reply` (warm-up queries always get b"pong")."""

    def handler(key: str, params: dict[str, str]) -> bytes | None:
        calls.append((key, params, threading.get_ident()))
        if "ping" in params:
            return b"pong"
        return reply

    return handler


async def wait_for_queryable(querier: AsyncBus, key: str, timeout_s: float = 5.0) -> None:
    """Declarations take a moment to reach the other session: ping until the queryable answers."""
    deadline = time.monotonic() + timeout_s
    while not await querier.get(f"{key}?ping=1", WARM, 0.5):
        if time.monotonic() > deadline:
            raise AssertionError(f"no queryable answered on {key} within {timeout_s} s")
        await asyncio.sleep(0.02)


@pytest.mark.bus
async def test_get_returns_the_handler_bytes_with_parameters(bus_pair: tuple[AsyncBus, AsyncBus]) -> None:
    a, b = bus_pair
    calls: Calls = []

    def handler(key: str, params: dict[str, str]) -> bytes:
        calls.append((key, params, threading.get_ident()))
        return b"pong" if "ping" in params else f"patch {params['id']} x{params['n']}".encode()

    a.declare_queryable(a.keys.store(1), KIND, handler)
    await wait_for_queryable(b, a.keys.store(1))
    calls.clear()
    before = a.counters.snapshot()[KIND]  # the warm-up pings count under the queryable's kind

    selector = f"{b.keys.store(1)}?id=3.1.4;n=2"
    replies = await b.get(selector, KIND, 2.0)

    assert replies == [(str(a.session.zid()), b"patch 3.1.4 x2")]
    assert calls == [(a.keys.store(1), {"id": "3.1.4", "n": "2"}, threading.get_ident())]
    after, asked = a.counters.snapshot()[KIND], b.counters.snapshot()[KIND]
    served = {name: after[name] - before[name] for name in ("sent_msgs", "sent_bytes", "recv_msgs", "recv_bytes")}
    assert served["sent_msgs"] == asked["recv_msgs"] == 1
    assert served["sent_bytes"] == asked["recv_bytes"] == len(b"patch 3.1.4 x2")
    assert served["recv_msgs"] == asked["sent_msgs"] == 1
    assert served["recv_bytes"] == asked["sent_bytes"] == len(selector.encode())
    assert after["dropped"] == asked["dropped"] == {}
    assert b.counters.snapshot()[WARM]["recv_bytes"] == before["sent_bytes"]  # pongs, counted on both sides


@pytest.mark.bus
async def test_a_wildcard_get_reaches_the_store(bus_pair: tuple[AsyncBus, AsyncBus]) -> None:
    a, b = bus_pair
    calls: Calls = []
    a.declare_queryable(a.keys.store(1), KIND, serving(calls))
    await wait_for_queryable(b, a.keys.store(1))
    replies = await b.get(b.keys.all_stores, KIND, 2.0)
    assert replies == [(str(a.session.zid()), b"held")]
    assert calls[-1][0] == b.keys.all_stores  # the handler sees the query's key expression


@pytest.mark.bus
async def test_none_is_not_held_and_counted(bus_pair: tuple[AsyncBus, AsyncBus]) -> None:
    a, b = bus_pair
    calls: Calls = []
    a.declare_queryable(a.keys.store(1), KIND, serving(calls, reply=None))
    await wait_for_queryable(b, a.keys.store(1))

    start = time.monotonic()
    assert await b.get(f"{b.keys.store(1)}?id=1.0.0", KIND, 3.0) == []
    assert time.monotonic() - start < 1.5  # the error reply finishes the query; no waiting for the timeout
    assert len(calls) == 2  # the ping and this query
    assert b.counters.dropped_count(KIND, "query_error") == 1
    assert a.counters.dropped_count(KIND, "not_held") == 1
    assert b.counters.snapshot()[KIND]["recv_msgs"] == 0


@pytest.mark.bus
async def test_a_failing_handler_does_not_break_the_bus(bus_pair: tuple[AsyncBus, AsyncBus]) -> None:
    a, b = bus_pair

    def handler(key: str, params: dict[str, str]) -> bytes:
        if "boom" in params:
            raise RuntimeError("handler bug")
        if "wrong" in params:
            return "not bytes"  # type: ignore[return-value]
        return b"pong"

    a.declare_queryable(a.keys.store(1), KIND, handler)
    await wait_for_queryable(b, a.keys.store(1))

    assert await b.get(f"{b.keys.store(1)}?boom=1", KIND, 2.0) == []
    assert await b.get(f"{b.keys.store(1)}?wrong=1", KIND, 2.0) == []
    assert a.counters.dropped_count(KIND, "handler_error") == 2
    assert b.counters.dropped_count(KIND, "query_error") == 2
    assert await b.get(b.keys.store(1), KIND, 2.0) == [(str(a.session.zid()), b"pong")]


@pytest.mark.bus
async def test_get_without_a_queryable_returns_at_once(bus_pair: tuple[AsyncBus, AsyncBus]) -> None:
    a, b = bus_pair
    start = time.monotonic()
    assert await b.get(b.keys.store(9), KIND, 5.0) == []
    assert time.monotonic() - start < 0.5
    assert b.counters.dropped_count(KIND) == 0


@pytest.mark.bus
async def test_a_query_never_answered_times_out(bus_pair: tuple[AsyncBus, AsyncBus]) -> None:
    a, b = bus_pair
    held: list[zenoh.Query] = []

    def on_query(query: zenoh.Query) -> None:
        if "ping" in dict(query.parameters):
            query.reply(query.key_expr, b"pong")
        else:
            held.append(query)  # referenced, so Zenoh does not finalise it; never answered

    queryable = a.session.declare_queryable(a.keys.store(1), on_query, complete=True)
    try:
        await wait_for_queryable(b, a.keys.store(1))
        ticks = 0

        async def ticker() -> None:
            nonlocal ticks
            while True:
                ticks += 1
                await asyncio.sleep(0.05)

        task = asyncio.create_task(ticker())
        start = time.monotonic()
        replies = await b.get(b.keys.store(1), KIND, 0.5)
        elapsed = time.monotonic() - start
        task.cancel()

        assert replies == []
        assert 0.4 < elapsed < 1.5
        assert ticks >= 5  # the loop kept running while the get waited
        assert len(held) == 1
        assert b.counters.dropped_count(KIND, "timeout") == 1
    finally:
        held.clear()
        queryable.undeclare()


@pytest.mark.bus
async def test_a_session_does_not_answer_its_own_get(bus_pair: tuple[AsyncBus, AsyncBus]) -> None:
    a, b = bus_pair
    calls: Calls = []
    a.declare_queryable(a.keys.store(1), KIND, serving(calls))
    await wait_for_queryable(b, a.keys.store(1))  # declared and reachable from b
    calls.clear()

    assert await a.get(a.keys.store(1), KIND, 1.0) == []
    assert await a.get(a.keys.all_stores, KIND, 1.0) == []
    assert calls == []
    assert await b.get(b.keys.store(1), KIND, 1.0) == [(str(a.session.zid()), b"held")]


@pytest.mark.bus
async def test_many_queries_each_get_their_answer(bus_pair: tuple[AsyncBus, AsyncBus]) -> None:
    a, b = bus_pair
    a.declare_queryable(a.keys.store(1), KIND, lambda key, params: params.get("i", "").encode())
    await wait_for_queryable(b, a.keys.store(1))
    results = await asyncio.gather(*(b.get(f"{b.keys.store(1)}?i={i}", KIND, 3.0) for i in range(50)))
    assert [r[0][1] for r in results] == [str(i).encode() for i in range(50)]


@pytest.mark.bus
async def test_queryable_and_get_on_a_closed_bus(bus_pair: tuple[AsyncBus, AsyncBus]) -> None:
    a, b = bus_pair

    async def coroutine_handler(key: str, params: dict[str, str]) -> bytes:
        return b""

    with pytest.raises(TypeError):
        a.declare_queryable(a.keys.store(1), KIND, coroutine_handler)  # type: ignore[arg-type]

    a.declare_queryable(a.keys.store(1), KIND, serving([]))
    await wait_for_queryable(b, a.keys.store(1))
    await a.close()
    assert a.closed_cleanly
    assert await b.get(b.keys.store(1), KIND, 1.0) == []  # undeclared with the session
    with pytest.raises(BusError):
        a.declare_queryable(a.keys.store(2), KIND, serving([]))
    assert await a.get(a.keys.store(1), KIND, 1.0) == []
    assert a.counters.dropped_count(KIND, "closed") == 1


def test_patch_and_store_keys() -> None:
    from swarm.bus.keys import Keys

    keys = Keys("m")
    assert keys.patch(7) == "swarm/m/agent/7/patch"
    assert keys.all_patches == "swarm/m/agent/*/patch"
    assert keys.store(250) == "swarm/m/agent/250/store"
    assert keys.all_stores == "swarm/m/agent/*/store"
    for agent_id in (1, 7, 250):
        for key in (keys.state(agent_id), keys.alive(agent_id), keys.patch(agent_id), keys.store(agent_id)):
            assert keys.agent_id_of(key) == agent_id
    for bad in ("swarm/m/agent/7/store/x", "swarm/m/agent/07/patch", "swarm/m/agent/*/store", "swarm/m/agent/7/stor"):
        assert keys.agent_id_of(bad) is None
    with pytest.raises(ValueError):
        keys.store(0)


@pytest.mark.bus
async def test_a_reply_builder_runs_off_the_loop_and_its_payloads_arrive_in_order(
    bus_pair: tuple[AsyncBus, AsyncBus],
) -> None:
    a, b = bus_pair
    built_on: list[int] = []

    def build() -> list[bytes]:
        built_on.append(threading.get_ident())
        return [b"chunk %d" % i for i in range(5)]

    a.declare_queryable(a.keys.store(1), KIND, lambda key, params: b"pong" if "ping" in params else build)
    await wait_for_queryable(b, a.keys.store(1))
    replies = await b.get(f"{b.keys.store(1)}?ids=1", KIND, 2.0)
    assert [payload for _, payload in replies] == [b"chunk %d" % i for i in range(5)]
    assert built_on and threading.get_ident() not in built_on


@pytest.mark.bus
async def test_a_reply_builder_that_fails_is_counted_and_answered_with_an_error(
    bus_pair: tuple[AsyncBus, AsyncBus],
) -> None:
    a, b = bus_pair

    def build() -> list[bytes]:
        raise RuntimeError("boom")

    a.declare_queryable(a.keys.store(1), KIND, lambda key, params: b"pong" if "ping" in params else build)
    await wait_for_queryable(b, a.keys.store(1))
    assert await b.get(f"{b.keys.store(1)}?ids=1", KIND, 2.0) == []
    assert a.counters.dropped_count(KIND, "handler_error") == 1
    assert b.counters.dropped_count(KIND, "query_error") == 1
