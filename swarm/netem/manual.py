"""`swarm netem up/show/apply/down`: a virtual swarm radio that outlives the command, for use by hand.

    swarm netem up --nodes 3                   # namespaces, bridge, control links; prints names and addresses
    ip netns exec swn-0a1f-0-n1 ping 10.10.31.12
    swarm netem apply 1-2 --loss 30%           # or --loss 0.3; --cut; --rate-kbit R (a node or all); --restore
    swarm netem apply --scenario links.toml --at 45
    swarm netem show                           # nodes, addresses, profiles in force, nft rules
    swarm netem down                           # or --all

Each network has a name ("default" unless --name) and a state file `<state dir>/<name>.json` holding its layout
(tag, pid, nodes) and the impairment table (all / per node / per pair, as `Impairments`). Every command reads it,
takes the network over with `SwarmNetwork.attach()` (which creates nothing), and `apply` writes back the table in
force afterwards, so the file always says what runs. The state dir is /run/swarm-netem (gone at reboot, like the
namespaces), or $SWARM_NETEM_STATE_DIR; one lock file there serialises the commands.

Outliving the command: `up` builds the network with `SwarmNetwork(n, keep=True)`, whose namespaces have pid
field 0 ("swn-<tag>-0-hub|n<k>") and no exit hook. `remove_leftovers()` (run by tests and missions to clean up
after killed processes) deletes only namespaces whose creating pid is dead, and skips pid 0, so it never
removes a manual network: `swarm netem down` is the only way. `down --all` also removes orphans: kept
namespaces whose state file is gone or unreadable.

What LINK means in `apply` (the same specs as scenario files): "a-b" sets the pair's own profile, "k" node k's
radio profile (all its links), "all" the all-links profile. These are layers that compose (a frame is dropped by
each profile covering its link, independently), exactly `SwarmNetwork.impair_pair/impair_node/impair_all`; an
apply REPLACES the profile of its layer (fields not given are clean, as in scenario files), and `--restore`
removes it ("all --restore" removes every profile: all links clean). Rate limits exist per node and for all
links only. `apply --scenario FILE --at T` makes the scenario's scripted per-pair state at T the whole table
(node and all-links profiles removed; the [radio] model needs drone positions and is not applied).

Every failure is one line: `NetemUnavailable` (not root, tool missing, command failed, delay/jitter asked),
`ConfigError` (bad name, link, value or scenario file), `SwarmError` (no such network, name taken, state file).
"""

from __future__ import annotations

import fcntl
import json
import math
import os
import re
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from swarm.config import ConfigError
from swarm.errors import SwarmError
from swarm.netem import topology
from swarm.netem.commands import NetemUnavailable, check_prerequisites, namespaces
from swarm.netem.impair import Impairments
from swarm.netem.network import SwarmNetwork
from swarm.netem.profile import LinkProfile, refuse_delay
from swarm.netem.scenario import LinkState, load_scenario, resolve_links
from swarm.netem.topology import NetworkLayout

STATE_DIR_ENV = "SWARM_NETEM_STATE_DIR"
DEFAULT_STATE_DIR = Path("/run/swarm-netem")
DEFAULT_NAME = "default"
STATE_FORMAT = 1
_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,31}$")
_LOCK = ".lock"


class NetworkNotUp(SwarmError):
    """No manual swarm network of that name exists."""


@dataclass
class ManualNetwork:
    """What a state file holds: the network's name, layout, impairment table in force and creation time."""

    name: str
    layout: NetworkLayout
    impairments: Impairments
    created: str

    def network(self) -> SwarmNetwork:
        """The network as a SwarmNetwork (attached: nothing created; its down() removes it)."""
        return SwarmNetwork.attach(self.layout, self.impairments)


# ----- state files -----


def state_dir() -> Path:
    return Path(os.environ.get(STATE_DIR_ENV) or DEFAULT_STATE_DIR)


def state_path(name: str) -> Path:
    return state_dir() / f"{check_name(name)}.json"


def check_name(name: str) -> str:
    """The name if it can name a network (it becomes a file name), else ConfigError."""
    if not _NAME_RE.match(name):
        raise ConfigError(
            f"network name {name!r} must be 1-32 letters, digits, '.', '_' or '-', starting with a letter or digit"
        )
    return name


def _profile_json(profile: LinkProfile) -> dict[str, Any]:
    return profile.model_dump(exclude_defaults=True)


