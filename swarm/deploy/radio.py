"""`swarm deploy netem`: an agent container impairs its own radio interface with `tc netem` before it starts.

In the compose deployment every agent has two interfaces, the radio (Zenoh between drones) and the control
network (MAVLink to the simulator, the observer's measurements), and Docker does not say which one is `eth0`.
The radio is therefore found by the address the compose file gave it (`ip -j addr`), and only that interface
is impaired, on egress: a packet between two agents crosses exactly one impaired interface, the sender's, so
`loss` is the loss of every link in each direction, as `LinkProfile.loss` is in the netns swarm.

What is applied (what the netns swarm measured, `swarm.netem.topology`):
- GSO off (`gso_max_segs 1 gso_max_size 1500`): with a veth's default offloads TCP leaves as ~47 kB
  super-packets, and one lost "packet" would be 30 segments.
- netem on IPv4 only, under a `prio` root with a u32 filter: ARP is not impaired. The netns swarm makes ARP
  entries static for the same reason: lost ARP probes fail neighbour entries, and the loss seen becomes bursty
  and far above the configured one. Docker gives no MACs in advance, so here ARP is left off the impaired band.
- nothing at all when loss, delay and jitter are 0: a clean radio is the kernel's default.

Every failure (bad value, no interface holding the address, `tc` missing or refused, a kernel without
sch_netem) is a `NetemUnavailable`: one line that names the interface and the reason.
"""

from __future__ import annotations

import ipaddress
import json
from collections.abc import Iterable, Mapping
from typing import Any

from swarm.config import ConfigError
from swarm.netem.commands import NetemUnavailable, run
from swarm.netem.profile import kernel_has_netem

NETEM_BAND = "1:4"  # a fourth prio band: the default priomap never sends anything there, only the filter does


def check_values(address: str, loss: float, delay_ms: float, jitter_ms: float) -> None:
    """ConfigError (one line) for values netem cannot take."""
    try:
        ipaddress.ip_address(address)
    except ValueError:
        raise ConfigError(f"--address '{address}' is not an IP address") from None
    if not 0.0 <= loss <= 1.0:
        raise ConfigError(f"--loss must be a fraction between 0 and 1 (got {loss:g})")
    if delay_ms < 0 or jitter_ms < 0:
        raise ConfigError(f"--delay-ms and --jitter-ms must not be negative (got {delay_ms:g}, {jitter_ms:g})")
    if jitter_ms > 0 and delay_ms == 0:
        raise ConfigError("--jitter-ms needs a --delay-ms to vary around")


def find_interface(address: str, links: Iterable[Mapping[str, Any]]) -> str:
    """The name of the interface holding `address`, from `ip -j addr` output; NetemUnavailable if none does."""
    wanted = ipaddress.ip_address(address)
    seen: list[str] = []
    for link in links:
        for info in link.get("addr_info", []):
            local = info.get("local")
            if local is None:
                continue
            seen.append(f"{link.get('ifname', '?')} {local}")
            try:
                if ipaddress.ip_address(local) == wanted:
                    return str(link["ifname"])
            except ValueError:
                continue
    have = ", ".join(seen) or "no addresses"
    raise NetemUnavailable(f"no interface holds {address} (this host has {have})")


def interface_of(address: str) -> str:
    """The interface holding `address` on this host (or in this container)."""
    return find_interface(address, json.loads(_run(["ip", "-j", "addr", "show"], "list the interfaces")))


def _percent(fraction: float) -> str:
    return f"{round(fraction * 100, 6):g}%"


def _ms(value: float) -> str:
    return f"{round(value, 3):g}ms"


def netem_commands(ifname: str, loss: float, delay_ms: float = 0.0, jitter_ms: float = 0.0) -> list[list[str]]:
    """The `ip` and `tc` commands that impair `ifname`'s egress; empty when there is nothing to impair."""
    if loss == 0 and delay_ms == 0 and jitter_ms == 0:
        return []
    netem = ["netem"]
    if loss > 0:
        netem += ["loss", _percent(loss)]
    if delay_ms > 0:
        netem += ["delay", _ms(delay_ms)] + ([_ms(jitter_ms)] if jitter_ms > 0 else [])
    every_packet = "protocol ip prio 1 u32 match ip dst 0.0.0.0/0"
    return [
        ["ip", "link", "set", "dev", ifname, "gso_max_segs", "1", "gso_max_size", "1500"],
        ["tc", "qdisc", "replace", "dev", ifname, "root", "handle", "1:", "prio", "bands", "4"],
        ["tc", "qdisc", "replace", "dev", ifname, "parent", NETEM_BAND, "handle", "40:", *netem],
        f"tc filter add dev {ifname} parent 1: {every_packet} flowid {NETEM_BAND}".split(),
    ]


def apply_radio_netem(
    address: str, loss: float, delay_ms: float = 0.0, jitter_ms: float = 0.0
) -> tuple[str, list[str]]:
    """Impair the interface holding `address`; returns (interface, the commands run). Nothing runs (and the
    interface is not even looked up) when loss, delay and jitter are all 0."""
    check_values(address, loss, delay_ms, jitter_ms)
    if loss == 0 and delay_ms == 0 and jitter_ms == 0:
        return "", []
    ifname = interface_of(address)
    commands = netem_commands(ifname, loss, delay_ms, jitter_ms)
    for argv in commands:
        _run(argv, f"impair the radio {ifname} ({address})")
    return ifname, [" ".join(argv) for argv in commands]


def _run(argv: list[str], doing: str) -> str:
    """Run one command (`swarm.netem.commands.run`); NetemUnavailable naming what we were doing, in one line."""
    try:
        return run(argv)
    except NetemUnavailable as exc:
        raise NetemUnavailable(f"cannot {doing}: {_with_hint(str(exc))}") from None


def _with_hint(message: str) -> str:
    """The command's one-line failure, with what to do about the two failures a container meets."""
    if "Operation not permitted" in message:
        return f"{message} (the container needs cap_add: NET_ADMIN)"
    if "qdisc kind is unknown" in message:
        # checked only after a failure: inside a container /lib/modules is not the host's, so "no module file"
        # is no proof that the kernel cannot load sch_netem on demand
        missing = "sch_netem" if kernel_has_netem() is False else "sch_prio or sch_netem"
        return f"{message} (this kernel lacks {missing}; on the Docker host: modprobe sch_prio sch_netem)"
    return message


def deploy_netem_command(address: str, loss: float, delay_ms: float, jitter_ms: float) -> int:
    """`swarm deploy netem`: impair this container's radio, say what was done in one line, return 0."""
    ifname, commands = apply_radio_netem(address, loss, delay_ms, jitter_ms)
    if not commands:
        print(f"radio {address}: clean (loss 0, no delay): nothing applied", flush=True)
        return 0
    delay = f", delay {delay_ms:g} ms" + (f" ± {jitter_ms:g} ms" if jitter_ms else "") if delay_ms else ""
    print(f"radio {address} ({ifname}): netem loss {100 * loss:g} %{delay} on egress of IPv4, ARP clean", flush=True)
    return 0
