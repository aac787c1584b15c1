"""AsyncBus between this process and peers in separate OS processes (tests/bus/peer_process.py)."""

from __future__ import annotations

import asyncio
import signal
import subprocess
import sys
import threading
import time
from collections.abc import AsyncIterator, Callable
from functools import partial

import pytest

from swarm.bus.bridge import AsyncBus
from swarm.bus.messages import AgentState
from tests.bus.conftest import REPO_ROOT, PeerProcess
from tests.bus.helpers import free_tcp_port, make_state, open_listening_bus, wait_until

pytestmark = [pytest.mark.timeout(60), pytest.mark.bus]

STARTUP_S = 15.0  # a child imports numpy, pydantic and zenoh, then connects; on a loaded 2-core host


@pytest.fixture
async def listener(mission: str) -> AsyncIterator[tuple[AsyncBus, str]]:
    bus, endpoint = await open_listening_bus(mission)
    try:
        yield bus, endpoint
    finally:
        await bus.close()


async def until_peer(peer: PeerProcess, condition: Callable[[], bool], timeout_s: float, what: str) -> float:
    def alive_and_done() -> bool:
        if condition():
            return True
        assert peer.proc.poll() is None, f"{what}: {peer.describe()}"
        return False

    try:
        return await wait_until(alive_and_done, timeout_s, what)
    except AssertionError as exc:
        raise AssertionError(f"{exc}\n{peer.describe()}") from None


async def test_states_cross_processes_both_ways(
    listener: tuple[AsyncBus, str], peer_process: Callable[[int, str], PeerProcess]
) -> None:
    bus, endpoint = listener
    received: list[tuple[str, AgentState, int]] = []
    bus.subscribe(bus.keys.all_states, AgentState, lambda key, msg: received.append((key, msg, threading.get_ident())))
    peer = peer_process(2, endpoint)

    await until_peer(peer, lambda: len(received) >= 3, STARTUP_S, "heartbeats from the other process")
    for key, msg, thread in received:
        assert key == bus.keys.state(2)
        assert msg == make_state(2, msg.seq)
        assert thread == threading.get_ident()

    seq = 0

    def peer_heard_us() -> bool:
        nonlocal seq
        bus.publish(bus.keys.state(1), make_state(1, seq))
        seq += 1
        return bool(peer.of("state"))

    await until_peer(peer, peer_heard_us, 5.0, "the other process to receive our heartbeat")
    event = peer.of("state")[0]
    heard = AgentState.model_validate(event["msg"])
    assert event["key"] == bus.keys.state(1)
    assert heard == make_state(1, heard.seq)

    start = time.monotonic()
    peer.stop()
    assert peer.proc.returncode == 0, peer.describe()
    assert time.monotonic() - start < 5.0


async def test_liveliness_join_and_leave_after_sigkill(
    listener: tuple[AsyncBus, str], peer_process: Callable[[int, str], PeerProcess]
) -> None:
    bus, endpoint = listener
    joined: list[str] = []
    left: list[float] = []
    bus.watch_liveliness(bus.keys.all_alive, joined.append, lambda key: left.append(time.monotonic()))
    peer = peer_process(3, endpoint)

    await until_peer(peer, lambda: bus.keys.alive(3) in joined, STARTUP_S, "the other process's token")
    assert not left

    killed_at = time.monotonic()
    peer.kill()
    await wait_until(lambda: bool(left), 3.0, "the token to vanish after SIGKILL (lease 1000 ms)")
    assert left[0] - killed_at < 3.0


async def test_close_with_a_live_peer_is_prompt(
    listener: tuple[AsyncBus, str], peer_process: Callable[[int, str], PeerProcess]
) -> None:
    bus, endpoint = listener
    received: list[AgentState] = []
    bus.subscribe(bus.keys.all_states, AgentState, lambda key, msg: received.append(msg))
    bus.watch_liveliness(bus.keys.all_alive, lambda key: None, lambda key: None)
    bus.declare_token(bus.keys.alive(1))
    peer = peer_process(4, endpoint)
    await until_peer(peer, lambda: len(received) >= 5, STARTUP_S, "heartbeats from the other process")

    for seq in range(20):
        bus.publish(bus.keys.state(1), make_state(1, seq), reliable=True)
    start = time.monotonic()
    await bus.close()
    assert time.monotonic() - start < 2.0
    assert bus.closed_cleanly
    await asyncio.sleep(0)  # deliveries still queued on the loop are dropped, not run
    count = len(received)
    await asyncio.sleep(0.2)
    assert len(received) == count