def impairments_to_json(imp: Impairments) -> dict[str, Any]:
    return {
        "all": _profile_json(imp.all) if imp.all is not None else None,
        "nodes": {str(k): _profile_json(p) for k, p in sorted(imp.nodes.items())},
        "pairs": {f"{a}-{b}": _profile_json(p) for (a, b), p in sorted(imp.pairs.items())},
    }


def impairments_from_json(tree: dict[str, Any]) -> Impairments:
    """The inverse of impairments_to_json; KeyError/ValueError/ValidationError/TypeError if malformed."""
    pairs = {}
    for key, profile in tree["pairs"].items():
        a, b = (int(part) for part in key.split("-"))
        pairs[(a, b)] = LinkProfile(**profile)
    return Impairments(
        LinkProfile(**tree["all"]) if tree["all"] is not None else None,
        {int(k): LinkProfile(**p) for k, p in tree["nodes"].items()},
        pairs,
    )


def save_state(network: ManualNetwork) -> None:
    """Write the state file atomically (a reader never sees half of it); SwarmError if it cannot be written."""
    layout = network.layout
    tree = {
        "format": STATE_FORMAT,
        "name": network.name,
        "created": network.created,
        "layout": {"tag": layout.tag, "pid": layout.pid, "nodes": layout.nodes},
        "impairments": impairments_to_json(network.impairments),
    }
    path = state_path(network.name)
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        tmp.write_text(json.dumps(tree, indent=2) + "\n")
        os.replace(tmp, path)
    except OSError as exc:
        raise SwarmError(f"cannot write the state file {path}: {exc.strerror or exc}") from None


def load_state(name: str) -> ManualNetwork | None:
    """The network's state, or None when it has no state file; SwarmError (one line) if the file is unusable."""
    path = state_path(name)
    try:
        tree = json.loads(path.read_text())
    except FileNotFoundError:
        return None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise SwarmError(
            f"the state file {path} is unreadable ({_why(exc)}); `swarm netem down --all` removes it and its network"
        ) from None
    try:
        if tree.get("format") != STATE_FORMAT:
            raise ValueError(f"format {tree.get('format')!r}, expected {STATE_FORMAT}")
        lay = tree["layout"]
        layout = NetworkLayout(str(lay["tag"]), int(lay["pid"]), int(lay["nodes"]))
        if not re.fullmatch(r"[0-9a-f]{4}", layout.tag) or not 1 <= layout.nodes <= topology.MAX_NODES:
            raise ValueError(f"bad layout {lay}")
        return ManualNetwork(name, layout, impairments_from_json(tree["impairments"]), str(tree.get("created", "")))
    except (AttributeError, KeyError, TypeError, ValueError, ValidationError) as exc:
        raise SwarmError(
            f"the state file {path} is unreadable ({_why(exc)}); `swarm netem down --all` removes it and its network"
        ) from None


def _why(exc: BaseException) -> str:
    if isinstance(exc, OSError):
        return exc.strerror or type(exc).__name__
    text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    return f"{type(exc).__name__}: {text}"


def network_names() -> list[str]:
    """Names of the networks that have a state file (sorted)."""
    try:
        return sorted(p.stem for p in state_dir().glob("*.json") if _NAME_RE.match(p.stem))
    except OSError:
        return []


def open_network(name: str = DEFAULT_NAME) -> SwarmNetwork:
    """The manual network `name` as an attached SwarmNetwork (for scripts and tests); NetworkNotUp if none."""
    state = load_state(name)
    if state is None:
        raise _not_up(name)
    return state.network()


@contextmanager
def _locked() -> Iterator[None]:
    """One command at a time changes the state dir (an up, apply or down of another shell waits)."""
    directory = state_dir()
    try:
        directory.mkdir(mode=0o755, parents=True, exist_ok=True)
        lock = open(directory / _LOCK, "a")  # noqa: SIM115 (closed below)
    except OSError as exc:
        raise SwarmError(f"cannot use the state directory {directory}: {exc.strerror or exc}") from None
    try:
        fcntl.flock(lock, fcntl.LOCK_EX)
        yield
    finally:
        lock.close()


# ----- helpers for the commands -----


def _name_flag(name: str) -> str:
    return "" if name == DEFAULT_NAME else f" --name {name}"


def _not_up(name: str) -> NetworkNotUp:
    others = [n for n in network_names() if n != name]
    if others:
        return NetworkNotUp(f"no swarm network named '{name}' is up (up: {', '.join(others)}; choose with --name)")
    return NetworkNotUp(
        f"no swarm network named '{name}' is up (start one with: swarm netem up --nodes N{_name_flag(name)})"
    )


