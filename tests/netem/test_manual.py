"""`swarm netem up/show/apply/down` (swarm/netem/manual.py) on real namespaces and nftables (root), plus the
root check and the pure helpers (no root).

Every test that creates a network does it through the `manual` fixture, whose teardown removes it (and, should
`down` itself fail, deletes the namespaces and control links of the tags it recorded), even when the test failed.
State files go to a temporary directory ($SWARM_NETEM_STATE_DIR), never to /run/swarm-netem.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from swarm.config import ConfigError
from swarm.errors import SwarmError
from swarm.netem import LinkProfile, NetemUnavailable, SwarmNetwork, remove_leftovers, topology
from swarm.netem.commands import namespaces, run
from swarm.netem.impair import Impairments
from swarm.netem.manual import (
    STATE_DIR_ENV,
    NetworkNotUp,
    impairments_from_json,
    impairments_to_json,
    load_state,
    netem_apply,
    netem_down,
    netem_show,
    netem_up,
    network_names,
    open_network,
    parse_loss,
    state_path,
)
from swarm.netem.topology import NetworkLayout
from tests.netem.measure import netem_problem, udp_one_way

needs_root = pytest.mark.skipif(netem_problem() is not None, reason=netem_problem() or "")
SMALL = 200  # datagrams per flow: cut and clean links are all or nothing


@pytest.fixture
def state_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    directory = tmp_path / "state"
    monkeypatch.setenv(STATE_DIR_ENV, str(directory))
    return directory


Up = Callable[[int, str], NetworkLayout]


@pytest.fixture
def manual(state_dir: Path) -> Iterator[Up]:
    """`up(nodes, name)` brings a manual network up and returns its layout; afterwards every network of the
    test's state directory is removed."""
    made: dict[str, NetworkLayout] = {}

    def up(nodes: int, name: str) -> NetworkLayout:
        try:
            assert netem_up(nodes, name) == 0
        finally:
            state = load_state(name)
            if state is not None:
                made[name] = state.layout
        return made[name]

    yield up
    for name in network_names():  # those of this test's state dir, made by `up` or by a subprocess
        try:
            state = load_state(name)
            if state is not None:
                made[name] = state.layout
            netem_down(name)
        except SwarmError:
            pass
    left = [ns for layout in made.values() for ns in layout.all_namespaces() if ns in namespaces()]
    for layout in made.values():  # whatever down() could not remove (it failed, or the test broke a part)
        topology.destroy(layout.all_namespaces())
        topology.remove_control_links(layout)
    assert not left, f"netem_down left namespaces behind: {left}"


def with_prefix(layout: NetworkLayout) -> list[str]:
    return sorted(name for name in namespaces() if name.startswith(layout.prefix + "-"))


def control_links(layout: NetworkLayout) -> list[str]:
    return [line for line in run(["ip", "-o", "link", "show"]).splitlines() if f" sw{layout.tag}c" in line]


def one_line_error(info: pytest.ExceptionInfo[BaseException]) -> str:
    text = str(info.value)
    assert text and "\n" not in text
    return text


# ----- no root needed -----


def test_loss_is_a_fraction_or_a_percentage() -> None:
    assert parse_loss("30%") == pytest.approx(0.3)
    assert parse_loss("0.3") == parse_loss(0.3) == 0.3
    assert parse_loss("100%") == 1.0 and parse_loss(None) is None
    for bad in ("30", "1.5", "-1%", "lots", "nan"):
        with pytest.raises(ConfigError) as info:
            parse_loss(bad)
        assert "--loss" in one_line_error(info)


def test_impairment_table_round_trips_through_json() -> None:
    imp = Impairments(LinkProfile(rate_kbit=500), {3: LinkProfile(cut=True)}, {(1, 2): LinkProfile(loss=0.25)})
    assert impairments_from_json(json.loads(json.dumps(impairments_to_json(imp)))) == imp
    assert impairments_from_json(impairments_to_json(Impairments())) == Impairments()


