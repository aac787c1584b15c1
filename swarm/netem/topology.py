"""The virtual swarm network: a hub namespace with a bridge, one namespace per node, a veth from each to the hub.

    node k's namespace "swn-<tag>-<pid>-n<k>"        hub namespace "swn-<tag>-<pid>-hub"
      lo (up)                                          br0 (bridge, no IP, multicast snooping off)
      eth0 10.<x>.<y>.<10+k>/24  <--- veth --->        v<k> (bridge port)

Names and addresses:
- `tag` is 4 random hex digits, unique among the existing namespaces, and gives the subnet 10.<x>.<y>.0/24
  (x, y = the tag's two bytes), so instances running side by side never share names or addresses. `pid` is the
  creating process: `remove_leftovers()` deletes only `swn-*` namespaces whose creator is dead, so it cannot
  touch a live instance or anything swarm.netem did not create.
- Interface names (`br0`, `v<k>`, `eth0`) live inside private namespaces, so they never collide.

Traps (measured in research/zenoh-netns-link-loss.md, section 2):
- GSO is turned off on each node's eth0 (`gso_max_segs 1 gso_max_size 1500`); with veth's default offloads a
  TCP flow reaches nftables as ~47 kB super-packets, and one "lost packet" would be 30 segments.
- Neighbour (ARP) entries are static: each node knows every other node's MAC (`02:<tag>:00:00:<k>`) permanently.
  Otherwise ARP requests and replies are dropped by the impairment too, a neighbour entry goes FAILED after
  three lost probes, and the measured loss would be bursty and far above the configured one.
- The hub has no address and no route: the namespaces are isolated from the host and from each other except
  through the bridge, so there is no path around an impairment.
"""

from __future__ import annotations

import os
import re
import secrets
import signal
import time
from dataclasses import dataclass

from swarm.netem.commands import delete_namespace, ip_batch, namespace_pids, namespaces, run

NAME_PREFIX = "swn-"
BRIDGE = "br0"
MAX_NODES = 200
_NAME_RE = re.compile(r"^swn-(?P<tag>[0-9a-f]{4})-(?P<pid>\d+)-(?P<role>hub|n\d+)$")
_reserved_tags: set[str] = set()  # tags handed out by this process, even to instances not up yet


@dataclass(frozen=True)
class Layout:
    """Names and addresses of one swarm network instance (pure data, nothing is created)."""

    tag: str
    pid: int
    nodes: int

    @property
    def prefix(self) -> str:
        return f"{NAME_PREFIX}{self.tag}-{self.pid}"

    @property
    def hub(self) -> str:
        return f"{self.prefix}-hub"

    @property
    def subnet(self) -> str:
        return f"10.{int(self.tag[:2], 16)}.{int(self.tag[2:], 16)}.0/24"

    @property
    def node_ids(self) -> range:
        return range(1, self.nodes + 1)

    def namespace(self, k: int) -> str:
        return f"{self.prefix}-n{k}"

    def port(self, k: int) -> str:
        """The hub-side end of node k's veth (its bridge port)."""
        return f"v{k}"

    def address(self, k: int) -> str:
        return f"10.{int(self.tag[:2], 16)}.{int(self.tag[2:], 16)}.{10 + k}"

    def mac(self, k: int) -> str:
        return f"02:{self.tag[:2]}:{self.tag[2:]}:00:00:{k:02x}"

    def all_namespaces(self) -> list[str]:
        return [self.hub, *(self.namespace(k) for k in self.node_ids)]


def new_layout(nodes: int) -> Layout:
    """A layout with a tag that no existing namespace and no other instance of this process uses (two instances
    of one process with the same tag would have the same names, and one's down() would delete the other)."""
    if not 1 <= nodes <= MAX_NODES:
        raise ValueError(f"a swarm network has 1 to {MAX_NODES} nodes, not {nodes}")
    taken = _reserved_tags | {m.group("tag") for name in namespaces() if (m := _NAME_RE.match(name))}
    while (tag := secrets.token_hex(2)) in taken:
        pass
    _reserved_tags.add(tag)
    return Layout(tag, os.getpid(), nodes)


def create_hub(layout: Layout) -> None:
    run(["ip", "netns", "add", layout.hub])
    ip_batch(layout.hub, [
        "link set lo up",
        f"link add {BRIDGE} type bridge mcast_snooping 0",
        f"link set {BRIDGE} up",
    ])


def add_node(layout: Layout, k: int) -> None:
    """Node k's namespace, its veth to the bridge, address, GSO off, static neighbours."""
    ns, port = layout.namespace(k), layout.port(k)
    run(["ip", "netns", "add", ns])
    ip_batch(layout.hub, [
        f"link add {port} type veth peer name eth0 netns {ns}",
        f"link set {port} master {BRIDGE} up",
    ])
    ip_batch(ns, [
        "link set lo up",
        f"link set dev eth0 address {layout.mac(k)} gso_max_segs 1 gso_max_size 1500",
        f"addr add {layout.address(k)}/24 dev eth0",
        "link set eth0 up",
        *(f"neigh replace {layout.address(j)} lladdr {layout.mac(j)} dev eth0 nud permanent"
          for j in layout.node_ids if j != k),
    ])


def _pids_inside(names: list[str]) -> set[int]:
    return {pid for name in names for pid in namespace_pids(name)} - {os.getpid()}


def _end_processes(names: list[str], grace_s: float = 1.0) -> None:
    """SIGTERM, then SIGKILL, whatever still runs inside these namespaces (it would otherwise outlive the
    network, stuck in a namespace without a link, and keep that namespace allocated)."""
    for sig in (signal.SIGTERM, signal.SIGKILL):
        pids = _pids_inside(names)
        for pid in pids:
            try:
                os.kill(pid, sig)
            except ProcessLookupError:
                pass
        deadline = time.monotonic() + grace_s
        while pids and time.monotonic() < deadline:
            time.sleep(0.05)
            pids = _pids_inside(names)
        if not pids:
            return


def destroy(names: list[str]) -> None:
    """End the processes inside, then delete the namespaces (node ones first); never fails for missing ones."""
    existing = set(namespaces())
    names = [name for name in names if name in existing]
    _end_processes(names)
    for name in sorted(names, key=lambda n: n.endswith("-hub")):
        delete_namespace(name)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_leftovers() -> list[str]:
    """Delete the namespaces of swarm networks whose creating process is dead; returns the names removed.

    Only names of the exact form swarm.netem creates ("swn-<4 hex>-<pid>-hub" / "-n<k>") are considered, and
    only when that pid no longer exists, so live instances and foreign namespaces are never touched.
    """
    stale = [name for name in namespaces() if (m := _NAME_RE.match(name)) and not _alive(int(m.group("pid")))]
    destroy(stale)
    return stale