def _present(layout: NetworkLayout) -> list[str]:
    existing = set(namespaces())
    return [ns for ns in layout.all_namespaces() if ns in existing]


def _node_table(layout: NetworkLayout) -> list[str]:
    rows = [("node", "namespace", "radio", "control", "host control end")]
    rows += [
        (str(k), layout.namespace(k), layout.address(k), layout.control_address(k), layout.control_host_address)
        for k in layout.node_ids
    ]
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    return ["  " + "  ".join(cell.ljust(w) for cell, w in zip(row, widths)).rstrip() for row in rows]


def describe_impairments(imp: Impairments) -> list[str]:
    """One line per profile in force ("all links: loss 0.1", "node 3: cut", "pair 1-2: loss 0.3")."""
    lines = [f"all links: {imp.all.describe()}"] if imp.all is not None else []
    lines += [f"node {k}: {p.describe()}" for k, p in sorted(imp.nodes.items())]
    lines += [f"pair {a}-{b}: {p.describe()}" for (a, b), p in sorted(imp.pairs.items())]
    return lines


def _in_force(imp: Impairments) -> str:
    return "; ".join(describe_impairments(imp)) or "nothing (every link clean)"


def parse_loss(value: str | float | None) -> float | None:
    """A loss given as a fraction ("0.3", 0.3) or a percentage ("30%"); ConfigError if it is neither or not in
    0..1."""
    if value is None:
        return None
    if isinstance(value, str):
        text = value.strip()
        percent = text.endswith("%")
        try:
            loss = float(text[:-1] if percent else text)
        except ValueError:
            raise ConfigError(f"--loss {value!r} is not a fraction (0.3) or a percentage (30%)") from None
        loss = loss / 100.0 if percent else loss
    else:
        loss = float(value)
    if math.isnan(loss) or not 0.0 <= loss <= 1.0:
        raise ConfigError(f"--loss {value} is out of range: a fraction 0..1 or a percentage 0%..100%")
    return loss


def _profile(
    loss: float | None, cut: bool, rate_kbit: int | None, delay_ms: float | None, jitter_ms: float | None
) -> LinkProfile:
    fields = {"loss": loss, "cut": cut or None, "rate_kbit": rate_kbit, "delay_ms": delay_ms, "jitter_ms": jitter_ms}
    try:
        return LinkProfile(**{k: v for k, v in fields.items() if v is not None})
    except ValidationError as exc:
        first = exc.errors()[0]
        field = str(first["loc"][0]).replace("_", "-") if first["loc"] else "profile"
        raise ConfigError(f"--{field}: {first['msg']} (got {first.get('input')!r})") from None


def _parse_link(link: str) -> tuple[int, ...]:
    """The node ids a link spec names (none for "all"); ConfigError if malformed."""
    try:
        resolve_links(link, topology.MAX_NODES)
    except ValueError as exc:
        raise ConfigError(f"link {link!r}: {exc}") from None
    return () if link == "all" else tuple(int(part) for part in link.split("-"))


# ----- the commands -----


def netem_up(nodes: int, name: str = DEFAULT_NAME) -> int:
    """`swarm netem up`: create network `name` of `nodes` nodes that stays until `swarm netem down`; print its
    nodes and addresses. SwarmError if a network of that name is up."""
    check_name(name)
    if not 1 <= nodes <= topology.MAX_NODES:
        raise ConfigError(f"--nodes must be 1 to {topology.MAX_NODES}, not {nodes}")
    check_prerequisites()
    with _locked():
        old = load_state(name)
        if old is not None:
            if _present(old.layout):
                raise SwarmError(
                    f"a swarm network named '{name}' is already up ({old.layout.nodes} nodes, "
                    f"{old.layout.prefix}-*); remove it first with: swarm netem down{_name_flag(name)}"
                )
            topology.remove_control_links(old.layout)
            state_path(name).unlink(missing_ok=True)
            print(f"note: the state of an earlier '{name}' whose namespaces were gone has been discarded")
        net = SwarmNetwork(nodes, keep=True)
        state = ManualNetwork(name, net.layout, Impairments(), datetime.now(UTC).isoformat(timespec="seconds"))
        save_state(state)  # first: whatever happens next, `down` can find what was created
        try:
            net.up()
        except BaseException:
            net.down()
            state_path(name).unlink(missing_ok=True)
            raise
    layout = net.layout
    print(
        f"swarm network '{name}' is up: {nodes} node{'s' if nodes != 1 else ''}, radio {layout.subnet} "
        f"(impairable), control links to the host at {layout.control_host_address} (never impaired)"
    )
    print("\n".join(_node_table(layout)))
    print(
        f"run a command on node k:  ip netns exec {layout.prefix}-n<k> COMMAND   "
        f"(e.g. ip netns exec {layout.namespace(1)} ping {layout.address(min(2, nodes))})"
    )
    flag = _name_flag(name)
    print(
        f"impair:  swarm netem apply{flag} 1-2 --loss 30%   see:  swarm netem show{flag}   "
        f"remove:  swarm netem down{flag}"
    )
    return 0


