"""`swarm deploy netem`: an agent container impairs its own radio interface before it starts.

In the compose deployment every agent has two interfaces, the radio (Zenoh between drones) and the control
network (MAVLink to the simulator, the observer's measurements), and the engine does not say which one is
`eth0`. The radio is therefore found by the address the compose file gave it (`ip -j addr`), and only that
interface is impaired, on egress: a packet between two agents crosses exactly one impaired interface, the
sender's, so `loss` is the loss of every link in each direction, as `LinkProfile.loss` is in the netns swarm.

Two backends, as in `swarm.netem` (`--backend auto` picks the first that works):
- `netem`: `tc netem` on IPv4 only, under a `prio` root with a u32 filter: ARP is not impaired. The netns
  swarm makes ARP entries static for the same reason: lost ARP probes fail neighbour entries, and the loss seen
  becomes bursty and far above the configured one. The engine gives no MACs in advance, so here ARP is left off
  the impaired band. Loss, delay and jitter.
- `nftables`, for kernels without sch_netem (Debian 12's CI machines): an `ip` family table whose prerouting
  chain drops packets arriving on the radio with `numgen random` (`swarm.netem.impair.drop_rule`, the netns
  swarm's rule). On ingress, not egress: a drop in the output or postrouting hook fails the sender's own
  send (UDP `sendto` gets EPERM, TCP keeps the segment queued), which no radio does; a drop on arrival is a
  packet lost in the air. Each direction of a link is still impaired once, at its receiver. IPv4 only, so ARP
  is clean here too. Loss only: delay and jitter are refused, never dropped silently.
Both first turn GSO off (`gso_max_segs 1 gso_max_size 1500`): with a veth's default offloads TCP leaves as
~47 kB super-packets, and one lost "packet" would be 30 segments. Nothing at all runs when loss, delay and
jitter are 0: a clean radio is the kernel's default.

`--record FILE` writes what was applied (`RadioImpairment`, JSON), so the mission report can name the backend.

Every failure (bad value, no interface holding the address, `tc`/`nft` missing or refused, no backend that can
apply the profile) is a `NetemUnavailable`: one line that names the interface and the reason.
"""

from __future__ import annotations

import ipaddress
import json
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any, Literal

from pydantic import Field

from swarm.config import ConfigError
from swarm.files import FileModel, write_atomic
from swarm.netem.commands import NetemUnavailable, run
from swarm.netem.impair import drop_rule
from swarm.netem.profile import LinkProfile, kernel_has_netem

NETEM_BAND = "1:4"  # a fourth prio band: the default priomap never sends anything there, only the filter does
NFT_TABLE = "swradio"
BACKENDS = ("auto", "netem", "nftables")
Backend = Literal["netem", "nftables"]


class RadioImpairment(FileModel):
    """What `swarm deploy netem` applied to one container's radio (its --record file)."""

    address: str
    interface: str = Field(description="the interface holding the address; empty when nothing was applied")
    backend: Backend | None = Field(description="None: a clean radio, nothing applied")
    loss: float
    delay_ms: float = 0.0
    jitter_ms: float = 0.0
    commands: list[str] = Field(default_factory=list, description="what ran, in order (nft scripts inline)")


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


def gso_off(ifname: str) -> list[str]:
    return ["ip", "link", "set", "dev", ifname, "gso_max_segs", "1", "gso_max_size", "1500"]


def nft_ruleset(ifname: str, loss: float) -> str:
    """The atomic nft script that (re)creates the radio's loss table: IPv4 arriving on `ifname` dropped at `loss`."""
    rule = drop_rule(f'iifname "{ifname}"', LinkProfile(loss=loss), "radio")
    return (
        f"table ip {NFT_TABLE}\n"
        f"delete table ip {NFT_TABLE}\n"
        f"table ip {NFT_TABLE} {{\n"
        "  chain radio {\n"
        "    type filter hook prerouting priority -300; policy accept;\n"
        f"    {rule}\n"
        "  }\n"
        "}\n"
    )


