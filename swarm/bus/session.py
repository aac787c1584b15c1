"""Zenoh session configuration and opening, from `BusSettings`.

Choices (each measured with Zenoh 1.10 on loopback and in network namespaces, on 2 cores):
- multicast scouting is off unless asked for; local swarms use explicit loopback endpoints. Gossip follows
  multicast (off with it), so a session talks only to the endpoints it was given.
- `connect/retry` is short (200 ms doubling to 1 s) so a peer returns within about a second after a cut heals;
  it must be inserted as a whole object ("connect/retry/period_init_ms" is an unknown key).
- router mode (multi-hop relaying) also autoconnects to routers found by scouting, which Zenoh does not do
  by default.
- the data priority's transmit queue holds 16 batches (1 MB per link), not Zenoh's 2: a pull reply is a burst
  of chunks written at once (4 requests of 4 patches: about 800 kB after a partition heals), and with
  CongestionControl.DROP whatever does not fit waits 1 ms and is dropped. Heartbeats (data_high) have their
  own queue, so a deep data queue does not delay them. Allocation is lazy: the memory is used only in bursts.
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

from swarm.bus.keys import MAX_AGENT_ID
from swarm.config import TLS_OBSERVER_NAME, BusSettings, tls_drone_name
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
        "transport/link/tx/queue/size/data": bus.data_queue_batches,
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
    if bus.tls_dir is not None:
        settings.update(_tls_settings(bus))
    return settings


# Access control (Zenoh ACL; subjects are the common names of the peers' TLS certificates). Every authenticated
# session may subscribe, and is sent everything; only drones may query (a store query of 1.2 kB asks for up to
# 4 MiB of replies, and the observer has no use for one); a session may only publish, serve, reply or hold a
# liveliness token under its own drone id. The observer certificate grants listening only.
_LISTEN_MESSAGES = ["declare_subscriber", "declare_liveliness_subscriber", "liveliness_query"]
_ASK_MESSAGES = ["query"]
_SPEAK_MESSAGES = ["put", "delete", "declare_queryable", "reply", "liveliness_token"]
_ALL_MESSAGES = _LISTEN_MESSAGES + _ASK_MESSAGES + _SPEAK_MESSAGES


def access_control(max_id: int = MAX_AGENT_ID) -> dict[str, Any]:
    """The ACL of a swarm session: drone-<k> speaks only under agent/<k>/ and alive/<k>, for every k; drones
    may query, the observer may not."""
    rules: list[dict[str, Any]] = [
        {
            "id": "listen",
            "permission": "allow",
            "flows": ["ingress"],
            "messages": _LISTEN_MESSAGES,
            "key_exprs": ["swarm/**"],
        },
        {
            "id": "ask",
            "permission": "allow",
            "flows": ["ingress"],
            "messages": _ASK_MESSAGES,
            "key_exprs": ["swarm/**"],
        },
        {
            "id": "send",
            "permission": "allow",
            "flows": ["egress"],
            "messages": _ALL_MESSAGES,
            "key_exprs": ["swarm/**"],
        },
    ]
    subjects: list[dict[str, Any]] = [{"id": TLS_OBSERVER_NAME, "cert_common_names": [TLS_OBSERVER_NAME]}]
    policies: list[dict[str, Any]] = [{"rules": ["listen", "send"], "subjects": [TLS_OBSERVER_NAME]}]
    for k in range(1, max_id + 1):
        name = tls_drone_name(k)
        rules.append(
            {
                "id": f"speak-{k}",
                "permission": "allow",
                "flows": ["ingress"],
                "messages": _SPEAK_MESSAGES,
                "key_exprs": [f"swarm/*/agent/{k}/**", f"swarm/*/alive/{k}"],
            }
        )
        subjects.append({"id": name, "cert_common_names": [name]})
        policies.append({"rules": ["listen", "ask", "send", f"speak-{k}"], "subjects": [name]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects, "policies": policies}


def _tls_settings(bus: BusSettings) -> dict[str, Any]:
    assert bus.tls_dir is not None
    if bus.tls_name is None:
        raise BusError("bus.tls_name is not set: which certificate in bus.tls_dir (drone-<id> or observer)")
    files = {
        "ca": bus.tls_dir / "ca.pem",
        "certificate": bus.tls_dir / f"{bus.tls_name}.pem",
        "key": bus.tls_dir / f"{bus.tls_name}.key",
    }
    for what, path in files.items():
        if not path.is_file():
            raise BusError(f"TLS {what} {path} not found (write them with `swarm deploy certs`)")
    ca, cert, key = (str(files[k].resolve()) for k in ("ca", "certificate", "key"))
    return {
        "transport/link/tls": {
            "root_ca_certificate": ca,
            "enable_mtls": True,
            "listen_certificate": cert,
            "listen_private_key": key,
            "connect_certificate": cert,
            "connect_private_key": key,
            "verify_name_on_connect": False,  # identity is the CA signature and the common name, not the address
        },
        "access_control": access_control(),
    }


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