def netem_show(name: str = DEFAULT_NAME) -> int:
    """`swarm netem show`: nodes, addresses, profiles in force and nft rules; 1 if the network is broken.
    NetworkNotUp (one line) if there is none."""
    check_name(name)
    check_prerequisites()
    state = load_state(name)
    if state is None:
        raise _not_up(name)
    layout = state.layout
    print(
        f"swarm network '{name}': {layout.nodes} nodes, radio {layout.subnet}, created {state.created}, "
        f"state {state_path(name)}"
    )
    print("\n".join(_node_table(layout)))
    lines = describe_impairments(state.impairments)
    if lines:
        print("impairments (layers that compose: each profile covering a link drops frames independently):")
        print("\n".join(f"  {line}" for line in lines))
    else:
        print("impairments: none (every link clean)")
    missing = sorted(set(layout.all_namespaces()) - set(_present(layout)))
    if missing:
        print(
            f"broken: {len(missing)} of its namespaces are gone ({', '.join(missing[:3])}"
            f"{', ...' if len(missing) > 3 else ''}); remove it with: swarm netem down{_name_flag(name)}"
        )
        return 1
    print(f"rules (nft in {layout.hub}):")
    print(state.network().rules().rstrip("\n"))
    return 0


def netem_apply(
    name: str = DEFAULT_NAME,
    link: str | None = None,
    loss: str | float | None = None,
    cut: bool = False,
    rate_kbit: int | None = None,
    restore: bool = False,
    delay_ms: float | None = None,
    jitter_ms: float | None = None,
    scenario: str | Path | None = None,
    at: float | None = None,
) -> int:
    """`swarm netem apply`: set (or with `restore` remove) the profile of LINK ("a-b", "k" or "all"), or make a
    scenario's state at time `at` the whole table; print what changed and what is in force."""
    check_name(name)
    given = [
        flag
        for flag, value in (
            ("--loss", loss),
            ("--cut", cut or None),
            ("--rate-kbit", rate_kbit),
            ("--delay-ms", delay_ms),
            ("--jitter-ms", jitter_ms),
        )
        if value is not None
    ]
    if scenario is not None:
        if link is not None or given or restore:
            raise ConfigError("--scenario FILE --at T replaces the whole table: give no LINK, impairment or --restore")
        if at is None or math.isnan(at) or at < 0:
            raise ConfigError("--scenario needs --at T, the time in seconds (0 or more) whose state to apply")
        return _apply_scenario(name, Path(scenario), at)
    if at is not None:
        raise ConfigError("--at goes with --scenario FILE")
    if link is None:
        raise ConfigError('give LINK ("a-b", "k" or "all") and an impairment or --restore, or --scenario FILE --at T')
    ids = _parse_link(link)
    if restore and given:
        raise ConfigError(f"--restore cannot be combined with {', '.join(given)}")
    if not restore and not given:
        raise ConfigError("give an impairment (--loss P, --cut, --rate-kbit R) or --restore")
    profile = LinkProfile() if restore else _profile(parse_loss(loss), cut, rate_kbit, delay_ms, jitter_ms)
    refuse_delay(profile)
    if len(ids) == 2 and profile.rate_kbit:
        raise NetemUnavailable(
            f"a rate limit on one pair ({link}) is not implemented; limit a node's radio "
            f"(swarm netem apply {ids[0]} --rate-kbit {profile.rate_kbit}) or all links"
        )
    check_prerequisites()
    with _locked():
        state = load_state(name)
        if state is None:
            raise _not_up(name)
        if any(k > state.layout.nodes for k in ids):
            raise ConfigError(
                f"link {link!r} names a node that network '{name}' does not have (nodes are 1..{state.layout.nodes})"
            )
        net = state.network()
        try:
            done = _change(net, ids, profile, restore)
        finally:
            state.impairments = net.applied()  # what is in force, also after a failed (rolled back) change
            save_state(state)
    print(f"network '{name}': {done}; in force: {_in_force(state.impairments)}")
    return 0


