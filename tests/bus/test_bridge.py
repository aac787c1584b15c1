"""AsyncBus between two real Zenoh sessions in this process, on loopback."""

from __future__ import annotations

import asyncio
import threading
import time

import msgpack
import pytest

from swarm.bus.bridge import AsyncBus
from swarm.bus.codec import encode
from swarm.bus.messages import AgentState
from swarm.config import BusSettings
from swarm.errors import BusError
from tests.bus.helpers import make_state, open_connecting_bus, open_listening_bus, wait_until

pytestmark = pytest.mark.timeout(60)

Received = list[tuple[str, AgentState, int]]


def recorder(into: Received):
    def handler(key: str, msg: AgentState) -> None:
        into.append((key, msg, threading.get_ident()))

    return handler


async def publish_until(bus: AsyncBus, agent_id: int, condition, what: str, timeout_s: float = 5.0) -> int:
    """Publish heartbeats (seq 0, 1, ...) every 20 ms until `condition()`: the subscription takes a moment
    to reach the publisher. Returns how many were sent."""
    seq = 0
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
        bus.publish(bus.keys.state(agent_id), make_state(agent_id, seq))
        seq += 1
        await asyncio.sleep(0.02)
    return seq


@pytest.mark.bus
async def test_state_arrives_on_the_loop_with_equal_fields(bus_pair: tuple[AsyncBus, AsyncBus]) -> None:
    a, b = bus_pair
    received: Received = []
    b.subscribe(b.keys.all_states, AgentState, recorder(received))
    sent = await publish_until(a, 4, lambda: len(received) >= 3, "three heartbeats")

    loop_thread = threading.get_ident()
    for key, msg, thread in received:
        assert key == a.keys.state(4)
        assert msg == make_state(4, msg.seq)
        assert thread == loop_thread
    seqs = [msg.seq for _, msg, _ in received]
    assert seqs == sorted(seqs)

    sent_counts = a.counters.snapshot()["state"]
    assert sent_counts["sent_msgs"] == sent
    assert sent_counts["sent_bytes"] == sum(len(encode(make_state(4, seq))) for seq in range(sent))
    assert a.counters.bytes_sent == sent_counts["sent_bytes"]
    recv_counts = b.counters.snapshot()["state"]
    assert recv_counts["recv_msgs"] == len(received)
    assert recv_counts["recv_bytes"] == sum(len(encode(msg)) for _, msg, _ in received)
    assert recv_counts["dropped"] == {}


@pytest.mark.bus
async def test_malformed_payloads_are_counted_and_never_delivered(bus_pair: tuple[AsyncBus, AsyncBus]) -> None:
    a, b = bus_pair
    received: Received = []
    b.subscribe(b.keys.all_states, AgentState, recorder(received))
    await publish_until(a, 2, lambda: len(received) >= 1, "the subscription")

    bad_payloads = {
        "not_msgpack": b"\xc1 definitely not msgpack",
        "kind": msgpack.packb({"v": 1, "k": "patch", "d": {}}),
        "version": msgpack.packb({"v": 99, "k": "state", "d": {}}),
        "invalid": msgpack.packb({"v": 1, "k": "state", "d": {"id": 2}}),
    }
    for reason, payload in bad_payloads.items():
        # Repeated until counted: a plain put is not guaranteed delivery, the counter is the evidence.
        deadline = time.monotonic() + 5.0
        while b.counters.dropped_count("state", reason) == 0:
            assert time.monotonic() < deadline, f"a {reason} payload was never counted as dropped"
            a.session.put(a.keys.state(2), payload)
            await asyncio.sleep(0.02)

    await publish_until(a, 2, lambda: received[-1][1].seq > 0, "a heartbeat after the bad payloads")
    assert all(msg == make_state(2, msg.seq) for _, msg, _ in received)
    assert set(b.counters.snapshot()["state"]["dropped"]) == set(bad_payloads)


@pytest.mark.bus
async def test_reliable_messages_arrive_all_and_in_order(bus_pair: tuple[AsyncBus, AsyncBus]) -> None:
    a, b = bus_pair
    received: Received = []
    b.subscribe(b.keys.all_states, AgentState, recorder(received))
    await publish_until(a, 3, lambda: len(received) >= 1, "the subscription")

    count = 200
    for seq in range(count):
        a.publish(a.keys.state(3), make_state(3, seq, epoch=1), reliable=True)
    reliable = lambda: [msg for _, msg, _ in received if msg.epoch == 1]  # noqa: E731
    await wait_until(lambda: len(reliable()) == count, 5.0, f"{count} reliable messages")
    assert [msg.seq for msg in reliable()] == list(range(count))
    assert a.counters.snapshot()["state"]["dropped"] == {}