def test_every_command_refuses_non_root_in_one_line(monkeypatch: pytest.MonkeyPatch, state_dir: Path) -> None:
    monkeypatch.setattr(os, "geteuid", lambda: 1000)
    calls = [
        lambda: netem_up(2, "x"),
        lambda: netem_show("x"),
        lambda: netem_apply("x", "1-2", loss="30%"),
        lambda: netem_down("x"),
        lambda: netem_down(all_networks=True),
    ]
    for call in calls:
        with pytest.raises(NetemUnavailable) as info:
            call()
        assert "needs root" in one_line_error(info)
    assert not state_dir.exists()  # nothing was created, not even the state directory


def _cli_has_netem() -> bool:
    from swarm.cli import build_parser

    try:
        build_parser().parse_args(["netem", "show"])
    except SystemExit:
        return False
    return True


_SHOW_AS_THE_CLI_DOES = """\
import sys
from swarm.errors import SwarmError
from swarm.netem.manual import netem_show
try:
    sys.exit(netem_show())
except SwarmError as exc:
    print(f"swarm netem: error: {exc}", file=sys.stderr)
    sys.exit(1)
"""


@pytest.mark.netns
def test_a_real_non_root_user_gets_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    setpriv = shutil.which("setpriv")
    if setpriv is None or os.geteuid() != 0:
        pytest.skip("needs root and setpriv to run as nobody")
    nobody = [setpriv, "--reuid=65534", "--regid=65534", "--clear-groups", sys.executable]
    if (
        subprocess.run(
            [*nobody, "-c", "import swarm.netem.manual"], cwd="/", capture_output=True, timeout=60
        ).returncode
        != 0
    ):
        pytest.skip(f"{sys.executable} or the swarm package is not readable by nobody")
    wired = _cli_has_netem()
    capsys.readouterr()
    argv = [*nobody, "-m", "swarm", "netem", "show"] if wired else [*nobody, "-c", _SHOW_AS_THE_CLI_DOES]
    done = subprocess.run(argv, cwd="/", capture_output=True, text=True, timeout=60)
    print(f"as nobody ({'swarm netem show' if wired else 'netem_show() as the CLI calls it'}): {done.stderr!r}")
    assert done.returncode == 1 and done.stdout == ""
    assert done.stderr.count("\n") == 1 and "needs root" in done.stderr


# ----- real namespaces (root) -----


