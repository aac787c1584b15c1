"""Link loss end to end (issue 6): real `swarm run --network netns` missions under link scenarios.

Each agent runs in its own network namespace on a virtual radio (veth + bridge); the scenario's loss and cuts are
real nftables rules in the hub namespace; MAVLink and the observer use the never-impaired control links.
Assertions come from the report (simulator truth, the observer, the link controller's records) and the agents'
logs. After each mission no namespace, control link or rule of it may be left, also when the test fails.
"""

from __future__ import annotations

import re
import subprocess
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from swarm.config import load_config
from swarm.mission.run import RunState, run_mission
from swarm.netem import remove_leftovers
from swarm.netem.commands import namespaces, tool
from tests.helpers import SwarmPorts
from tests.netem.measure import netem_problem

pytestmark = [
    pytest.mark.netns,
    pytest.mark.timeout(300),
    pytest.mark.skipif(netem_problem() is not None, reason=netem_problem() or ""),
]


def _swarm_links() -> list[str]:
    out = subprocess.run([tool("ip"), "-o", "link", "show"], capture_output=True, text=True, check=True).stdout
    return [line.split(":")[1].strip() for line in out.splitlines() if line.split(":")[1].strip().startswith("sw")]


@pytest.fixture
def nothing_left_behind() -> Iterator[list[str]]:
    """Records the namespaces each mission created (via on_tick) and checks they are all gone afterwards."""
    remove_leftovers()
    before = set(namespaces())
    seen: list[str] = []
    yield seen
    left = sorted(set(namespaces()) - before)
    links = _swarm_links()
    remove_leftovers()
    assert seen, "the mission never created its network"
    assert not left, f"namespaces left behind: {left}"
    assert not links, f"control links left behind: {links}"


def _config(out: Path, ports: SwarmPorts, scenario: Path, **overrides: Any):
    return load_config(
        overrides={
            "mission.world": "box",
            "mission.out": str(out),
            "mission.drones": 3,
            "mission.max_time_s": 150.0,
            "mission.network": "netns",
            "mission.links": str(scenario),
            **ports.settings(),
            **overrides,
        }
    )


def _record_namespaces(seen: list[str]):
    def on_tick(state: RunState) -> None:
        if not seen and state.net is not None:
            seen.extend(state.net.layout.all_namespaces())
            assert set(seen) <= set(namespaces())

    return on_tick


def test_a_mission_with_30_percent_loss_on_every_link_completes_and_converges(
    tmp_path: Path, swarm_ports: SwarmPorts, nothing_left_behind: list[str]
) -> None:
    scenario = tmp_path / "loss30.toml"
    scenario.write_text('name = "loss-30"\n[[event]]\nat = 0\nlink = "all"\nloss = 0.3\n')
    report = run_mission(
        _config(tmp_path / "run", swarm_ports, scenario), live=False, on_tick=_record_namespaces(nothing_left_behind)
    )

    assert report["status"] == "complete", report["reason"]
    assert report["network"] == "netns"
    assert report["explored_fraction"] >= 0.95
    assert report["converged"], [(a["id"], a["patches_held"]) for a in report["agents"]]
    applied = {(i["link"], i["profile"], i["backend"]) for i in report["impairments"]}
    assert applied == {(pair, "loss 0.3", "nftables") for pair in ("1-2", "1-3", "2-3")}
    assert report["partitions"] == []  # loss is not a partition
    received = [a["bytes_received"] for a in report["agents"]]
    assert min(received) > 0, "the agents must have talked over the lossy radio"


def test_a_cut_splits_the_swarm_into_two_clusters_and_the_heal_merges_them_and_their_maps(
    tmp_path: Path, swarm_ports: SwarmPorts, nothing_left_behind: list[str]
) -> None:
    cut_at, heal_at = 6.0, 16.0
    scenario = tmp_path / "cut.toml"
    scenario.write_text(
        'name = "cut-and-heal"\n'
        f'[[event]]\nat = {cut_at}\nlink = "3"\ncut = true\n'
        f'[[event]]\nat = {heal_at}\nlink = "3"\nrestore = true\n'
    )
    report = run_mission(
        _config(tmp_path / "run", swarm_ports, scenario), live=False, on_tick=_record_namespaces(nothing_left_behind)
    )

    assert report["status"] == "complete", report["reason"]
    takeoff = report["scenario"]["takeoff_t"]
    cut_t, heal_t = takeoff + cut_at, takeoff + heal_at
    [partition] = report["partitions"]
    assert partition["components"] == [[1, 2], [3]]
    assert partition["start"] == pytest.approx(cut_t, abs=0.6) and partition["end"] == pytest.approx(heal_t, abs=0.6)

    def clusters_at(t: float) -> set[tuple[int, tuple[int, ...]]]:
        """The swarm's own clusters (observer's leader timeline) in force at time t."""
        times = [e["t"] for e in report["leaders"] if e["t"] <= t]
        last = max(times) if times else None
        return {(e["leader"], tuple(e["members"])) for e in report["leaders"] if e["t"] == last}

    during = [clusters_at(e["t"]) for e in report["leaders"] if cut_t < e["t"] < heal_t]
    assert {(1, (1, 2)), (3, (3,))} in during, f"no two-cluster state during the cut: {during}"
    after = [clusters_at(e["t"]) for e in report["leaders"] if e["t"] > heal_t]
    assert {(1, (1, 2, 3))} in after, f"the clusters never merged after the heal: {after}"

    [heal] = report["convergence_after_heal_s"]
    assert heal["heal_t"] == pytest.approx(heal_t, abs=0.6)
    assert heal["members"] == [1, 2, 3] and heal["patches"] > 0
    # about 3 s: the links come back (lease and connect retry) and the pull replies arrive whole; before the data
    # queue held a pull's burst (BusSettings.data_queue_batches), dropped replies made this 6-15 s
    assert heal["s"] is not None and heal["s"] < 6.0, heal
    assert report["converged"]
    # Zenoh logs a routing error when it re-establishes a healed link inconsistently (see RADIO_PROTOCOLS).
    zenoh_errors = [
        line
        for k in (1, 2, 3)
        for line in (tmp_path / "run" / "logs" / f"agent-{k}.log").read_text(errors="replace").splitlines()
        if " ERROR " in _plain(line)
    ]
    assert not zenoh_errors, zenoh_errors[:3]


def _plain(line: str) -> str:
    """A log line without terminal colour codes."""
    return re.sub(r"\x1b\[[0-9;]*m", "", line)