def _change(net: SwarmNetwork, ids: tuple[int, ...], profile: LinkProfile, restore: bool) -> str:
    remove = restore or profile.is_clean
    if len(ids) == 2:
        a, b = min(ids), max(ids)
        if remove:
            net.restore_pair(a, b)
            return f"pair {a}-{b}: own profile removed"
        net.impair_pair(a, b, profile)
        return f"pair {a}-{b}: {profile.describe()}"
    if len(ids) == 1:
        if remove:
            net.restore_node(ids[0])
            return f"node {ids[0]}: own profile removed"
        net.impair_node(ids[0], profile)
        return f"node {ids[0]} (all its links): {profile.describe()}"
    if restore:
        net.restore_all()
        return "every profile removed"
    if remove:
        imp = net.applied()
        net.set_impairments(Impairments(None, imp.nodes, imp.pairs))
        return "all-links profile removed"
    net.impair_all(profile)
    return f"all links: {profile.describe()}"


def _apply_scenario(name: str, path: Path, at: float) -> int:
    scenario = load_scenario(path)
    check_prerequisites()
    with _locked():
        state = load_state(name)
        if state is None:
            raise _not_up(name)
        scenario.check_drones(state.layout.nodes)
        links = LinkState(state.layout.nodes)
        events = [event for event in scenario.events if event.at <= at]
        for event in events:
            links.apply(event)
        pairs = {pair: p for pair, p in links.profiles().items() if not p.is_clean}
        for (a, b), profile in pairs.items():
            refuse_delay(profile)
            if profile.rate_kbit:
                raise NetemUnavailable(
                    f"scenario '{scenario.name}' at {at:g} s limits the rate of link {a}-{b}; "
                    "per-pair rate limits are not implemented"
                )
        net = state.network()
        try:
            net.set_impairments(Impairments(pairs=pairs))
        finally:
            state.impairments = net.applied()
            save_state(state)
    radio = "; its [radio] model is not applied (it needs drone positions)" if scenario.radio is not None else ""
    print(
        f"network '{name}': scenario '{scenario.name}' at {at:g} s ({len(events)} of {len(scenario.events)} "
        f"events so far){radio}; in force: {_in_force(state.impairments)}"
    )
    return 0


def netem_down(name: str = DEFAULT_NAME, all_networks: bool = False) -> int:
    """`swarm netem down`: remove network `name` (or every manual network, orphans included, with
    `all_networks`): processes inside, namespaces, control links, rules, state file. Nothing up is not an error."""
    if not all_networks:
        check_name(name)
    check_prerequisites()
    with _locked():
        if all_networks:
            return _down_all()
        state = load_state(name)
        if state is None:
            orphans = topology.kept_namespaces()
            known = {s.layout.tag for n in network_names() if (s := _try_load(n)) is not None}
            stray = sorted(tag for tag in orphans if tag not in known)
            extra = (
                (f" ({len(stray)} kept network(s) without a state file remain: swarm netem down --all removes them)")
                if stray
                else ""
            )
            print(f"no swarm network named '{name}' is up: nothing to remove{extra}")
            return 0
        _remove(name, state.layout)
    return 0


def _try_load(name: str) -> ManualNetwork | None:
    try:
        return load_state(name)
    except SwarmError:
        return None


def _remove(name: str, layout: NetworkLayout) -> None:
    SwarmNetwork.attach(layout).down()  # ends processes inside, deletes namespaces (rules, qdiscs) and control links
    state_path(name).unlink(missing_ok=True)
    print(f"swarm network '{name}' removed ({layout.nodes} nodes, {layout.prefix}-*)")


def _down_all() -> int:
    removed = 0
    known: set[str] = set()
    for name in network_names():
        state = _try_load(name)
        if state is None:
            state_path(name).unlink(missing_ok=True)
            print(f"removed the unreadable state file of '{name}' (its namespaces are removed as orphans below)")
            continue
        _remove(name, state.layout)
        known.add(state.layout.tag)
        removed += 1
    for tag, names in sorted(topology.kept_namespaces().items()):
        if tag in known:
            continue
        layout = topology.layout_of(tag, names)
        SwarmNetwork.attach(layout).down()
        print(f"removed an orphaned kept network ({layout.prefix}-*, no state file)")
        removed += 1
    if not removed:
        print("no swarm network is up: nothing to remove")
    return 0
