"""The virtual swarm network: a hub namespace with a bridge, one namespace per node, a veth from each to the hub.

    node k's namespace "swn-<tag>-<pid>-n<k>"        hub namespace "swn-<tag>-<pid>-hub"
      lo (up)                                          br0 (bridge, no IP, multicast snooping off)
      eth0 10.<x>.<y>.<10+k>/24  <--- veth --->        v<k> (bridge port)      the radio: impaired
      ctl0 100.<64+x>.<y>.<10+k> <--- veth --->        sw<tag>c<k> in the host namespace, 100.<64+x>.<y>.1
                                                                                the control link: never impaired

The control link is a point-to-point veth between the node and the host namespace (both ends /32 with a peer
route). It carries what must stay outside the experiment: the drone's MAVLink to the simulator and the
observer's view of the swarm. A node can reach only the host end of its own control link (there is no route to
another node's control address), so no traffic between nodes can go around the radio.

Names and addresses:
- `tag` is 4 random hex digits, unique among the existing namespaces, and gives the subnet 10.<x>.<y>.0/24
  (x, y = the tag's two bytes), so instances running side by side never share names or addresses. `pid` is the
  creating process: `remove_leftovers()` deletes only `swn-*` namespaces whose creator is dead, so it cannot
  touch a live instance or anything swarm.netem did not create.
- Interface names (`br0`, `v<k>`, `eth0`) live inside private namespaces, so they never collide.
- Kept networks (`swarm netem up`, swarm/netem/manual.py) must outlive the process that creates them, so their
  pid field is 0 (`KEPT_PID`): "swn-<tag>-0-hub|n<k>". `remove_leftovers()` never touches them (a dead creator
  is their normal state); only `swarm netem down` (or `SwarmNetwork.down()` on an attached instance) removes
  them. `kept_namespaces()` lists them by tag, which is how `swarm netem down --all` finds orphans.

Traps (each one measured on this ground):
- GSO is turned off on each node's eth0 (`gso_max_segs 1 gso_max_size 1500`); with veth's default offloads a
  TCP flow reaches nftables as ~47 kB super-packets, and one "lost packet" would be 30 segments.
- Neighbour (ARP) entries are static: each node knows every other node's MAC (`02:<tag>:00:00:<k>`) permanently.
  Otherwise ARP requests and replies are dropped by the impairment too, a neighbour entry goes FAILED after
  three lost probes, and the measured loss would be bursty and far above the configured one.
- The hub has no address and no route, and node namespaces have no default route: nodes reach each other only
  through the bridge, so there is no path around an impairment. The host end of the control links shares one
  address (100.<64+x>.<y>.1) on every control veth, which Linux allows with peer routes.
- The tag's first byte is below 64, so the control subnet 100.64.0.0/10 (shared address space, RFC 6598) is
  enough for every tag.
"""

from __future__ import annotations

import os
import re
import secrets
import signal
import time
from dataclasses import dataclass

from swarm.netem.commands import NetemUnavailable, delete_namespace, ip_batch, namespace_pids, namespaces, run

NAME_PREFIX = "swn-"
BRIDGE = "br0"
MAX_NODES = 200
# TCP's retransmission timeout floor on the radio (Linux's default is 200 ms). On a lossy link the same segment
# is often lost three times in a row; at 200 ms doubling that stalls the link past Zenoh's 1 s lease and the
# peers flap. A radio a few hops wide has RTTs of milliseconds, so a low floor is what its hosts should use too.
RADIO_RTO_MIN = "20ms"
KEPT_PID = 0  # the pid field of networks that outlive their creator (swarm netem up); see the module docstring
_NAME_RE = re.compile(r"^swn-(?P<tag>[0-9a-f]{4})-(?P<pid>\d+)-(?P<role>hub|n\d+)$")
_reserved_tags: set[str] = set()  # tags handed out by this process, even to instances not up yet


@dataclass(frozen=True)
class NetworkLayout:
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

    def control_port(self, k: int) -> str:
        """The host-namespace end of node k's control link (unique on the host: it carries the tag)."""
        return f"sw{self.tag}c{k}"

    @property
    def control_host_address(self) -> str:
        """The host end of every control link: where the simulator and the observer are reached from a node."""
        return f"100.{64 + int(self.tag[:2], 16)}.{int(self.tag[2:], 16)}.1"

    def control_address(self, k: int) -> str:
        """Node k's end of its control link."""
        return f"100.{64 + int(self.tag[:2], 16)}.{int(self.tag[2:], 16)}.{10 + k}"

    def mac(self, k: int) -> str:
        return f"02:{self.tag[:2]}:{self.tag[2:]}:00:00:{k:02x}"

    def all_namespaces(self) -> list[str]:
        return [self.hub, *(self.namespace(k) for k in self.node_ids)]

    @property
    def kept(self) -> bool:
        """Whether this network outlives its creator (pid field 0): `remove_leftovers()` never removes it."""
        return self.pid == KEPT_PID


