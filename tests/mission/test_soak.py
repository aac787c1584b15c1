"""`swarm soak` (issue 7): missions back to back with random faults and loss, memory and fd growth per agent,
patches lost. The 20-minute soak itself is run by hand (README); here one real mission goes through it."""

from __future__ import annotations

import contextlib
import random
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest
from rich.console import Console

from swarm.config import FaultSpec, load_config
from swarm.mission import soak as soak_module
from swarm.mission.soak import MAX_GROWTH, AgentSampler, PatchAudit, audit, random_fault, soak, summarise
from tests.helpers import SwarmPorts


def test_random_faults_are_valid_specs_of_every_kind() -> None:
    rng = random.Random(1)
    specs = [FaultSpec.model_validate(random_fault(rng, 3)) for _ in range(200)]
    assert {s.kind for s in specs} == {"kill", "restart", "freeze", "telemetry-loss"}
    assert {s.agent for s in specs} == {1, 2, 3}


def _mission(
    status: str = "complete", lost: int = 0, growth: float | None = 0.05, converged: bool = True, unknown: int = 0
) -> dict:
    agent = {
        "agent": "agent-1",
        "pid": 1,
        "warm_rss_mb": 100.0,
        "peak_rss_mb": 105.0,
        "rss_growth": growth,
        "warm_fds": 30,
        "peak_fds": 32,
    }
    return {
        "status": status,
        "converged": converged,
        "patches_sealed": 10,
        "patches_lost": lost,
        "patches": {"unknown": unknown},
        "agents": [agent],
    }


@pytest.mark.parametrize(
    ("missions", "passed"),
    [
        ([_mission(), _mission(growth=MAX_GROWTH)], True),
        ([_mission(), _mission(status="failed")], False),
        ([_mission(lost=1)], False),
        ([_mission(converged=False)], False),
        ([_mission(unknown=1)], False),
        ([_mission(growth=MAX_GROWTH + 0.01)], False),
        ([_mission(growth=None)], False),  # nothing measured is not a pass
        ([], False),
    ],
)
def test_the_soak_passes_only_when_every_mission_completes_nothing_is_lost_and_memory_holds(
    missions: list[dict], passed: bool
) -> None:
    assert summarise(missions)["passed"] is passed


def test_an_agent_that_exited_but_is_not_reaped_yet_is_not_sampled(monkeypatch: pytest.MonkeyPatch) -> None:
    """A zombie reads an RSS of 0: taken as the warm sample, it made the growth a division by zero (a one-mission
    soak failed so when an agent exited just as its warm-up ended)."""
    clock = [100.0]
    monkeypatch.setattr(soak_module.time, "monotonic", lambda: clock[0])
    rss = [0]

    class Zombie:  # psutil.Process of an exited agent: only what the sampler reads
        def __init__(self, pid: int) -> None:
            pass

        def oneshot(self) -> Any:
            return contextlib.nullcontext()

        def memory_info(self) -> Any:
            return SimpleNamespace(rss=rss[0])

        def num_fds(self) -> int:
            return 9

    monkeypatch.setattr(soak_module.psutil, "Process", Zombie)
    agent = SimpleNamespace(pid=4242, name="agent-2", poll=lambda: None)
    state = SimpleNamespace(agents={2: agent})
    sampler = AgentSampler()
    rss[0] = 150 * 2**20
    sampler(state)  # type: ignore[arg-type]  # first seen: warming up
    clock[0] += soak_module.WARMUP_S + 1.0
    rss[0] = 0
    sampler(state)  # type: ignore[arg-type]
    [sample] = sampler.samples.values()
    assert sample.warm_rss is None and sample.as_dict()["rss_growth"] is None
    rss[0] = 160 * 2**20
    sampler(state)  # type: ignore[arg-type]
    assert sample.warm_rss == 160 * 2**20 and sample.as_dict()["rss_growth"] == 0.0


def test_a_patch_is_lost_when_a_survivor_lacks_it_holds_other_bytes_or_its_seq_is_a_hole() -> None:
    sealed = {"1.5.0": "a", "1.5.1": "b", "1.5.3": "d", "2.7.0": "e"}  # 1.5.2 was never written: a hole
    everything = set(sealed)
    assert audit(sealed, [(everything, dict(sealed)), (everything, dict(sealed))]) == PatchAudit(sealed=4, gaps=1)
    # the old rule (some survivor holds it) passed this: the second survivor lacks 2.7.0
    lacking = audit(sealed, [(everything, dict(sealed)), (everything - {"2.7.0"}, {})])
    assert lacking.missing == 1 and lacking.lost == 2
    altered = audit(sealed, [(everything, {**sealed, "1.5.1": "forged"})])
    assert altered.altered == 1 and altered.lost == 2
    extra = audit(sealed, [(everything | {"3.1.0"}, dict(sealed))])
    assert extra.unknown == 1 and extra.lost == 1
    assert audit({}, []) == PatchAudit()


@pytest.mark.mission
@pytest.mark.netns  # as root the soak flies on a netns radio: with the other namespace tests, one at a time
def test_a_one_mission_soak_flies_a_real_mission_and_measures_every_agent(
    tmp_path: Path, swarm_ports: SwarmPorts
) -> None:
    config = load_config(
        overrides={"mission.world": "box", "mission.drones": 3, "mission.max_time_s": 150.0, **swarm_ports.settings()}
    )
    result = soak(config, minutes=0.01, out=tmp_path / "soak", seed=4, console=Console(stderr=True))

    [mission] = result["missions"]
    assert mission["status"] == "complete", mission["reason"]
    FaultSpec.model_validate(mission["fault"])
    assert mission["patches_sealed"] > 0 and mission["patches_lost"] == 0, mission["patches"]
    assert mission["converged"] and mission["patches"]["unknown"] == 0
    sampled = [a for a in mission["agents"] if a["rss_growth"] is not None]
    assert sampled, "no agent lived past its warm-up"
    for agent in sampled:
        assert 50 < agent["warm_rss_mb"] <= agent["peak_rss_mb"] < 2000
        assert 3 <= agent["warm_fds"] <= agent["peak_fds"]
    assert (tmp_path / "soak" / "soak.json").is_file()
    assert result["summary"]["missions"] == 1 and result["summary"]["patches_lost"] == 0


@pytest.mark.sim
def test_bad_minutes_is_one_line_and_exit_2(tmp_path: Path) -> None:
    done = subprocess.run(
        [sys.executable, "-m", "swarm", "soak", "--minutes", "0"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        "swarm soak: config error: --minutes must be more than 0 and at most 1440, got 0.0"
    ]
