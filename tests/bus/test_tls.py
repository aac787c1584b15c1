"""Authenticated swarm (issue 7): real Zenoh sessions over mutual TLS with access control, on loopback.

Every negative check runs next to a positive control on the same publisher and window (a certified listener
that does receive), so "nothing arrived" means refused, not slow.
"""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import pytest
import zenoh

from swarm.bus.bridge import AsyncBus
from swarm.bus.messages import AgentState
from swarm.bus.session import zenoh_config
from swarm.config import BusSettings, ConfigError, load_config
from swarm.deploy.certs import make_certs
from swarm.errors import BusError
from tests.bus.helpers import LEASE_MS, free_tcp_port, make_state

MISSION = "tls"
ROUNDS = 20


@pytest.fixture(scope="module")
def certs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    directory = tmp_path_factory.mktemp("certs")
    make_certs(directory, drones=3)
    return directory


@pytest.fixture(scope="module")
def rogue_certs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Another CA's certificates, with the same names as the swarm's."""
    directory = tmp_path_factory.mktemp("rogue")
    make_certs(directory, drones=3)
    return directory


def _settings(certs: Path | None, name: str | None, **endpoints: list[str]) -> BusSettings:
    return BusSettings(tls_dir=certs, tls_name=name, lease_ms=LEASE_MS, **endpoints)


async def _listening(certs: Path, name: str) -> tuple[AsyncBus, str]:
    for _ in range(5):  # other test runs share this machine's ports
        endpoint = f"tls/127.0.0.1:{free_tcp_port()}"
        try:
            return await AsyncBus.open(_settings(certs, name, listen=[endpoint]), MISSION), endpoint
        except BusError as exc:
            if "in use" not in str(exc):
                raise
    raise AssertionError("no free port")


def _recorder(into: list[tuple[str, int]]):
    def handler(key: str, msg: AgentState) -> None:
        into.append((key, msg.id))

    return handler


async def _publish_until(sender: AsyncBus, keys_ids: list[tuple[int, int]], done, what: str) -> None:
    """Publish a heartbeat of claimed id `i` on drone k's key for each (k, i), round after round, until `done()`."""
    for seq in range(ROUNDS * 10):  # 10 s
        for key_id, claimed in keys_ids:
            sender.publish(sender.keys.state(key_id), make_state(claimed, seq))
        if done():
            return
        await asyncio.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


@pytest.mark.bus
async def test_drones_with_swarm_certificates_talk_and_a_forged_id_heartbeat_is_rejected(certs: Path) -> None:
    drone1, endpoint = await _listening(certs, "drone-1")
    received: list[tuple[str, int]] = []
    drone1.subscribe(drone1.keys.all_states, AgentState, _recorder(received))
    drone2 = await AsyncBus.open(_settings(certs, "drone-2", listen=[], connect=[endpoint]), MISSION)
    try:
        # drone 2 sends its own heartbeat and one that claims to be drone 3 (key and payload both say 3)
        await _publish_until(
            drone2,
            [(3, 3), (2, 2)],
            lambda: sum(k.endswith("/2/state") for k, _ in received) >= ROUNDS,
            "drone 2's own heartbeats",
        )
        assert {k for k, _ in received} == {drone1.keys.state(2)}, "a heartbeat under another drone's id arrived"
        assert {i for _, i in received} == {2}
    finally:
        await drone2.close()
        await drone1.close()


