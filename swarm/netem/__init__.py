"""A virtual swarm radio network on one Linux machine, with link impairments (loss, cuts, rate) per pair, per
node or on every link: the ground on which link-loss experiments run.

    from swarm.netem import SwarmNetwork, LinkProfile, NetemUnavailable

    with SwarmNetwork(nodes=3) as net:                 # namespaces created; removed on exit, even on error
        agent = subprocess.Popen(net.exec_argv(1, [sys.executable, "-m", "swarm", ...]))
        net.impair_pair(1, 2, LinkProfile(loss=0.3))   # 30 % loss each way between nodes 1 and 2
        net.cut_node(3)                                # node 3's radio is dead
        print(net.rules())
        net.restore_all()

How (each choice measured; this kernel has no sch_netem, so no `tc netem`):
- topology.py: one network namespace per node (eth0 = its radio, 10.<x>.<y>.<10+k>/24) joined by veths to a
  bridge in a hub namespace. GSO is off on eth0, or loss would hit 64 kB super-packets; ARP entries are static,
  or lost ARP would add bursty extra loss. A process runs on node k's radio via `net.exec_argv(k, argv)`; the
  namespace has only lo and eth0, so traffic between nodes cannot go around the impaired link.
- impair.py: loss and cuts are one bridge-family nftables table in the hub, matching bridge ports
  (`iifname "v1" oifname "v2" numgen random mod ... drop`), rebuilt atomically with `nft -f -` on every change;
  rate limits are tbf on both ends of a node's veth.
- profile.py: `LinkProfile` (loss, cut, rate_kbit; delay_ms and jitter_ms exist but are refused with
  `NetemUnavailable`, since nothing here can apply them). An impairment is never faked or silently dropped.
- commands.py: `ip`/`nft`/`tc` calls; not root, a missing tool or a failing command is `NetemUnavailable`,
  one line with the command's first stderr line.
- manual.py: `swarm netem up/show/apply/down`, a network that outlives the command (`SwarmNetwork(n,
  keep=True)`, state in /run/swarm-netem/<name>.json, taken over by `SwarmNetwork.attach`).

Zenoh in the namespaces: shared memory must stay off (the project's default, `bus.shared_memory = false`). All
namespaces share /dev/shm, so with it on, payloads above about 3 kB would bypass the emulated link entirely.

Cleanup: `down()` (or leaving the `with` block) ends the processes left inside and deletes every namespace,
which takes the veths, bridge, qdiscs and nft tables with it; it also runs at interpreter exit. A process killed
before that leaves namespaces named "swn-<tag>-<pid>-..."; `remove_leftovers()` deletes those whose pid is dead,
and nothing else. Kept networks (`swarm netem up`) have pid field 0 and are never leftovers: only
`swarm netem down` removes them.
"""

from swarm.netem.commands import NetemUnavailable, check_prerequisites
from swarm.netem.impair import Impairments
from swarm.netem.manual import netem_apply, netem_down, netem_show, netem_up, open_network  # noqa: E402 (uses the above)
from swarm.netem.network import SwarmNetwork
from swarm.netem.profile import LinkProfile, kernel_has_netem
from swarm.netem.topology import NAME_PREFIX, remove_leftovers

__all__ = [
    "NAME_PREFIX",
    "Impairments",
    "LinkProfile",
    "NetemUnavailable",
    "SwarmNetwork",
    "check_prerequisites",
    "kernel_has_netem",
    "netem_apply",
    "netem_down",
    "netem_show",
    "netem_up",
    "open_network",
    "remove_leftovers",
]