@pytest.mark.bus
async def test_handler_exceptions_do_not_stop_delivery(bus_pair: tuple[AsyncBus, AsyncBus]) -> None:
    a, b = bus_pair
    delivered: list[int] = []

    def flaky(key: str, msg: AgentState) -> None:
        delivered.append(msg.seq)
        if len(delivered) == 1:
            raise RuntimeError("handler bug")

    b.subscribe(b.keys.all_states, AgentState, flaky)
    await publish_until(a, 5, lambda: len(delivered) >= 3, "deliveries after a failing handler")
    assert b.counters.dropped_count("state", "handler_error") == 1


@pytest.mark.bus
async def test_async_handlers_are_refused(bus_pair: tuple[AsyncBus, AsyncBus]) -> None:
    _, b = bus_pair

    async def handler(key: str, msg: AgentState) -> None:
        pass

    with pytest.raises(TypeError):
        b.subscribe(b.keys.all_states, AgentState, handler)  # type: ignore[arg-type]


@pytest.mark.bus
async def test_liveliness_join_history_and_leave(bus_pair: tuple[AsyncBus, AsyncBus]) -> None:
    a, b = bus_pair
    a.declare_token(a.keys.alive(7))
    a.declare_token(a.keys.alive(7))  # idempotent
    events: list[tuple[str, str, int]] = []
    b.watch_liveliness(
        b.keys.all_alive,
        lambda key: events.append(("join", key, threading.get_ident())),
        lambda key: events.append(("leave", key, threading.get_ident())),
    )
    await wait_until(lambda: ("join", a.keys.alive(7)) in [e[:2] for e in events], 5.0, "the join (history)")
    a.undeclare_token(a.keys.alive(7))
    await wait_until(lambda: ("leave", a.keys.alive(7)) in [e[:2] for e in events], 5.0, "the leave")
    assert all(thread == threading.get_ident() for _, _, thread in events)


@pytest.mark.bus
async def test_close_is_prompt_and_idempotent(mission: str) -> None:
    bus, _ = await open_listening_bus(mission)
    received: Received = []
    bus.subscribe(bus.keys.all_states, AgentState, recorder(received))
    bus.watch_liveliness(bus.keys.all_alive, lambda key: None, lambda key: None)
    bus.declare_token(bus.keys.alive(1))
    bus.publish(bus.keys.state(1), make_state(1, 0))
    bus.publish(bus.keys.state(1), make_state(1, 1), reliable=True)

    start = time.monotonic()
    await bus.close()
    assert time.monotonic() - start < 2.0
    assert bus.closed and bus.closed_cleanly
    assert bus.session.is_closed()
    await bus.close()

    assert bus.counters.snapshot()["state"]["sent_msgs"] == 2  # the reliable one was flushed by close()
    closed_drops = bus.counters.dropped_count("state", "closed")  # own messages still queued for the loop
    bus.publish(bus.keys.state(1), make_state(1, 2))  # after close: dropped and counted, never raised
    assert bus.counters.dropped_count("state", "closed") == closed_drops + 1
    with pytest.raises(BusError):
        bus.declare_token(bus.keys.alive(2))


@pytest.mark.bus
async def test_context_manager_closes(mission: str) -> None:
    bus, _ = await open_listening_bus(mission)
    async with bus:
        bus.declare_token(bus.keys.alive(1))
    assert bus.closed and bus.session.is_closed()


async def test_open_rejects_a_bad_mission_before_opening() -> None:
    with pytest.raises(ValueError):
        await AsyncBus.open(BusSettings(), "bad/mission")


@pytest.mark.bus
async def test_router_mode_relays_along_a_chain(mission: str) -> None:
    """a - hub - c, with a and c not connected: in router mode the hub forwards (peers would not)."""
    hub, endpoint = await open_listening_bus(mission, mode="router")
    opened = [hub]
    try:
        a = await open_connecting_bus(mission, endpoint, mode="router")
        opened.append(a)
        c = await open_connecting_bus(mission, endpoint, mode="router")
        opened.append(c)
        received: Received = []
        a.subscribe(a.keys.state(6), AgentState, recorder(received))
        await publish_until(c, 6, lambda: len(received) >= 2, "c's heartbeats at a through the hub")
        assert all(msg == make_state(6, msg.seq) for _, msg, _ in received)
        assert hub.counters.snapshot() == {}  # relayed by Zenoh, never decoded by the hub's bus
        neighbours = {str(z) for z in [*a.session.info.routers_zid(), *a.session.info.peers_zid()]}
        assert str(hub.session.zid()) in neighbours
        assert str(c.session.zid()) not in neighbours
    finally:
        for bus in reversed(opened):
            await bus.close()