def new_layout(nodes: int, keep: bool = False) -> NetworkLayout:
    """A layout with a tag that no existing namespace and no other instance of this process uses (two instances
    of one process with the same tag would have the same names, and one's down() would delete the other).
    With `keep`, the pid field is `KEPT_PID` (0) instead of this process's pid: the network is meant to outlive
    it, and `remove_leftovers()` leaves it alone."""
    if not 1 <= nodes <= MAX_NODES:
        raise ValueError(f"a swarm network has 1 to {MAX_NODES} nodes, not {nodes}")
    taken = _reserved_tags | {m.group("tag") for name in namespaces() if (m := _NAME_RE.match(name))}
    while (tag := f"{secrets.randbelow(64):02x}{secrets.token_hex(1)}") in taken:
        pass
    _reserved_tags.add(tag)
    return NetworkLayout(tag, KEPT_PID if keep else os.getpid(), nodes)


def create_hub(layout: NetworkLayout) -> None:
    run(["ip", "netns", "add", layout.hub])
    ip_batch(layout.hub, ["link set lo up", f"link add {BRIDGE} type bridge mcast_snooping 0", f"link set {BRIDGE} up"])


def add_node(layout: NetworkLayout, k: int) -> None:
    """Node k's namespace, its veth to the bridge, address, GSO off, static neighbours; its control link."""
    ns, port = layout.namespace(k), layout.port(k)
    run(["ip", "netns", "add", ns])
    ip_batch(
        layout.hub, [f"link add {port} type veth peer name eth0 netns {ns}", f"link set {port} master {BRIDGE} up"]
    )
    ip_batch(
        ns,
        [
            "link set lo up",
            f"link set dev eth0 address {layout.mac(k)} gso_max_segs 1 gso_max_size 1500",
            f"addr add {layout.address(k)}/24 dev eth0",
            "link set eth0 up",
            f"route replace {layout.subnet} dev eth0 proto kernel scope link src {layout.address(k)} "
            f"rto_min {RADIO_RTO_MIN}",
            *(
                f"neigh replace {layout.address(j)} lladdr {layout.mac(j)} dev eth0 nud permanent"
                for j in layout.node_ids
                if j != k
            ),
        ],
    )
    add_control_link(layout, k)


def add_control_link(layout: NetworkLayout, k: int) -> None:
    """The veth between node k and the host namespace, outside the bridge (see the module docstring)."""
    ns, host_end = layout.namespace(k), layout.control_port(k)
    host, node = layout.control_host_address, layout.control_address(k)
    run(["ip", "link", "add", host_end, "type", "veth", "peer", "name", "ctl0", "netns", ns])
    run(["ip", "addr", "add", host, "peer", f"{node}/32", "dev", host_end])
    run(["ip", "link", "set", host_end, "up"])
    ip_batch(ns, [f"addr add {node} peer {host}/32 dev ctl0", "link set ctl0 up"])


def remove_control_links(layout: NetworkLayout) -> None:
    """Delete the host ends of the instance's control links now (deleting a namespace removes its veths only
    when the kernel gets round to it, so a test checking the host right after `down()` would still see them)."""
    prefix = f"sw{layout.tag}c"
    for line in run(["ip", "-o", "link", "show"]).splitlines():
        name = line.split(":", 2)[1].strip().split("@", 1)[0] if line.count(":") >= 2 else ""
        if name.startswith(prefix):
            try:
                run(["ip", "link", "del", name])
            except NetemUnavailable:
                pass  # already gone with its namespace


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
    only when that pid no longer exists, so live instances and foreign namespaces are never touched. Kept
    networks (pid field 0, made by `swarm netem up`) are never removed here: their creator is dead by design.
    """
    stale = [
        name
        for name in namespaces()
        if (m := _NAME_RE.match(name)) and int(m.group("pid")) != KEPT_PID and not _alive(int(m.group("pid")))
    ]
    destroy(stale)
    return stale


def kept_namespaces() -> dict[str, list[str]]:
    """The namespaces of kept networks (pid field 0), grouped by tag: {"0a1f": ["swn-0a1f-0-hub", ...]}."""
    kept: dict[str, list[str]] = {}
    for name in namespaces():
        if (m := _NAME_RE.match(name)) and int(m.group("pid")) == KEPT_PID:
            kept.setdefault(m.group("tag"), []).append(name)
    return kept


def layout_of(tag: str, names: list[str]) -> NetworkLayout:
    """A layout covering these namespaces of one instance (nodes = the highest node number among them), for
    removing an instance whose size is not recorded anywhere else."""
    pids = {int(m.group("pid")) for name in names if (m := _NAME_RE.match(name))}
    roles = [m.group("role") for name in names if (m := _NAME_RE.match(name))]
    nodes = max((int(role[1:]) for role in roles if role.startswith("n")), default=0)
    return NetworkLayout(tag, pids.pop() if len(pids) == 1 else KEPT_PID, max(nodes, 1))
