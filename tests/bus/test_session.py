from __future__ import annotations

import json
import socket

import pytest

from swarm.bus.session import open_session, zenoh_config
from swarm.config import BusSettings
from swarm.errors import BusError, SwarmError


def get(config, key: str):
    return json.loads(config.get_json(key))


def test_router_is_the_default_and_listens_on_an_ephemeral_port() -> None:
    config = zenoh_config(BusSettings())
    assert get(config, "mode") == "router"
    assert get(config, "listen/endpoints") == ["tcp/[::]:0"]


def test_peer_defaults() -> None:
    config = zenoh_config(BusSettings(mode="peer", listen=["tcp/127.0.0.1:7451"], connect=["tcp/127.0.0.1:7452"]))
    assert get(config, "mode") == "peer"
    assert get(config, "listen/endpoints") == ["tcp/127.0.0.1:7451"]
    assert get(config, "connect/endpoints") == ["tcp/127.0.0.1:7452"]
    assert get(config, "connect/retry") == {"period_init_ms": 200, "period_max_ms": 1000, "period_increase_factor": 2.0}
    assert get(config, "scouting/multicast/enabled") is False
    assert get(config, "scouting/gossip/enabled") is False
    assert get(config, "transport/shared_memory/enabled") is False
    assert get(config, "transport/link/tx/lease") == 1000
    assert get(config, "transport/link/tx/keep_alive") == 4
    assert get(config, "transport/unicast/max_links") == 1


def test_settings_are_carried_over() -> None:
    bus = BusSettings(mode="router", multicast_scouting=True, lease_ms=3000, keep_alive=3, shared_memory=True)
    config = zenoh_config(bus)
    everyone = {"router": ["router", "peer"], "peer": ["router", "peer"]}
    assert get(config, "mode") == "router"
    assert get(config, "scouting/multicast/enabled") is True
    assert get(config, "scouting/gossip/enabled") is True
    assert get(config, "scouting/multicast/autoconnect") == everyone
    assert get(config, "scouting/gossip/autoconnect") == everyone
    assert get(config, "transport/shared_memory/enabled") is True
    assert get(config, "transport/link/tx/lease") == 3000
    assert get(config, "transport/link/tx/keep_alive") == 3


def test_tcp_and_udp_allow_two_links() -> None:
    bus = BusSettings(listen=["tcp/127.0.0.1:7451", "udp/127.0.0.1:7451"], connect=["udp/127.0.0.1:7452"])
    assert get(zenoh_config(bus), "transport/unicast/max_links") == 2


def test_invalid_endpoint_is_one_line() -> None:
    with pytest.raises(BusError) as info:
        zenoh_config(BusSettings(listen=["garbage"]))
    message = str(info.value)
    assert isinstance(info.value, SwarmError)
    assert "\n" not in message and ".rs" not in message
    assert message.startswith("invalid Zenoh setting listen/endpoints")


@pytest.mark.bus
def test_listen_port_in_use_is_one_clear_line() -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        with pytest.raises(BusError) as info:
            open_session(BusSettings(listen=[f"tcp/127.0.0.1:{port}"]))
    assert str(info.value) == f"cannot listen on tcp/127.0.0.1:{port}: address already in use"


@pytest.mark.bus
def test_unusable_endpoint_is_one_line() -> None:
    with pytest.raises(BusError) as info:
        open_session(BusSettings(listen=["tcp/notanaddress"]))
    assert str(info.value) == "cannot open the Zenoh session: invalid socket address"


@pytest.mark.bus
def test_open_and_close() -> None:
    session = open_session(BusSettings(listen=["tcp/127.0.0.1:0"]))
    try:
        assert not session.is_closed()
    finally:
        session.close()