@pytest.mark.bus
async def test_a_session_without_a_certificate_or_with_another_cas_receives_nothing(
    certs: Path, rogue_certs: Path
) -> None:
    drone1, endpoint = await _listening(certs, "drone-1")
    observer_got: list[tuple[str, int]] = []
    stranger_got: list[tuple[str, int]] = []
    rogue_got: list[tuple[str, int]] = []
    observer = await AsyncBus.open(_settings(certs, "observer", listen=[], connect=[endpoint]), MISSION)
    # no certificate of its own; it trusts the swarm's CA, so only the missing client certificate can stop it
    plain = zenoh_config(BusSettings(connect=[endpoint], lease_ms=LEASE_MS))
    plain.insert_json5("transport/link/tls/root_ca_certificate", json.dumps(str(certs / "ca.pem")))
    plain.insert_json5("transport/link/tls/verify_name_on_connect", "false")
    stranger = zenoh.open(plain)
    stranger.declare_subscriber(f"swarm/{MISSION}/**", lambda sample: stranger_got.append((str(sample.key_expr), 0)))
    # a certificate named drone-2 from another CA; it trusts the swarm's CA, so only its own certificate is wrong
    forged = zenoh_config(_settings(rogue_certs, "drone-2", listen=[], connect=[endpoint]))
    forged.insert_json5("transport/link/tls/root_ca_certificate", json.dumps(str(certs / "ca.pem")))
    rogue = zenoh.open(forged)
    rogue.declare_subscriber(f"swarm/{MISSION}/**", lambda sample: rogue_got.append((str(sample.key_expr), 0)))
    try:
        observer.subscribe(observer.keys.all_states, AgentState, _recorder(observer_got))
        await _publish_until(drone1, [(1, 1)], lambda: len(observer_got) >= ROUNDS, "the observer's heartbeats")
        assert stranger_got == [], "a session without a certificate received swarm data"
        assert rogue_got == [], "a session with another CA's certificate received swarm data"
    finally:
        stranger.close()
        rogue.close()
        for bus in (observer, drone1):
            await bus.close()


def test_with_tls_every_endpoint_must_be_tls(certs: Path) -> None:
    with pytest.raises(ConfigError, match="every endpoint must be tls/"):
        load_config(overrides={"bus.tls_dir": str(certs), "bus.listen": ["tcp/127.0.0.1:7447"]})


def test_an_agent_takes_its_own_certificate_and_a_missing_one_is_one_clear_error(certs: Path, tmp_path: Path) -> None:
    config = load_config(overrides={"bus.tls_dir": str(certs), "agent.id": 3})
    assert config.agent_bus().tls_name == "drone-3"
    assert config.bus.tls_name is None  # the observer and tools name theirs explicitly
    missing = load_config(overrides={"bus.tls_dir": str(tmp_path), "agent.id": 2})
    with pytest.raises(BusError, match=r"TLS ca .*ca.pem not found \(write them with `swarm deploy certs`\)"):
        zenoh_config(missing.agent_bus())


@pytest.mark.bus
async def test_the_observer_certificate_cannot_query_a_store_and_a_drones_can(certs: Path) -> None:
    """Issue 25: a store query of 1.2 kB asks for up to 4 MiB of replies; the listen-only observer may not ask."""
    drone1, endpoint = await _listening(certs, "drone-1")
    asked: list[str] = []

    def serve(key: str, params: dict[str, str]) -> bytes:
        asked.append(params.get("from", "?"))
        return b"patch bytes"

    drone1.declare_queryable(drone1.keys.store(1), "store", serve)
    drone2 = await AsyncBus.open(_settings(certs, "drone-2", listen=[], connect=[endpoint]), MISSION)
    observer = await AsyncBus.open(_settings(certs, "observer", listen=[], connect=[endpoint]), MISSION)
    try:
        selector = f"{drone1.keys.store(1)}?ids=1.0.0;from="
        for _ in range(100):  # the positive control: the queryable's declaration takes a moment to arrive
            if await drone2.get(selector + "2", "store", 0.5):
                break
            await asyncio.sleep(0.05)
        else:
            raise AssertionError("drone 2's store query was never answered")
        observer_replies = [await observer.get(selector + "9", "store", 0.5) for _ in range(5)]
        drone_replies = await drone2.get(selector + "2", "store", 0.5)
        assert observer_replies == [[]] * 5, "the observer's store query was answered"
        assert [payload for _, payload in drone_replies] == [b"patch bytes"]
        assert "9" not in asked, "the observer's query reached the store"
    finally:
        for bus in (observer, drone2, drone1):
            await bus.close()
