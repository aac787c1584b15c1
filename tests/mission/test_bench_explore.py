"""`swarm bench explore`'s summary of repeated missions (one function, fed rows shaped like `_row`'s)."""

from __future__ import annotations

from swarm.mission.bench_explore import summarise


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
