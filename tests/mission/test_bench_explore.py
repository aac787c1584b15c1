"""`swarm bench explore`: the summary of repeated missions (fed rows shaped like `_row`'s), and the order of the
missions with a fake `run_mission` (the missions themselves are real in every other test)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from swarm.config import SwarmConfig, load_config
from swarm.mission.bench_explore import bench_explore, summarise
from swarm.mission.run import INTERRUPTED


def _run(strategy: str, drones: int, t95: float | None, duration: float = 300.0, **extra: object) -> dict:
    return {
        "strategy": strategy, "drones": drones, "status": "complete", "duration_s": duration,
        "explored_fraction": 0.97, "time_to_95_s": t95, "distance_per_drone_m": 100.0 / drones,
        "overlap_fraction": 0.5, "bytes_per_agent_s": 40_000.0, "collisions": 0, **extra,
    }


def test_cells_take_medians_and_ranges_and_ratios_use_the_one_drone_median() -> None:
    rows = [
        _run("coordinated", 1, 100.0), _run("coordinated", 1, 180.0), _run("coordinated", 1, 140.0),
        _run("coordinated", 3, 50.0), _run("coordinated", 3, 70.0), _run("coordinated", 3, 60.0, collisions=1),
    ]
    one, three = summarise(rows)
    assert (one["drones"], one["missions"], one["time_to_95_s"]) == (1, 3, {"median": 140.0, "min": 100.0, "max": 180.0})
    assert one["vs_1_drone"] == 1.0
    assert three["time_to_95_s"]["median"] == 60.0
    assert three["vs_1_drone"] == round(60.0 / 140.0, 3)
    assert three["collisions"] == 1 and three["complete"] == 3


def test_the_closest_approach_is_the_smallest_measured_in_any_mission() -> None:
    rows = [_run("coordinated", 3, 50.0, closest_world_m=None), _run("coordinated", 3, 60.0, closest_world_m=0.12),
            _run("coordinated", 3, 70.0, closest_world_m=0.04), _run("coordinated", 1, 100.0, closest_world_m=None)]
    three, one = summarise(rows)
    assert three["closest_world_m"] == 0.04
    assert one["closest_world_m"] is None  # never under the simulator's NEAR_GAP_M


def test_a_mission_that_never_reached_95_percent_counts_as_its_whole_duration_and_is_counted() -> None:
    rows = [_run("uncoordinated", 2, 80.0), _run("uncoordinated", 2, None, duration=420.0, status="timeout"),
            _run("uncoordinated", 2, 90.0)]
    (cell,) = summarise(rows)
    assert cell["reached_95"] == 2 and cell["complete"] == 2
    assert cell["time_to_95_s"] == {"median": 90.0, "min": 80.0, "max": 420.0}
    assert cell["vs_1_drone"] is None  # no one-drone cell for this strategy


def test_each_strategy_is_compared_with_its_own_single_drone_cell() -> None:
    rows = [_run("coordinated", 1, 100.0), _run("coordinated", 3, 45.0),
            _run("uncoordinated", 1, 200.0, same_as="coordinated"), _run("uncoordinated", 3, 60.0)]
    by_key = {(c["strategy"], c["drones"]): c for c in summarise(rows)}
    assert by_key["coordinated", 3]["vs_1_drone"] == 0.45
    assert by_key["uncoordinated", 3]["vs_1_drone"] == 0.3
    assert by_key["uncoordinated", 1]["same_as"] == "coordinated"


def _report(cfg: SwarmConfig, reason: str = "") -> dict:
    return {
        "status": "failed" if reason else "complete", "reason": reason, "duration_s": 100.0,
        "explored_fraction": 0.97, "time_to": {"0.95": 80.0},
        "agents": [{"distance_m": 50.0, "closest_world_m": 0.1}, {"distance_m": 40.0, "closest_world_m": None}],
        "overlap_fraction": 0.5, "bandwidth": {"bytes_per_agent_s": 40_000.0}, "collisions": 0,
        "run_dir": str(cfg.mission.out),
    }


def test_the_single_drone_missions_are_flown_once_and_an_interrupted_mission_ends_the_bench(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
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
        ("coordinated", 1, 1), ("coordinated", 1, 2), ("coordinated", 3, 1), ("coordinated", 3, 2)]


def test_every_mission_is_flown_in_order_and_one_drone_only_for_the_first_strategy(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    flown: list[tuple[str, int]] = []

    def fake_run(cfg: SwarmConfig, live: bool | None = None) -> dict:
        flown.append((cfg.explore.strategy, cfg.mission.drones))
        return _report(cfg)

    monkeypatch.setattr("swarm.mission.bench_explore.run_mission", fake_run)
    assert bench_explore(load_config(), [1, 3], ["coordinated", "uncoordinated"], tmp_path, repeats=2) == 0
    assert flown == [("coordinated", 1)] * 2 + [("coordinated", 3)] * 2 + [("uncoordinated", 3)] * 2
    runs = json.loads((tmp_path / "bench-explore.json").read_text())["runs"]
    copies = [r for r in runs if r.get("same_as")]
    assert [(r["strategy"], r["drones"], r["repeat"], r["same_as"]) for r in copies] == [
        ("uncoordinated", 1, 1, "coordinated"), ("uncoordinated", 1, 2, "coordinated")]
