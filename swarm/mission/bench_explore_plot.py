"""The figure of `swarm bench explore`: one PNG, one column of boxes per (strategy, swarm size).

Panels: success rate (complete, >= 95 % explored, no collision), time to 95 % and time to done over every world
and repeat (box: quartiles, whiskers: range), and the per-world ratio of the time to 95 % to the oracle's for the
same size (1 is the oracle; dashed). Drawn on `Figure` + `FigureCanvasAgg` like `swarm.mission.plots`.
"""

from __future__ import annotations

import statistics
from pathlib import Path
from typing import Any


def plot_bench_explore(
    path: Path, rows: list[dict[str, Any]], summary: list[dict[str, Any]], oracle: dict[str, dict[str, Any]]
) -> Path | None:
    """Write the figure; None (nothing written) when there is no mission."""
    if not rows or not summary:
        return None
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    keys = [(c["strategy"], c["drones"]) for c in summary]
    labels = [f"{s[:5]}. {n}" for s, n in keys]
    by_key: dict[tuple[str, int], list[dict[str, Any]]] = {k: [] for k in keys}
    for r in rows:
        by_key.setdefault((r["strategy"], r["drones"]), []).append(r)

    def t95(r: dict[str, Any]) -> float:
        return r["time_to_95_s"] if r["time_to_95_s"] is not None else r["duration_s"]

    ratios = []
    for strategy, n in keys:
        per_world: dict[str, list[float]] = {}
        for r in by_key[(strategy, n)]:
            per_world.setdefault(r.get("world", ""), []).append(t95(r))
        got = []
        for world, times in per_world.items():
            plan = oracle.get(world, {}).get(str(n))
            if plan and plan.get("time_to_95_s"):
                got.append(statistics.median(times) / plan["time_to_95_s"])
        ratios.append(got or [float("nan")])

    fig = Figure(figsize=(max(6.0, 1.2 * len(keys) + 2), 10), dpi=100)
    FigureCanvasAgg(fig)
    axes = fig.subplots(4, 1, sharex=True)
    positions = list(range(1, len(keys) + 1))
    axes[0].bar(positions, [100 * c["success_rate"] for c in summary], color="tab:green")
    axes[0].set_ylabel("success, %")
    axes[0].set_ylim(0, 105)
    axes[1].boxplot([[t95(r) for r in by_key[k]] for k in keys], positions=positions, whis=(0, 100))
    axes[1].set_ylabel("time to 95 %, s")
    axes[2].boxplot([[r["duration_s"] for r in by_key[k]] for k in keys], positions=positions, whis=(0, 100))
    axes[2].set_ylabel("time to done, s")
    axes[3].boxplot(ratios, positions=positions, whis=(0, 100))
    axes[3].axhline(1.0, linestyle="--", color="grey")
    axes[3].set_ylabel("time to 95 % / oracle")
    axes[3].set_xticks(positions, labels)
    worlds = len({r.get("world", "") for r in rows})
    axes[0].set_title(f"swarm bench explore: {len(rows)} missions on {worlds} world(s)")
    fig.savefig(path, bbox_inches="tight")
    return path