def apply_radio_netem(
    address: str, loss: float, delay_ms: float = 0.0, jitter_ms: float = 0.0
) -> tuple[str, list[str]]:
    """Impair the interface holding `address` with tc netem; returns (interface, the commands run). Nothing runs
    (and the interface is not even looked up) when loss, delay and jitter are all 0."""
    check_values(address, loss, delay_ms, jitter_ms)
    if loss == 0 and delay_ms == 0 and jitter_ms == 0:
        return "", []
    ifname = interface_of(address)
    commands = netem_commands(ifname, loss, delay_ms, jitter_ms)
    for argv in commands:
        _run(argv, f"impair the radio {ifname} ({address})")
    return ifname, [" ".join(argv) for argv in commands]


def apply_radio_nftables(
    address: str, loss: float, delay_ms: float = 0.0, jitter_ms: float = 0.0
) -> tuple[str, list[str]]:
    """Impair the interface holding `address` with the nftables loss rule; as `apply_radio_netem`."""
    check_values(address, loss, delay_ms, jitter_ms)
    if delay_ms or jitter_ms:
        raise NetemUnavailable(
            f"radio {address}: delay/jitter ({delay_ms:g} ms / {jitter_ms:g} ms) need tc netem; "
            "the nftables backend applies loss only"
        )
    if loss == 0:
        return "", []
    ifname = interface_of(address)
    script = nft_ruleset(ifname, loss)
    _run(gso_off(ifname), f"impair the radio {ifname} ({address})")
    _run(["nft", "-f", "-"], f"impair the radio {ifname} ({address})", script)
    return ifname, [" ".join(gso_off(ifname)), "nft -f - <<< " + " ".join(script.split())]


def impair_radio(
    address: str, loss: float, delay_ms: float = 0.0, jitter_ms: float = 0.0, backend: str = "auto"
) -> RadioImpairment:
    """Impair the radio with `backend` (auto: tc netem, and nftables where the kernel has no sch_netem)."""
    if backend not in BACKENDS:
        raise ConfigError(f"--backend must be one of {', '.join(BACKENDS)} (got {backend})")
    check_values(address, loss, delay_ms, jitter_ms)
    if loss == 0 and delay_ms == 0 and jitter_ms == 0:
        return RadioImpairment(address=address, interface="", backend=None, loss=0.0)
    chosen: Backend
    if backend == "nftables":
        chosen = "nftables"
        ifname, commands = apply_radio_nftables(address, loss, delay_ms, jitter_ms)
    else:
        try:
            chosen = "netem"
            ifname, commands = apply_radio_netem(address, loss, delay_ms, jitter_ms)
        except NetemUnavailable as exc:
            if backend == "netem" or "qdisc kind is unknown" not in str(exc):
                raise
            _remove_root_qdisc(interface_of(address))  # the prio root went in before netem was refused
            chosen = "nftables"
            ifname, commands = apply_radio_nftables(address, loss, delay_ms, jitter_ms)
    return RadioImpairment(
        address=address,
        interface=ifname,
        backend=chosen,
        loss=loss,
        delay_ms=delay_ms,
        jitter_ms=jitter_ms,
        commands=commands,
    )


def _remove_root_qdisc(ifname: str) -> None:
    try:
        run(["tc", "qdisc", "del", "dev", ifname, "root"])
    except NetemUnavailable:
        pass  # there was none


def _run(argv: list[str], doing: str, stdin: str | None = None) -> str:
    """Run one command (`swarm.netem.commands.run`); NetemUnavailable naming what we were doing, in one line."""
    try:
        return run(argv, stdin)
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


def deploy_netem_command(
    address: str, loss: float, delay_ms: float, jitter_ms: float, backend: str = "auto", record: Path | None = None
) -> int:
    """`swarm deploy netem`: impair this container's radio, say what was done in one line, return 0."""
    done = impair_radio(address, loss, delay_ms, jitter_ms, backend)
    if record is not None:
        record.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(record, done.model_dump_json(indent=2).encode())
    if done.backend is None:
        print(f"radio {address}: clean (loss 0, no delay): nothing applied", flush=True)
        return 0
    delay = f", delay {delay_ms:g} ms" + (f" ± {jitter_ms:g} ms" if jitter_ms else "") if delay_ms else ""
    how = "on egress by tc netem" if done.backend == "netem" else "on ingress by nftables (no sch_netem here)"
    print(f"radio {address} ({done.interface}): loss {100 * loss:g} %{delay} of IPv4 {how}, ARP clean", flush=True)
    return 0