async def test_frozen_peer_leaves_on_lease_expiry_and_rejoins(
    listener: tuple[AsyncBus, str], peer_process: Callable[[int, str], PeerProcess]
) -> None:
    """SIGSTOP keeps the peer's sockets open, so only the lease can tell that it is gone."""
    bus, endpoint = listener
    events: list[tuple[str, float]] = []
    bus.watch_liveliness(
        bus.keys.all_alive,
        lambda key: events.append(("join", time.monotonic())),
        lambda key: events.append(("leave", time.monotonic())),
    )
    peer = peer_process(5, endpoint)
    await until_peer(peer, lambda: len(events) == 1, STARTUP_S, "the other process's token")

    frozen_at = time.monotonic()
    peer.proc.send_signal(signal.SIGSTOP)
    try:
        await wait_until(lambda: len(events) == 2, 3.0, "the lease to expire")
    finally:
        peer.proc.send_signal(signal.SIGCONT)
    assert events[1][0] == "leave"
    assert 0.5 < events[1][1] - frozen_at < 3.0

    await until_peer(peer, lambda: len(events) == 3, 5.0, "the peer to reconnect")
    assert events[2][0] == "join"


async def test_a_router_frozen_past_its_lease_hears_every_router_again(
    listener: tuple[AsyncBus, str], peer_process: Callable[..., PeerProcess]
) -> None:
    """Three routers as `swarm run` wires them (each dials the lower ids): 3 is frozen past the lease twice, and
    after each thaw it must hear both others again. Zenoh 1.10.2 leaves the thawed router deaf to one of them in
    about half the thaws (their tokens and its own heartbeats still get through; 1.9 does not, but keeps a
    killed router's token for ever), so router 3 repairs its routes as an agent does (`--repair-routes`)."""
    bus, endpoint = listener
    heard: dict[int, int] = {}  # the latest seq this process (router 1) heard from each peer
    bus.subscribe(bus.keys.all_states, AgentState, lambda key, msg: heard.__setitem__(msg.id, msg.seq))
    bus.declare_token(bus.keys.alive(1))
    endpoint_2 = f"tcp/127.0.0.1:{free_tcp_port()}"
    peer_process(2, endpoint, listen=endpoint_2)
    frozen = peer_process(3, [endpoint, endpoint_2], repair_routes=True)
    seq = 0

    def publish_and(condition: Callable[[], bool]) -> Callable[[], bool]:
        def step() -> bool:
            nonlocal seq
            seq += 1
            bus.publish(bus.keys.state(1), make_state(1, seq))
            return condition()

        return step

    def heard_from_3_beyond(mark: int) -> bool:
        return heard.get(3, -1) > mark

    def heard_by_3_since(marks: dict[int, int]) -> Callable[[], bool]:
        def done() -> bool:
            latest = {e["msg"]["id"]: e["msg"]["seq"] for e in frozen.of("state")}
            return all(latest.get(k, -1) > mark for k, mark in marks.items())

        return done

    await until_peer(frozen, publish_and(heard_by_3_since({1: 0, 2: 0})), STARTUP_S, "router 3 to hear 1 and 2")
    for _ in range(2):
        frozen.proc.send_signal(signal.SIGSTOP)
        try:
            await asyncio.sleep(2.5)  # the freeze itself: 2.5 leases, so both others close their links to 3
            mark_3 = heard.get(3, -1)  # the last heartbeat 3 sent before it froze
        finally:
            frozen.proc.send_signal(signal.SIGCONT)
        # marks taken after the thaw: only heartbeats sent once 3 has reconnected can pass
        await until_peer(frozen, publish_and(partial(heard_from_3_beyond, mark_3)), 5.0, "router 1 to hear 3 again")
        marks = {1: seq, 2: heard[2]}
        await until_peer(frozen, publish_and(heard_by_3_since(marks)), 5.0, f"router 3 to hear 1 and 2 ({marks})")


EXIT_SCRIPT = """
import asyncio, sys
from swarm.bus.bridge import AsyncBus
from swarm.bus.messages import AgentState
from swarm.config import BusSettings

async def main():
    bus = await AsyncBus.open(BusSettings(listen=["tcp/127.0.0.1:0"]), sys.argv[1])
    bus.subscribe(bus.keys.all_states, AgentState, lambda key, msg: None)
    bus.watch_liveliness(bus.keys.all_alive, lambda key: None, lambda key: None)
    bus.declare_token(bus.keys.alive(1))
    if sys.argv[2] == "raise":
        raise RuntimeError("a bug with the bus still open")

asyncio.run(main())
"""


@pytest.mark.parametrize("ending", ["return", "raise"])
def test_process_exits_with_its_bus_left_open(mission: str, ending: str) -> None:
    """Exiting with a Zenoh callback still declared hangs the interpreter unless the bus closes it."""
    proc = subprocess.Popen(
        [sys.executable, "-c", EXIT_SCRIPT, mission, ending],
        cwd=REPO_ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        _, stderr = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == (1 if ending == "raise" else 0), stderr
    assert "was not closed; closing it at exit" in stderr
