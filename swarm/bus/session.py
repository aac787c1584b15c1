"""Zenoh session configuration and opening, from `BusSettings`.

Choices (measured in research/zenoh-netns-link-loss.md, sections 1 and 3c):
- multicast scouting is off unless asked for; local swarms use explicit loopback endpoints. Gossip follows
  multicast (off with it), so a session talks only to the endpoints it was given.
- `connect/retry` is short (200 ms doubling to 1 s) so a peer returns within about a second after a cut heals;
  it must be inserted as a whole object ("connect/retry/period_init_ms" is an unknown key).
- router mode (multi-hop relaying) also autoconnects to routers found by scouting, which Zenoh does not do
  by default.
- shared memory is off unless enabled: all network namespaces share /dev/shm, and large payloads would
  bypass an emulated radio link.
- with both TCP and UDP endpoints, two links per peer are allowed (`transport/unicast/max_links=2`):
  best-effort publications then use UDP (no head-of-line blocking) and reliable ones TCP.
- an empty listen list means every interface on an ephemeral port (Zenoh's peer default; a router would
  otherwise take the fixed port 7447, and two on one machine would collide).
- router mode is the default: a router forwards between sessions that cannot reach each other, so heartbeats,
  pushes and pull requests cross a multi-hop swarm (measured: a chain 1-2-3 gets node 1's patches to node 3 as
  they are pushed, where peers rely on node 2's store, 0.6 s later; tests/sync). Patch sync also works between
  peers, by store and forward.
"""

from __future__ import annotations

import json
import re
from typing import Any

import zenoh

from swarm.config import BusSettings
from swarm.errors import BusError

ROUTER_DEFAULT_LISTEN = ["tcp/[::]:0"]  # as a peer's default: Zenoh's router default is the fixed port 7447
CONNECT_RETRY = {"period_init_ms": 200, "period_max_ms": 1000, "period_increase_factor": 2}
_AUTOCONNECT_ALL = {"router": ["router", "peer"], "peer": ["router", "peer"]}

_SOURCE_LOCATION_RE = re.compile(r" at \S+?\.rs:\d+\.?")
_JSON5_ERROR_RE = re.compile(r'Json5Err\(Message \{ msg: "(.*?)", location')
_LISTEN_ERROR_RE = re.compile(r"listener bound to (\S+?): \[.*: (.+?) \(os error \d+\)")


def zenoh_error_text(exc: BaseException) -> str:
    """A Zenoh error as one short line, without Rust source locations."""
    text = str(exc)
    inner = _JSON5_ERROR_RE.search(text)
    if inner:
        text = inner.group(1)
    text = _SOURCE_LOCATION_RE.sub("", text)
    return " ".join(text.split()) or type(exc).__name__


def _protocols(endpoints: list[str]) -> set[str]:
    return {endpoint.split("/", 1)[0] for endpoint in endpoints}


def _settings(bus: BusSettings) -> dict[str, Any]:
    settings: dict[str, Any] = {
        "mode": bus.mode,
        "connect/endpoints": bus.connect,
        "connect/retry": CONNECT_RETRY,
        "scouting/multicast/enabled": bus.multicast_scouting,
        "scouting/gossip/enabled": bus.multicast_scouting,
        "transport/shared_memory/enabled": bus.shared_memory,
        "transport/link/tx/lease": bus.lease_ms,
        "transport/link/tx/keep_alive": bus.keep_alive,
    }
    if bus.listen:
        settings["listen/endpoints"] = bus.listen
    elif bus.mode == "router":
        settings["listen/endpoints"] = ROUTER_DEFAULT_LISTEN
    if {"tcp", "udp"} <= _protocols(bus.listen + bus.connect):
        settings["transport/unicast/max_links"] = 2
    if bus.mode == "router":
        settings["scouting/multicast/autoconnect"] = _AUTOCONNECT_ALL
        settings["scouting/gossip/autoconnect"] = _AUTOCONNECT_ALL
    return settings


def zenoh_config(bus: BusSettings) -> zenoh.Config:
    """The Zenoh configuration of a swarm session; raises BusError (one line) on an unusable setting."""
    config = zenoh.Config()
    for key, value in _settings(bus).items():
        try:
            config.insert_json5(key, json.dumps(value))
        except Exception as exc:
            raise BusError(f"invalid Zenoh setting {key}={json.dumps(value)}: {zenoh_error_text(exc)}") from None
    return config


def open_session(bus: BusSettings) -> zenoh.Session:
    """Open a Zenoh session (blocking: up to about 0.5 s with connect endpoints); raises BusError (one line)."""
    config = zenoh_config(bus)
    try:
        return zenoh.open(config)
    except Exception as exc:
        listen_error = _LISTEN_ERROR_RE.search(str(exc))
        if listen_error:
            endpoint, reason = listen_error.groups()
            raise BusError(f"cannot listen on {endpoint}: {reason[:1].lower()}{reason[1:]}") from None
        raise BusError(f"cannot open the Zenoh session: {zenoh_error_text(exc)}") from None
