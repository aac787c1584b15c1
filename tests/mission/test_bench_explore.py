"""`swarm bench explore`: the world list, the summary of repeated missions over several worlds (fed rows shaped
like `_row`'s), the oracle's cache, and the order of the missions with a fake `run_mission` and oracle (the
missions themselves are real in every other test, the oracle in test_oracle)."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest

from swarm.config import SwarmConfig, load_config
from swarm.errors import WorldError
from swarm.mission.bench_explore import bench_explore, expand_worlds, oracle_times, summarise
from swarm.mission.run import INTERRUPTED
from tests.file_models import agent_row_data, mission_report_data
from tests.helpers import swarm_cmd


def _run(strategy: str, drones: int, t95: float | None, duration: float = 300.0, **extra: object) -> dict:
    return {
        "strategy": strategy,
        "drones": drones,
        "status": "complete",
        "duration_s": duration,
        "explored_fraction": 0.97,
        "time_to_95_s": t95,
        "distance_per_drone_m": 100.0 / drones,
        "overlap_fraction": 0.5,
        "bytes_per_agent_s": 40_000.0,
        "collisions": 0,
        **extra,
    }


def test_cells_take_medians_and_ranges_and_ratios_use_the_one_drone_median() -> None:
    rows = [
        _run("coordinated", 1, 100.0),
        _run("coordinated", 1, 180.0),
        _run("coordinated", 1, 140.0),
        _run("coordinated", 3, 50.0),
        _run("coordinated", 3, 70.0),
        _run("coordinated", 3, 60.0, collisions=1),
    ]
    one, three = summarise(rows)
    assert (one["drones"], one["missions"]) == (1, 3)
    assert one["time_to_95_s"] == {"median": 140.0, "q1": 120.0, "q3": 160.0, "min": 100.0, "max": 180.0}
    assert one["vs_1_drone"] == 1.0
    assert three["time_to_95_s"]["median"] == 60.0
    assert three["vs_1_drone"] == round(60.0 / 140.0, 3)
    assert three["collisions"] == 1 and three["complete"] == 3


def test_the_closest_approach_is_the_smallest_measured_in_any_mission() -> None:
    rows = [
        _run("coordinated", 3, 50.0, closest_world_m=None),
        _run("coordinated", 3, 60.0, closest_world_m=0.12),
        _run("coordinated", 3, 70.0, closest_world_m=0.04),
        _run("coordinated", 1, 100.0, closest_world_m=None),
    ]
    three, one = summarise(rows)
    assert three["closest_world_m"] == 0.04
    assert one["closest_world_m"] is None  # never under the simulator's NEAR_GAP_M


def test_a_mission_that_never_reached_95_percent_counts_as_its_whole_duration_and_is_counted() -> None:
    rows = [
        _run("uncoordinated", 2, 80.0),
        _run("uncoordinated", 2, None, duration=420.0, status="timeout"),
        _run("uncoordinated", 2, 90.0),
    ]
    (cell,) = summarise(rows)
    assert cell["reached_95"] == 2 and cell["complete"] == 2
    assert (cell["time_to_95_s"]["median"], cell["time_to_95_s"]["min"], cell["time_to_95_s"]["max"]) == (
        90.0,
        80.0,
        420.0,
    )
    assert cell["vs_1_drone"] is None  # no one-drone cell for this strategy


def test_each_strategy_is_compared_with_its_own_single_drone_cell() -> None:
    rows = [
        _run("coordinated", 1, 100.0),
        _run("coordinated", 3, 45.0),
        _run("uncoordinated", 1, 200.0, same_as="coordinated"),
        _run("uncoordinated", 3, 60.0),
    ]
    by_key = {(c["strategy"], c["drones"]): c for c in summarise(rows)}
    assert by_key["coordinated", 3]["vs_1_drone"] == 0.45
    assert by_key["uncoordinated", 3]["vs_1_drone"] == 0.3
    assert by_key["uncoordinated", 1]["same_as"] == "coordinated"


def _report(cfg: SwarmConfig, reason: str = "") -> dict:
    return {
        "status": "failed" if reason else "complete",
        "reason": reason,
        "duration_s": 100.0,
        "explored_fraction": 0.97,
        "time_to": {"0.95": 80.0},
        "agents": [{"distance_m": 50.0, "closest_world_m": 0.1}, {"distance_m": 40.0, "closest_world_m": None}],
        "overlap_fraction": 0.5,
        "bandwidth": {"bytes_per_agent_s": 40_000.0},
        "collisions": 0,
        "run_dir": str(cfg.mission.out),
    }


def _no_oracle(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(
        "swarm.mission.bench_explore.oracle_times",
        lambda cfg, sizes, cache: {str(n): {"time_to_95_s": 50.0 / n, "views": 9} for n in sizes},
    )


def test_the_single_drone_missions_are_flown_once_and_an_interrupted_mission_ends_the_bench(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _no_oracle(monkeypatch)
    flown: list[tuple[str, int]] = []

    def fake_run(cfg: SwarmConfig, live: bool | None = None) -> dict:  # stands in for the missions only
        flown.append((cfg.explore.strategy, cfg.mission.drones))
        return _report(cfg, INTERRUPTED if len(flown) == 4 else "")

    monkeypatch.setattr("swarm.mission.bench_explore.run_mission", fake_run)
    code = bench_explore(load_config(), [1, 3], ["coordinated", "uncoordinated"], tmp_path, repeats=2)
    # coordinated 1 (x2) and 3 (x2), then the interrupt: no uncoordinated mission (its 1-drone rows are copies)
    assert flown == [("coordinated", 1), ("coordinated", 1), ("coordinated", 3), ("coordinated", 3)]
    assert code == 1
    runs = json.loads((tmp_path / "bench-explore.json").read_text())["runs"]
    assert [(r["strategy"], r["drones"], r["repeat"]) for r in runs] == [
        ("coordinated", 1, 1),
        ("coordinated", 1, 2),
        ("coordinated", 3, 1),
        ("coordinated", 3, 2),
    ]


def test_every_mission_is_flown_in_order_and_one_drone_only_for_the_first_strategy(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _no_oracle(monkeypatch)
    flown: list[tuple[str, int]] = []

    def fake_run(cfg: SwarmConfig, live: bool | None = None) -> dict:
        flown.append((cfg.explore.strategy, cfg.mission.drones))
        return _report(cfg)

    monkeypatch.setattr("swarm.mission.bench_explore.run_mission", fake_run)
    assert bench_explore(load_config(), [1, 3], ["coordinated", "uncoordinated"], tmp_path, repeats=2) == 0
    assert (tmp_path / "bench-explore.png").stat().st_size > 0
    assert flown == [("coordinated", 1)] * 2 + [("coordinated", 3)] * 2 + [("uncoordinated", 3)] * 2
    runs = json.loads((tmp_path / "bench-explore.json").read_text())["runs"]
    copies = [r for r in runs if r.get("same_as")]
    assert [(r["strategy"], r["drones"], r["repeat"], r["same_as"]) for r in copies] == [
        ("uncoordinated", 1, 1, "coordinated"),
        ("uncoordinated", 1, 2, "coordinated"),
    ]


def test_a_seed_range_expands_to_each_seed_and_keeps_its_options() -> None:
    assert expand_worlds("gen:1..3") == ["gen:1", "gen:2", "gen:3"]
    assert expand_worlds("office, gen:7..8:size=30x20,hall.ply,gen:4") == [
        "office",
        "gen:7:size=30x20",
        "gen:8:size=30x20",
        "hall.ply",
        "gen:4",
    ]
    assert expand_worlds("gen:5..5") == ["gen:5"]
    assert expand_worlds("gen:1..2:size=20x15,doors=1.1-1.4,office,gen:3:storeys=2,rooms=4") == [
        "gen:1:size=20x15,doors=1.1-1.4",
        "gen:2:size=20x15,doors=1.1-1.4",
        "office",
        "gen:3:storeys=2,rooms=4",
    ]
    assert expand_worlds("gen:1..2,doors=1.2") == ["gen:1:doors=1.2", "gen:2:doors=1.2"]


@pytest.mark.parametrize(
    "bad, says",
    [("gen:5..2", "backwards"), ("gen:x..y", "whole numbers"), ("gen:1..", "whole numbers"), ("office,,box", "empty")],
)
def test_a_malformed_world_list_is_one_clear_error(bad: str, says: str) -> None:
    with pytest.raises(WorldError, match=says) as info:
        expand_worlds(bad)
    assert "\n" not in str(info.value)


def test_an_unknown_world_stops_the_bench_before_any_mission(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    flown: list[str] = []
    monkeypatch.setattr("swarm.mission.bench_explore.run_mission", lambda cfg, live=None: flown.append("x"))
    _no_oracle(monkeypatch)
    with pytest.raises(WorldError, match="atlantis"):
        bench_explore(load_config(), [1], ["coordinated"], tmp_path, worlds=["box", "atlantis"])
    assert flown == [] and not (tmp_path / "bench-explore.json").exists()


def test_over_several_worlds_ratios_are_per_world_then_the_median_and_early_completions_are_named() -> None:
    rows = [
        _run("coordinated", 1, 100.0, world="a"),
        _run("coordinated", 3, 40.0, world="a"),
        _run("coordinated", 1, 200.0, world="b"),
        _run("coordinated", 3, 100.0, world="b"),
        _run("coordinated", 1, 50.0, world="c"),
        _run("coordinated", 3, 30.0, world="c", collisions=1),
        _run("coordinated", 1, None, world="d", explored_fraction=0.3, duration=15.0, repeat=2),
    ]
    oracle = {
        "a": {"1": {"time_to_95_s": 50.0}, "3": {"time_to_95_s": 20.0}},
        "b": {"1": {"time_to_95_s": 100.0}, "3": {"time_to_95_s": 40.0}},
        "c": {"1": {"time_to_95_s": 50.0}, "3": {"time_to_95_s": None}},
        "d": {"1": {"time_to_95_s": 30.0}},
    }
    one, three = summarise(rows, oracle)
    assert (one["worlds"], one["missions"], one["success"]) == (4, 4, 3)
    assert one["success_rate"] == 0.75
    assert one["complete_below_95"] == ["d #2: 30.0 %"]  # complete at 30 %: never hidden
    assert one["vs_oracle"] == 1.5  # median of 2.0, 2.0, 1.0, 0.5
    assert one["time_to_done_s"]["median"] == 300.0 and one["time_to_done_s"]["min"] == 15.0
    assert three["vs_1_drone"] == 0.5  # median of 0.4, 0.5, 0.6
    assert three["vs_oracle"] == 2.25  # worlds a (2.0) and b (2.5); c has no oracle time
    assert (three["success"], three["collisions"], three["complete_below_95"]) == (2, 1, [])


def test_the_oracle_is_computed_once_per_world_and_size_and_then_read_from_the_cache(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    config = load_config(overrides={"mission.world": "box"})
    first = oracle_times(config, [1, 2], tmp_path)
    assert first["1"]["time_to_95_s"] >= first["2"]["time_to_95_s"] > 0
    assert len(list(tmp_path.glob("box-*.json"))) == 2

    def no_oracle(*args: object, **kwargs: object) -> None:
        raise AssertionError("computed again")

    monkeypatch.setattr("swarm.mission.oracle.Oracle", no_oracle)
    assert oracle_times(config, [1, 2], tmp_path) == first
    slower = config.model_copy(update={"agent": config.agent.model_copy(update={"cruise_speed_m_s": 0.5})})
    with pytest.raises(AssertionError, match="computed again"):
        oracle_times(slower, [1], tmp_path)  # another setting the oracle depends on: not the cached plan


@pytest.mark.parametrize(
    "worlds, says", [("gen:5..2", "backwards"), ("gen:x..y", "gen:A..B"), ("box,atlantis", "atlantis")]
)
@pytest.mark.sim
def test_bad_worlds_on_the_command_line_are_one_line_and_a_non_zero_exit_before_any_mission(
    tmp_path: Path, worlds: str, says: str
) -> None:
    out = tmp_path / "bench"
    result = subprocess.run(
        swarm_cmd("bench", "explore", "--worlds", worlds, "--drones", "1", "--out", str(out)),
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    lines = result.stderr.strip().splitlines()
    assert result.returncode != 0 and len(lines) == 1 and says in lines[0], result.stderr
    assert not (out / "bench-explore.json").exists()


def test_resume_keeps_the_missions_flown_to_their_end_and_flies_the_rest(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A bench of 40 missions takes hours; one stopped half way (Ctrl-C) picks up where it stopped."""
    _no_oracle(monkeypatch)
    flown: list[tuple[str, int, str]] = []
    stop_at = [3]

    def fake_run(cfg: SwarmConfig, live: bool | None = None) -> dict:  # writes report.json as a mission does
        flown.append((cfg.explore.strategy, cfg.mission.drones, cfg.mission.world))
        short = _report(cfg, INTERRUPTED if len(flown) == stop_at[0] else "")
        mission = {"world": cfg.mission.world, "strategy": cfg.explore.strategy, "seed": cfg.mission.seed}
        report = mission_report_data(
            **{key: short[key] for key in ("status", "reason", "duration_s", "explored_fraction", "run_dir")},
            drones=cfg.mission.drones,
            mission={**mission_report_data()["mission"], **mission},
            agents=[agent_row_data(k, distance_m=d) for k, d in ((1, 50.0), (2, 40.0))],
        )
        assert cfg.mission.out is not None
        cfg.mission.out.mkdir(parents=True, exist_ok=True)
        (cfg.mission.out / "report.json").write_text(json.dumps(report))
        return report

    monkeypatch.setattr("swarm.mission.bench_explore.run_mission", fake_run)
    worlds = ["office", "warehouse"]
    assert bench_explore(load_config(), [1, 3], ["coordinated"], tmp_path, worlds=worlds) == 1  # stopped at 3
    first = list(flown)
    stop_at[0] = 0
    assert bench_explore(load_config(), [1, 3], ["coordinated"], tmp_path, worlds=worlds, resume=True) == 0
    assert first == [("coordinated", 1, "office"), ("coordinated", 3, "office"), ("coordinated", 1, "warehouse")]
    # the interrupted mission is flown again, the two finished ones are not
    assert flown[3:] == [("coordinated", 1, "warehouse"), ("coordinated", 3, "warehouse")]
    runs = json.loads((tmp_path / "bench-explore.json").read_text())["runs"]
    assert [(r["world"], r["drones"]) for r in runs] == [
        ("office", 1),
        ("office", 3),
        ("warehouse", 1),
        ("warehouse", 3),
    ]
