"""Impairments as rules: one bridge-family nftables table in the hub for loss and cuts, tbf for node rates.

Every change rebuilds the whole table from the current profiles and loads it atomically with `nft -f -`:

    table bridge swimp                 # create it if missing, so that the delete below cannot fail
    delete table bridge swimp
    table bridge swimp {
      chain links {                    # NB: a chain named "fwd" does not parse (reserved word)
        type filter hook forward priority 0; policy accept;
        numgen random mod 1000000 < 100000 counter drop comment "all: loss 0.1"
        iifname "v3" counter drop comment "node 3: cut"
        oifname "v3" counter drop comment "node 3: cut"
        iifname "v1" oifname "v2" numgen random mod 1000000 < 300000 counter drop comment "pair 1-2: loss 0.3"
        iifname "v2" oifname "v1" numgen random mod 1000000 < 300000 counter drop comment "pair 1-2: loss 0.3"
      }
    }

The forward hook of a bridge sees every frame between two ports, once per output port for flooded frames
(broadcast, multicast such as Zenoh scouting), so a rule on (input port, output port) is a link between two
nodes. Each rule draws its own random number, so profiles compose like independent radios: a frame from a to b
with node a at 10 % and pair a-b at 30 % is lost with probability 1 - 0.9 * 0.7. Loss precision is one in a
million. Rules need a newline (or ';') before '}'.

Rates are per node (its radio), both directions: tbf as root qdisc of the node's eth0 (uplink) and of its
bridge port in the hub (downlink). Per-pair rates would need htb + u32 classes on the hub ports: not built, so
`rate_kbit` on a pair is refused rather than ignored.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from swarm.netem.commands import NetemUnavailable, run_in
from swarm.netem.profile import LinkProfile
from swarm.netem.topology import NetworkLayout

TABLE = "swimp"
CHAIN = "links"
_LOSS_SCALE = 1_000_000
_TBF_LATENCY = "50ms"
_UNKNOWN = -1


@dataclass
class Impairments:
    """The profiles in force: everything, per node (its radio), per unordered pair (a < b)."""

    all: LinkProfile | None = None
    nodes: dict[int, LinkProfile] = field(default_factory=dict)
    pairs: dict[tuple[int, int], LinkProfile] = field(default_factory=dict)

    def copy(self) -> Impairments:
        return Impairments(self.all, dict(self.nodes), dict(self.pairs))


def drop_rule(match: str, profile: LinkProfile, comment: str) -> str:
    """One nft rule: the packets `match` selects are dropped as the profile's loss or cut says."""
    if profile.cut or profile.loss >= 1.0:
        verdict = "counter drop"
    else:
        threshold = max(1, round(profile.loss * _LOSS_SCALE))
        verdict = f"numgen random mod {_LOSS_SCALE} < {threshold} counter drop"
    return f'{match} {verdict} comment "{comment}: {profile.describe()}"'.strip()


def drop_rules(layout: NetworkLayout, imp: Impairments) -> list[str]:
    """The nft rules (one per line) for the loss and cut parts of the profiles."""
    rules = []
    if imp.all is not None and imp.all.drops:
        rules.append(drop_rule("", imp.all, "all"))
    for k, profile in sorted(imp.nodes.items()):
        if profile.drops:
            rules.append(drop_rule(f'iifname "{layout.port(k)}"', profile, f"node {k}"))
            rules.append(drop_rule(f'oifname "{layout.port(k)}"', profile, f"node {k}"))
    for (a, b), profile in sorted(imp.pairs.items()):
        if profile.drops:
            for src, dst in ((a, b), (b, a)):
                match = f'iifname "{layout.port(src)}" oifname "{layout.port(dst)}"'
                rules.append(drop_rule(match, profile, f"pair {a}-{b}"))
    return rules


def ruleset(layout: NetworkLayout, imp: Impairments) -> str:
    """The atomic nft script that replaces the impairment table with the one for `imp`."""
    body = "".join(f"    {rule}\n" for rule in drop_rules(layout, imp))
    return (
        f"table bridge {TABLE}\n"
        f"delete table bridge {TABLE}\n"
        f"table bridge {TABLE} {{\n"
        f"  chain {CHAIN} {{\n"
        f"    type filter hook forward priority 0; policy accept;\n"
        f"{body}"
        f"  }}\n"
        f"}}\n"
    )


def load_ruleset(layout: NetworkLayout, imp: Impairments) -> None:
    run_in(layout.hub, ["nft", "-f", "-"], ruleset(layout, imp))


def list_ruleset(layout: NetworkLayout) -> str:
    return run_in(layout.hub, ["nft", "list", "table", "bridge", TABLE])


def node_rates(layout: NetworkLayout, imp: Impairments) -> dict[int, int]:
    """kbit/s limit of each rate-limited node: the lowest of its own profile's and the all-links profile's."""
    rates = {}
    for k in layout.node_ids:
        limits = [p.rate_kbit for p in (imp.all, imp.nodes.get(k)) if p is not None and p.rate_kbit > 0]
        if limits:
            rates[k] = min(limits)
    return rates


def _tbf(rate_kbit: int) -> list[str]:
    burst = max(3000, rate_kbit * 1000 // 8 // 50)  # 20 ms at full rate, at least two full frames
    return ["root", "tbf", "rate", f"{rate_kbit}kbit", "burst", str(burst), "latency", _TBF_LATENCY]


def apply_rates(layout: NetworkLayout, in_force: dict[int, int], new: dict[int, int]) -> None:
    """Change the tbf qdiscs of the nodes whose rate differs from `in_force`, updating `in_force` node by node
    (so that after a failure it still says what is applied)."""
    for k in layout.node_ids:
        if in_force.get(k) == new.get(k):
            continue
        in_force[k] = _UNKNOWN  # until both ends are done: forces a retry on the next change
        for ns, dev in ((layout.namespace(k), "eth0"), (layout.hub, layout.port(k))):
            if k in new:
                run_in(ns, ["tc", "qdisc", "replace", "dev", dev, *_tbf(new[k])])
            else:
                try:
                    run_in(ns, ["tc", "qdisc", "del", "dev", dev, "root"])
                except NetemUnavailable:
                    pass  # no tbf there (a half-applied earlier change): nothing to remove
        if k in new:
            in_force[k] = new[k]
        else:
            del in_force[k]
