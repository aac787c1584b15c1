"""`SwarmNetwork`: the object an experiment or a test holds: topology up/down plus impairments by pair, node, all.

Impairments are kept as a table of profiles (all / per node / per pair); every change rebuilds the rules from
that table (see impair.py), so `restore_*` simply removes an entry. If loading the rules fails, the table is
rolled back to what is actually in force and the error is raised: what `applied()` reports is what runs.

Outliving the process (`swarm netem up`, manual.py): `SwarmNetwork(n, keep=True).up()` names the namespaces with
pid field 0 (see topology.py: `remove_leftovers()` never touches them) and registers no exit hook, so the network
stays until someone removes it. Another process takes it over with `SwarmNetwork.attach(layout, impairments)`,
which creates and checks nothing; its `down()` removes the network.
"""

from __future__ import annotations

import atexit
from collections.abc import Mapping
from types import TracebackType

from swarm.netem import impair, topology
from swarm.netem.commands import NetemUnavailable, check_prerequisites, tool
from swarm.netem.impair import Impairments
from swarm.netem.profile import LinkProfile, refuse_delay
from swarm.netem.topology import NetworkLayout

CUT = LinkProfile(cut=True)


class SwarmNetwork:
    """A virtual swarm radio network of `nodes` nodes (ids 1..nodes), one network namespace each.

    Use it as a context manager (`with SwarmNetwork(3) as net:`), or call `up()` and `down()` yourself;
    `down()` also runs at interpreter exit if it was forgotten. Impairments set before `up()` are applied by
    `up()`; `down()` forgets them. With `keep=True` the network outlives this process: no exit hook, and names
    that `remove_leftovers()` leaves alone (see the module docstring).
    """

    def __init__(self, nodes: int, keep: bool = False) -> None:
        if not 1 <= nodes <= topology.MAX_NODES:
            raise ValueError(f"a swarm network has 1 to {topology.MAX_NODES} nodes, not {nodes}")
        self.nodes = nodes
        self.keep = keep
        self._layout: NetworkLayout | None = None
        self._is_up = False
        self._imp = Impairments()
        self._rates: dict[int, int] = {}  # tbf limits in force, per node

    # ----- topology -----

    @property
    def layout(self) -> NetworkLayout:
        """Names and addresses (chosen on first use: the tag must not clash with existing namespaces)."""
        if self._layout is None:
            self._layout = topology.new_layout(self.nodes, keep=self.keep)
        return self._layout

    @classmethod
    def attach(cls, layout: NetworkLayout, impairments: Impairments | None = None) -> SwarmNetwork:
        """An instance for a network that is already up (made by another process, e.g. `swarm netem up`), with
        `impairments` as the profiles in force (node rate limits are taken to be the ones they imply). Nothing is
        created, checked or registered: no exit hook, so the network outlives this instance unless `down()` is
        called, which removes it."""
        net = cls(layout.nodes, keep=layout.kept)
        net._layout = layout
        net._is_up = True
        net._imp = impairments.copy() if impairments is not None else Impairments()
        net._rates = impair.node_rates(layout, net._imp)
        return net

    @property
    def prefix(self) -> str:
        """The name prefix of every namespace of this instance ("swn-<tag>-<pid>")."""
        return self.layout.prefix

    @property
    def is_up(self) -> bool:
        return self._is_up

    def up(self) -> SwarmNetwork:
        """Create the hub, the bridge and every node; a no-op if already up. On failure, everything created so
        far is removed before the error (NetemUnavailable, one line) is raised."""
        if self._is_up:
            return self
        check_prerequisites()
        layout = self.layout
        if not self.keep:
            atexit.register(self.down)
        try:
            topology.create_hub(layout)
            for k in layout.node_ids:
                topology.add_node(layout, k)
            self._is_up = True
            self._apply(self._imp)
        except BaseException:
            self.down()
            raise
        return self

    def down(self) -> None:
        """Remove every namespace this instance created (with their links, bridge, qdiscs and nft tables) and end
        the processes still running inside them; the impairment profiles are forgotten. Idempotent: namespaces
        that are already gone are not an error."""
        atexit.unregister(self.down)
        self._is_up = False
        self._imp = Impairments()
        self._rates = {}
        if self._layout is not None:
            topology.destroy(self._layout.all_namespaces())
            topology.remove_control_links(self._layout)

    def __enter__(self) -> SwarmNetwork:
        return self.up()

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.down()

    def namespace(self, k: int) -> str:
        return self.layout.namespace(self._node(k))

    def address(self, k: int) -> str:
        """Node k's IPv4 address on the swarm network (inside its namespace)."""
        return self.layout.address(self._node(k))

    def exec_argv(self, k: int, argv: list[str]) -> list[str]:
        """The command line that runs `argv` inside node k's namespace (for subprocess.Popen)."""
        return [tool("ip"), "netns", "exec", self.namespace(k), *argv]

    # ----- impairments -----

    def impair_pair(self, a: int, b: int, profile: LinkProfile) -> None:
        """Apply `profile` to the link between nodes a and b, both directions."""
        if profile.rate_kbit:
            raise NetemUnavailable(
                "a per-pair rate limit is not implemented (needs htb + u32 on the hub ports); "
                "rate_kbit works with impair_node and impair_all"
            )
        imp = self._imp.copy()
        imp.pairs[self._pair(a, b)] = profile
        self._change(imp, profile)

    def impair_node(self, k: int, profile: LinkProfile) -> None:
        """Apply `profile` to node k's radio: every link between k and any other node, both directions."""
        imp = self._imp.copy()
        imp.nodes[self._node(k)] = profile
        self._change(imp, profile)

    def impair_all(self, profile: LinkProfile) -> None:
        """Apply `profile` to every link, both directions."""
        imp = self._imp.copy()
        imp.all = profile
        self._change(imp, profile)

    def set_pairs(self, profiles: Mapping[tuple[int, int], LinkProfile]) -> None:
        """Make `profiles` the per-pair profiles, all at once (one rule load): pairs not given, or given a clean
        profile, have no pair profile afterwards. Node and all-links profiles are kept."""
        imp = self._imp.copy()
        imp.pairs = {}
        for (a, b), profile in profiles.items():
            if profile.rate_kbit:
                raise NetemUnavailable(f"a per-pair rate limit ({a}-{b}) is not implemented; use impair_node")
            refuse_delay(profile)
            if not profile.is_clean:
                imp.pairs[self._pair(a, b)] = profile
        self._change(imp)

    def set_impairments(self, imp: Impairments) -> None:
        """Make `imp` (all-links, per-node and per-pair profiles) the whole table in force, in one rule load;
        refused as a whole (nothing changes) if a profile asks for delay/jitter, a pair has a rate limit, or a node
        does not exist."""
        for profile in [imp.all, *imp.nodes.values(), *imp.pairs.values()]:
            if profile is not None:
                refuse_delay(profile)
        for k in imp.nodes:
            self._node(k)
        pairs = {}
        for (a, b), profile in imp.pairs.items():
            if profile.rate_kbit:
                raise NetemUnavailable(f"a per-pair rate limit ({a}-{b}) is not implemented; use a node's profile")
            pairs[self._pair(a, b)] = profile
        self._change(Impairments(imp.all, dict(imp.nodes), pairs))

    def cut_pair(self, a: int, b: int) -> None:
        self.impair_pair(a, b, CUT)

    def cut_node(self, k: int) -> None:
        self.impair_node(k, CUT)

    def restore_pair(self, a: int, b: int) -> None:
        """Remove the pair's own profile (node and all-links profiles still apply)."""
        imp = self._imp.copy()
        imp.pairs.pop(self._pair(a, b), None)
        self._change(imp)

    def restore_node(self, k: int) -> None:
        """Remove node k's own profile (pair and all-links profiles still apply)."""
        imp = self._imp.copy()
        imp.nodes.pop(self._node(k), None)
        self._change(imp)

    def restore_all(self) -> None:
        """Remove every profile: all links clean."""
        self._change(Impairments())

    def applied(self) -> Impairments:
        """A copy of the profiles in force."""
        return self._imp.copy()

    def rules(self) -> str:
        """The impairment rules in force, as `nft list` prints them, plus one comment line per rate limit
        ("" when the network is down)."""
        if not self._is_up:
            return ""
        text = impair.list_ruleset(self.layout)
        for k, rate in sorted(self._rates.items()):
            if rate > 0:
                port = self.layout.port(k)
                text += f"# node {k}: tbf {rate} kbit/s on eth0 (uplink) and on hub port {port} (downlink)\n"
        return text

    # ----- internals -----

    def _node(self, k: int) -> int:
        if not 1 <= k <= self.nodes:
            raise ValueError(f"node {k} does not exist (nodes are 1..{self.nodes})")
        return k

    def _pair(self, a: int, b: int) -> tuple[int, int]:
        self._node(a)
        self._node(b)
        if a == b:
            raise ValueError(f"a pair needs two different nodes, not {a} and {b}")
        return (min(a, b), max(a, b))

    def _change(self, imp: Impairments, profile: LinkProfile | None = None) -> None:
        if profile is not None:
            refuse_delay(profile)
        old = self._imp
        try:
            self._apply(imp)
        except BaseException:
            if self._is_up:
                try:
                    self._apply(old)
                except NetemUnavailable:
                    pass
            raise

    def _apply(self, imp: Impairments) -> None:
        """Make `imp` the impairments in force (only recorded while down; loaded by `up()`)."""
        if self._is_up:
            impair.load_ruleset(self.layout, imp)
            rates = impair.node_rates(self.layout, imp)
            if rates or self._rates:
                check_prerequisites(("tc",))
                impair.apply_rates(self.layout, self._rates, rates)  # updates self._rates as it goes
        self._imp = imp