@needs_root
@pytest.mark.netns
def test_up_creates_a_kept_network_and_prints_its_addresses(
    manual: Up, state_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    layout = manual(3, "lab")
    out = capsys.readouterr().out
    assert layout.pid == 0 and layout.kept and layout.nodes == 3
    assert with_prefix(layout) == sorted(layout.all_namespaces())
    assert len(control_links(layout)) == 3
    tree = json.loads((state_dir / "lab.json").read_text())
    assert tree["layout"] == {"tag": layout.tag, "pid": 0, "nodes": 3} and tree["impairments"]["pairs"] == {}
    for k in (1, 2, 3):
        line = next(line for line in out.splitlines() if layout.namespace(k) + " " in line)
        assert layout.address(k) in line and layout.control_address(k) in line
        assert layout.control_host_address in line
    assert f"ip netns exec {layout.prefix}-n<k>" in out
    eth0 = run(["ip", "-n", layout.namespace(2), "addr", "show", "dev", "eth0"])
    ctl0 = run(["ip", "-n", layout.namespace(2), "addr", "show", "dev", "ctl0"])
    assert f"inet {layout.address(2)}/24" in eth0 and f"inet {layout.control_address(2)} peer" in ctl0

    with pytest.raises(SwarmError) as info:  # the name is taken
        netem_up(2, "lab")
    assert "already up" in one_line_error(info) and "netem down --name lab" in str(info.value)
    other = manual(1, "other")  # another name coexists
    assert other.tag != layout.tag and len(with_prefix(layout)) == 4 and len(with_prefix(other)) == 2


@needs_root
@pytest.mark.netns
def test_apply_changes_the_rules_that_show_prints(manual: Up, capsys: pytest.CaptureFixture[str]) -> None:
    layout = manual(3, "rules")
    assert netem_apply("rules", "1-2", loss="30%") == 0
    assert netem_apply("rules", "3", cut=True) == 0
    assert netem_apply("rules", "all", rate_kbit=1000) == 0
    capsys.readouterr()
    assert netem_show("rules") == 0
    out = capsys.readouterr().out
    assert "pair 1-2: loss 0.3" in out and "node 3: cut" in out and "all links: rate 1000 kbit" in out
    assert 'iifname "v1" oifname "v2" numgen random mod 1000000 < 300000' in out
    assert 'iifname "v3" counter' in out and 'oifname "v3" counter' in out
    assert "# node 2: tbf 1000 kbit/s" in out
    state = load_state("rules")
    assert state is not None and state.impairments == Impairments(
        LinkProfile(rate_kbit=1000), {3: LinkProfile(cut=True)}, {(1, 2): LinkProfile(loss=0.3)}
    )

    assert netem_apply("rules", "3", restore=True) == 0  # only node 3's own profile goes
    assert netem_apply("rules", "1-2", cut=True) == 0  # replaces the pair's loss
    capsys.readouterr()
    netem_show("rules")
    out = capsys.readouterr().out
    assert "node 3: cut" not in out and "pair 1-2: cut" in out and "numgen" not in out

    assert netem_apply("rules", "all", restore=True) == 0  # every profile, tbf included, is gone
    capsys.readouterr()
    netem_show("rules")
    out = capsys.readouterr().out
    assert "impairments: none" in out and "drop" not in out and "tbf" not in out
    assert "tbf" not in run(["ip", "netns", "exec", layout.namespace(1), "tc", "qdisc", "show", "dev", "eth0"])


@needs_root
@pytest.mark.netns
def test_refused_applies_change_nothing(manual: Up, state_dir: Path) -> None:
    manual(3, "refuse")
    netem_apply("refuse", "1-3", loss=0.2)
    before = (state_dir / "refuse.json").read_text()
    rules = open_network("refuse").rules()
    refusals: list[tuple[type[Exception], dict[str, object], str]] = [
        (NetemUnavailable, {"link": "1", "delay_ms": 30.0}, "delay/jitter"),
        (NetemUnavailable, {"link": "1-2", "rate_kbit": 500}, "rate limit on one pair"),
        (ConfigError, {"link": "1-4", "cut": True}, "nodes are 1..3"),
        (ConfigError, {"link": "1-x", "cut": True}, '"a-b"'),
        (ConfigError, {"link": "2", "loss": "130%"}, "out of range"),
        (ConfigError, {"link": "2"}, "give an impairment"),
        (ConfigError, {"link": "2", "cut": True, "restore": True}, "--restore cannot"),
        (ConfigError, {"link": "2", "rate_kbit": -5}, "--rate-kbit"),
    ]
    for error, kwargs, message in refusals:
        with pytest.raises(error) as info:
            netem_apply("refuse", **kwargs)  # type: ignore[arg-type]
        assert message in one_line_error(info), kwargs
    assert (state_dir / "refuse.json").read_text() == before
    counters = re.compile(r"packets \d+ bytes \d+")
    assert counters.sub("", open_network("refuse").rules()) == counters.sub("", rules)


@needs_root
@pytest.mark.netns
def test_cut_stops_traffic_and_restore_brings_it_back(manual: Up) -> None:
    manual(3, "cut")
    netem_apply("cut", "2-1", cut=True)
    net = open_network("cut")  # what a script would do: attach to the running network
    assert udp_one_way(net, [(1, 2), (2, 1), (1, 3), (3, 2)], SMALL) == {
        (1, 2): 0,
        (2, 1): 0,
        (1, 3): SMALL,
        (3, 2): SMALL,
    }
    netem_apply("cut", "1-2", restore=True)
    assert udp_one_way(open_network("cut"), [(1, 2), (2, 1)], SMALL) == {(1, 2): SMALL, (2, 1): SMALL}


@needs_root
@pytest.mark.netns
def test_scenario_state_at_a_time(manual: Up, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    scenario = tmp_path / "links.toml"
    scenario.write_text(
        'name = "heal"\n'
        '[[event]]\nat = 10\nlink = "1-2"\nloss = 0.3\n'
        '[[event]]\nat = 20\nlink = "3"\ncut = true\n'
        '[[event]]\nat = 30\nlink = "3"\nrestore = true\n'
    )
    manual(3, "scen")
    netem_apply("scen", "2", loss=0.5)  # replaced by the scenario's state
    expected = {
        5: Impairments(),
        15: Impairments(pairs={(1, 2): LinkProfile(loss=0.3)}),
        25: Impairments(
            pairs={(1, 2): LinkProfile(loss=0.3), (1, 3): LinkProfile(cut=True), (2, 3): LinkProfile(cut=True)}
        ),
        30: Impairments(pairs={(1, 2): LinkProfile(loss=0.3)}),
    }
    for at, imp in expected.items():
        assert netem_apply("scen", scenario=scenario, at=at) == 0
        state = load_state("scen")
        assert state is not None and state.impairments == imp, at
    assert "scenario 'heal' at 30 s (3 of 3 events so far)" in capsys.readouterr().out
    with pytest.raises(ConfigError) as info:
        netem_apply("scen", scenario=scenario)
    assert "--at" in one_line_error(info)


@needs_root
@pytest.mark.netns
def test_down_removes_namespaces_control_links_processes_and_state(
    manual: Up, capsys: pytest.CaptureFixture[str]
) -> None:
    layout = manual(2, "gone")
    netem_apply("gone", "1", loss=0.1)
    proc = subprocess.Popen(open_network("gone").exec_argv(1, ["sleep", "60"]))
    try:
        capsys.readouterr()
        assert netem_down("gone") == 0
        assert "swarm network 'gone' removed" in capsys.readouterr().out
        assert proc.wait(timeout=5) != 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert with_prefix(layout) == [] and control_links(layout) == []
    assert not state_path("gone").exists()
    assert netem_down("gone") == 0  # idempotent
    assert "nothing to remove" in capsys.readouterr().out
    with pytest.raises(NetworkNotUp) as info:
        netem_show("gone")
    assert "no swarm network named 'gone' is up" in one_line_error(info)
    with pytest.raises(NetworkNotUp):
        netem_apply("gone", "1", cut=True)


@needs_root
@pytest.mark.netns
def test_remove_leftovers_never_removes_a_manual_network(state_dir: Path, manual: Up) -> None:
    # Brought up by a process that has exited, as `swarm netem up` does: its creator is dead.
    script = "from swarm.netem.manual import netem_up; netem_up(2, 'kept')"
    subprocess.run(
        [sys.executable, "-c", script],
        check=True,
        capture_output=True,
        timeout=60,
        env={**os.environ, STATE_DIR_ENV: str(state_dir)},
    )
    state = load_state("kept")  # the `manual` fixture removes it too, should the test fail before `down`
    assert state is not None
    layout = state.layout
    try:
        assert len(with_prefix(layout)) == 3
        removed = remove_leftovers()
        assert not set(removed) & set(layout.all_namespaces())
        assert with_prefix(layout) == sorted(layout.all_namespaces())
        assert netem_show("kept") == 0
    finally:
        netem_down("kept")
    assert with_prefix(layout) == [] and control_links(layout) == []


@needs_root
@pytest.mark.netns
def test_down_all_removes_every_manual_network_and_orphans(
    manual: Up, state_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    if topology.kept_namespaces():
        pytest.skip("other kept networks exist on this machine; down --all would remove them too")
    a = manual(1, "a")
    b = manual(2, "b")
    state_path("b").unlink()  # b's namespaces are now orphans
    (state_dir / "c.json").write_text("not json")
    with pytest.raises(SwarmError) as info:
        netem_show("c")
    assert "unreadable" in one_line_error(info)
    capsys.readouterr()
    assert netem_down(all_networks=True) == 0
    out = capsys.readouterr().out
    assert "'a' removed" in out and "orphaned" in out and "unreadable state file of 'c'" in out
    assert with_prefix(a) == with_prefix(b) == [] and control_links(b) == []
    assert list(state_dir.glob("*.json")) == []
    assert netem_down(all_networks=True) == 0
    assert "no swarm network is up" in capsys.readouterr().out


@needs_root
@pytest.mark.netns
def test_attach_takes_over_without_creating_anything(manual: Up) -> None:
    layout = manual(2, "att")
    before = namespaces()
    net = SwarmNetwork.attach(layout, Impairments(pairs={(1, 2): LinkProfile(cut=True)}))
    assert net.is_up and net.keep and net.prefix == layout.prefix and namespaces() == before
    assert net.applied().pairs == {(1, 2): LinkProfile(cut=True)}
    assert net.rules().count("drop") == 0  # the table given is recorded, not loaded: nothing changed yet
    net.cut_pair(1, 2)
    assert net.rules().count("drop") == 2
