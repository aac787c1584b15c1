"""Planner timings on the 30 x 20 x 3 m office at 0.2 m: `.venv/bin/python -m tests.explore.bench_planner`."""

from __future__ import annotations

import time

from swarm.explore.planner import path_length, plan_path
from tests.explore.synthetic import office_grid

REPEATS = 5
CASES = [
    ("3D, far corner", (1.0, 1.0, 1.5), (29.0, 19.0, 1.5), None),
    ("3D, far corner, climbing", (1.0, 1.0, 0.8), (29.0, 19.0, 1.9), None),
    ("3D, same side, 28 m", (1.0, 1.0, 1.5), (29.0, 1.0, 1.5), None),
    ("z band 1.0..2.0 m", (1.0, 1.0, 1.5), (29.0, 19.0, 1.5), (1.0, 2.0)),
    ("single layer 1.5 m", (1.0, 1.0, 1.5), (29.0, 19.0, 1.5), (1.5, 1.5)),
]


def main() -> None:
    raw = office_grid()
    started = time.perf_counter()
    grid = raw.inflate(0.3)
    print(f"grid {raw.shape}, inflate(0.3): {(time.perf_counter() - started) * 1000:.0f} ms")
    for name, start, goal, z_limits in CASES:
        times = []
        for _ in range(REPEATS):
            started = time.perf_counter()
            path = plan_path(grid, start, goal, z_limits=z_limits)
            times.append(time.perf_counter() - started)
        print(
            f"{name:26s} first {times[0] * 1000:4.0f} ms, best {min(times) * 1000:4.0f} ms,"
            f" {len(path)} waypoints, {path_length(path):.1f} m"
        )


if __name__ == "__main__":
    main()
