"""The figure of `swarm experiment dropout`: each figure of the missions against the loss level, in one PNG.

Panels: mission time, explored fraction, convergence (time to 95 % explored; for the cut-and-heal also the time
the maps took to converge after the heal), kB received per agent-second and leader changes. The loss levels are
a line over the loss in %; the cut-and-heal is a separate point to the right of a dotted divider; the unimpaired
baseline is a dashed reference line across each panel. A mission that did not complete is drawn with a red
cross (a timeout's time is the max time: a lower bound); one that could not run has no point.

Drawn on `Figure` + `FigureCanvasAgg` like `swarm.mission.plots`: no pyplot, no global state.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

DROPOUT_PNG = "dropout.png"

Value = Callable[[dict[str, Any]], float | None]


def _scaled(key: str, factor: float) -> Value:
    def value(row: dict[str, Any]) -> float | None:
        v = row.get(key)
        return None if v is None else float(v) * factor

    return value


HEAL_VALUE = _scaled("convergence_after_heal_s", 1.0)
PANELS: tuple[tuple[str, str, Value], ...] = (
    ("mission time", "s", _scaled("duration_s", 1.0)),
    ("explored fraction", "% of the reachable space", _scaled("explored_fraction", 100.0)),
    ("convergence", "s: to 95 % explored (★ maps converged after the heal)", _scaled("time_to_95_s", 1.0)),
    ("bandwidth", "kB received per agent-s", _scaled("bytes_per_agent_s", 1e-3)),
    ("leader changes", "count", _scaled("leader_changes", 1.0)),
)


def x_positions(rows: Sequence[dict[str, Any]]) -> tuple[list[float], float]:
    """Each row's x (its loss in %; the cut-and-heal to the right of the highest level), and the divider's x."""
    top = max((100.0 * r["loss"] for r in rows if not r["cut"]), default=0.0)
    gap = max(10.0, 0.25 * top)
    return [top + gap if r["cut"] else 100.0 * r["loss"] for r in rows], top + gap / 2


def plot_dropout(rows: Sequence[dict[str, Any]], path: Path, title: str) -> Path:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D

    xs, divider = x_positions(rows)
    ok = [r["status"] == "complete" for r in rows]
    base = next((r for r in rows if r["baseline"]), None)
    fig = Figure(figsize=(15, 9), dpi=100, layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(2, 3).ravel()
    for ax, (name, unit, value) in zip(axes, PANELS, strict=False):
        line = [(x, value(r)) for x, r in zip(xs, rows, strict=True) if not r["cut"] and value(r) is not None]
        if line:
            ax.plot(*zip(*line, strict=True), color="tab:blue", linewidth=1.5, zorder=1)
        for x, r, good in zip(xs, rows, ok, strict=True):
            v = value(r)
            if v is None:
                continue
            if good:
                ax.plot(x, v, marker="D" if r["cut"] else "o", color="tab:orange" if r["cut"] else "tab:blue", zorder=2)
            else:
                ax.plot(x, v, marker="x", color="red", markersize=9, markeredgewidth=2, zorder=3)
        if name == "convergence":
            for x, r in zip(xs, rows, strict=True):
                if r["cut"] and HEAL_VALUE(r) is not None:
                    ax.plot(x, HEAL_VALUE(r), marker="*", markersize=13, color="tab:green", zorder=2)
                if "duration_s" in r and value(r) is None:  # flown, but 95 % was never reached
                    ax.text(
                        x,
                        0.97,
                        "never",
                        transform=ax.get_xaxis_transform(),
                        ha="center",
                        va="top",
                        color="red" if r["status"] != "complete" else "black",
                        fontsize="small",
                    )
        reference = value(base) if base is not None else None
        if reference is not None:
            ax.axhline(reference, linestyle="--", color="grey", linewidth=1.0, zorder=0)
        if name == "explored fraction":
            ax.set_ylim(0.0, 102.0)
        else:
            ax.set_ylim(bottom=0.0)
        ax.set_title(name)
        ax.set_ylabel(unit)
        ax.set_xlabel("loss on every link, %")
        ticks = sorted({x for x, r in zip(xs, rows, strict=True) if not r["cut"]})
        labels = [f"{t:g}" for t in ticks]
        if any(r["cut"] for r in rows):
            ax.axvline(divider, linestyle=":", color="black", linewidth=0.8)
            ticks.append(next(x for x, r in zip(xs, rows, strict=True) if r["cut"]))
            labels.append("cut &\nheal")
        ax.set_xticks(ticks, labels)
        ax.set_xlim(min(xs) - 5.0, max(xs) + 5.0)
        ax.grid(alpha=0.3)
    key = axes[-1]
    key.axis("off")
    key.legend(
        handles=[
            Line2D([], [], color="tab:blue", marker="o", label="loss level (mission complete)"),
            Line2D([], [], color="tab:orange", marker="D", linestyle="none", label="cut and heal (mission complete)"),
            Line2D(
                [],
                [],
                color="tab:green",
                marker="*",
                markersize=13,
                linestyle="none",
                label="maps converged, s after the heal (slowest heal)",
            ),
            Line2D(
                [], [], color="red", marker="x", markeredgewidth=2, linestyle="none", label="mission did not complete"
            ),
            Line2D([], [], color="grey", linestyle="--", label="unimpaired baseline"),
        ],
        loc="center",
        fontsize="medium",
        frameon=False,
    )
    fig.suptitle(title)
    fig.savefig(path, bbox_inches="tight")
    return path
