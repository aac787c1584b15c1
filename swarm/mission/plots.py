"""The exploration report's figures: PNG files beside report.json, drawn with matplotlib's Agg renderer.

One function per figure. Each takes plain data (what report.json, observer.json and the agents' summaries hold)
and a path, and returns the path, or None when there is nothing to draw: a run that never took off still gets
its report, with fewer figures. matplotlib is imported inside the drawing functions only, so nothing else in the
swarm pays for importing it; figures are built on `Figure` + `FigureCanvasAgg`, never pyplot, so no display,
no global figure state, and no backend switch that could surprise a caller.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from swarm.errors import WorldError

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from swarm.agent.summary import AgentSummary
    from swarm.mission.files import MissionReport, ObserverStatus
    from swarm.sim.worlds import World

log = logging.getLogger(__name__)

EXPLORED_PNG = "explored.png"
TRAJECTORIES_PNG = "trajectories.png"
LEADERS_PNG = "leaders.png"
BYTES_PNG = "bytes.png"
PLOT_NAMES = (EXPLORED_PNG, TRAJECTORIES_PNG, LEADERS_PNG, BYTES_PNG)

COVERAGE_TARGET = 0.95  # the dotted line on the explored figure: the coverage a mission is judged by
FLOOR_RESOLUTION_M = 0.1
FLOOR_LIFT_M = 1.0  # the floor plan is cut at flight height, where the walls the drones flew between are
FLOOR_SURFACE_M = 0.05  # closer than this to the mesh counts as wall: thin (open-mesh) walls have no inside
LAST_STATE_MIN_S = 0.5  # the last leader state is drawn at least this long, so a final change stays visible
SOLID_GREY = "#404040"

Segment = tuple[float, float, int]  # (start t, end t, leader followed)


@dataclass
class FloorPlan:
    """A horizontal cut through the world: solid cells (dark grey on the trajectories figure)."""

    solid: np.ndarray  # (ny, nx) bool, row j is y, column i is x
    extent: tuple[float, float, float, float]  # xmin, xmax, ymin, ymax of the cells' outer edges
    z: float


# --- pure data ---------------------------------------------------------------------------------------------------


def floor_plan(
    world: World, lo: Sequence[float], hi: Sequence[float], z: float, resolution: float = FLOOR_RESOLUTION_M
) -> FloorPlan:
    """Solid cells of a grid over the xy of [lo, hi) at height z: inside a solid or within 5 cm of the mesh."""
    xs = np.arange(lo[0] + resolution / 2, hi[0], resolution)
    ys = np.arange(lo[1] + resolution / 2, hi[1], resolution)
    gx, gy = np.meshgrid(xs, ys)  # (ny, nx)
    points = np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, z)])
    solid = np.zeros(len(points), dtype=bool)
    if len(points):
        solid = world.is_inside_solid(points) | (world.distance(points) < FLOOR_SURFACE_M)
    extent = (float(lo[0]), float(lo[0] + len(xs) * resolution), float(lo[1]), float(lo[1] + len(ys) * resolution))
    return FloorPlan(solid.reshape(gx.shape), extent, float(z))


def report_floor_plan(report: MissionReport) -> FloorPlan | None:
    """The floor plan of the report's world at home floor + 1 m over the mission volume, or None when the world
    cannot be loaded any more (a mesh file moved since the run): the trajectories are still worth drawing."""
    from swarm.sim.worlds import load_world

    spec = report.mission.world or report.world
    if not spec:
        return None
    try:
        world = load_world(spec)
    except WorldError as exc:
        log.warning("no floor plan: %s", exc)
        return None
    lo, hi = report.mission.volume.min, report.mission.volume.max
    spawns = report.mission.spawns
    home_z = float(spawns[0][2]) if spawns else float(world.default_start[2])
    return floor_plan(world, lo, hi, home_z + FLOOR_LIFT_M)


def leader_segments(leaders: Sequence[Mapping[str, Any]], end_t: float) -> dict[int, list[Segment]]:
    """Per drone, the time spans it followed each leader, from the observer's leader timeline.

    Entries with the same t are one state of the swarm; a state lasts until the next one (the last until end_t).
    A drone missing from a state (landed, silent) has no span then. Adjacent spans with one leader are merged.
    """
    states: list[tuple[float, dict[int, int]]] = []
    for entry in leaders:
        t = float(entry["t"])
        if not states or states[-1][0] != t:
            states.append((t, {}))
        for member in entry["members"]:
            states[-1][1][int(member)] = int(entry["leader"])
    segments: dict[int, list[Segment]] = {}
    for i, (t, following) in enumerate(states):
        t_end = states[i + 1][0] if i + 1 < len(states) else max(end_t, t + LAST_STATE_MIN_S)
        for member, leader in following.items():
            spans = segments.setdefault(member, [])
            if spans and spans[-1][2] == leader and spans[-1][1] == t:
                spans[-1] = (spans[-1][0], t_end, leader)
            else:
                spans.append((t, t_end, leader))
    return dict(sorted(segments.items()))


def received_rate(timeline: Sequence[Sequence[float]]) -> tuple[np.ndarray, np.ndarray]:
    """(t, received kB/s) from an agent's cumulative [t, bytes_sent, bytes_received] samples: the rate over each
    interval, stamped at its end. Intervals that do not move forward in time are dropped."""
    samples = np.asarray(timeline, dtype=np.float64).reshape(-1, 3)
    if len(samples) < 2:
        return np.zeros(0), np.zeros(0)
    dt = np.diff(samples[:, 0])
    received = np.diff(samples[:, 2])
    forward = dt > 0
    return samples[1:, 0][forward], received[forward] / dt[forward] / 1000.0


def _by_id(data: Mapping[Any, Any]) -> list[tuple[int, Any]]:
    """JSON objects key agents by strings; sort them as the numbers they are."""
    return sorted(((int(k), v) for k, v in data.items()), key=lambda kv: kv[0])


# --- figures -----------------------------------------------------------------------------------------------------


def _figure(width: float, height: float) -> tuple[Figure, Axes]:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=100)
    FigureCanvasAgg(fig)
    return fig, fig.add_subplot()


def _save(fig: Figure, path: Path) -> Path:
    fig.savefig(path, bbox_inches="tight")
    return path


def _colour(index: int) -> Any:
    """A stable colour per drone or leader id, so one drone has one colour on every figure."""
    from matplotlib import colormaps

    return colormaps["tab10"]((index - 1) % 10)


def plot_explored(
    timeline: Sequence[Sequence[float]], by_agent: Mapping[Any, Sequence[Sequence[float]]], path: Path
) -> Path | None:
    """Explored fraction over time: the swarm's fused map thick, each drone's own contribution thin."""
    agents = [(k, v) for k, v in _by_id(by_agent) if v]
    if not timeline and not agents:
        return None
    fig, ax = _figure(8, 4.5)
    for k, series in agents:
        t, f = np.asarray(series, dtype=float).T
        ax.plot(t, f, linewidth=1.0, color=_colour(k), label=f"drone {k}")
    if timeline:
        t, f = np.asarray(timeline, dtype=float).T
        ax.plot(t, f, linewidth=2.8, color="black", label="swarm (fused)")
    ax.axhline(COVERAGE_TARGET, linestyle=":", color="grey", label=f"{COVERAGE_TARGET:.0%}")
    ax.set_ylim(0.0, 1.02)
    ax.set_xlabel("time since start (s)")
    ax.set_ylabel("explored fraction of the reachable space")
    ax.legend(loc="lower right", fontsize="small")
    ax.grid(alpha=0.3)
    return _save(fig, path)


def plot_trajectories(
    trajectories: Mapping[Any, Sequence[Sequence[float]]], plan: FloorPlan | None, path: Path
) -> Path | None:
    """Each drone's xy track (start o, end s) over the floor plan at flight height."""
    tracks = [(k, v) for k, v in _by_id(trajectories) if v]
    if not tracks:
        return None
    from matplotlib.colors import ListedColormap

    fig, ax = _figure(9, 7)
    if plan is not None and plan.solid.size:
        walls = np.ma.masked_where(~plan.solid, plan.solid.astype(float))
        ax.imshow(walls, origin="lower", extent=plan.extent, cmap=ListedColormap([SOLID_GREY]), interpolation="nearest")
        ax.set_xlim(plan.extent[0], plan.extent[1])
        ax.set_ylim(plan.extent[2], plan.extent[3])
    for k, samples in tracks:
        xyz = np.asarray(samples, dtype=float)[:, 1:3]
        colour = _colour(k)
        ax.plot(xyz[:, 0], xyz[:, 1], linewidth=1.2, color=colour, label=f"drone {k}")
        ax.plot(*xyz[0], marker="o", color=colour)
        ax.plot(*xyz[-1], marker="s", color=colour)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m, east)")
    ax.set_ylabel("y (m, north)")
    title = "trajectories" + (f" over the floor plan at z = {plan.z:.2f} m" if plan is not None else "")
    ax.set_title(title)
    ax.legend(loc="upper right", fontsize="small")
    return _save(fig, path)


def plot_leaders(leaders: Sequence[Mapping[str, Any]], end_t: float, path: Path) -> Path | None:
    """Who followed whom over time: one row per drone coloured by its leader; a leader's own row is bold."""
    segments = leader_segments(leaders, end_t)
    if not segments:
        return None
    from matplotlib.patches import Patch

    fig, ax = _figure(9, 1.0 + 0.5 * len(segments))
    rows = list(segments)
    for row, agent in enumerate(rows):
        for t0, t1, leader in segments[agent]:
            bold = leader == agent
            height = 0.8 if bold else 0.5
            ax.broken_barh(
                [(t0, t1 - t0)],
                (row - height / 2, height),
                facecolors=_colour(leader),
                edgecolors="black" if bold else "none",
                linewidth=2.0 if bold else 0.0,
            )
    leader_ids = sorted({leader for spans in segments.values() for _, _, leader in spans})
    ax.legend(
        handles=[Patch(color=_colour(k), label=f"leader {k}") for k in leader_ids], loc="upper right", fontsize="small"
    )
    ax.set_yticks(range(len(rows)), [f"drone {k}" for k in rows])
    ax.set_ylim(-0.7, len(rows) - 0.3)
    ax.set_xlabel("time since start (s)")
    ax.set_title("clusters: leader followed by each drone (a drone leading is outlined)")
    return _save(fig, path)


def plot_bytes(timelines: Mapping[int, Sequence[Sequence[float]]], path: Path) -> Path | None:
    """Received bus traffic per drone in kB/s, differenced from the agents' cumulative counters."""
    rates = [(k, received_rate(v)) for k, v in sorted(timelines.items()) if v]
    rates = [(k, (t, r)) for k, (t, r) in rates if len(t)]
    if not rates:
        return None
    fig, ax = _figure(8, 4.5)
    for k, (t, rate) in rates:
        ax.step(t, rate, where="pre", color=_colour(k), linewidth=1.2, label=f"drone {k}")
    ax.set_xlabel("time since the agent started (s)")
    ax.set_ylabel("received (kB/s)")
    ax.set_ylim(bottom=0.0)
    ax.legend(loc="upper right", fontsize="small")
    ax.grid(alpha=0.3)
    return _save(fig, path)


def write_plots(
    run_dir: Path, report: MissionReport, observer: ObserverStatus | None, summaries: Mapping[int, AgentSummary]
) -> list[str]:
    """Draw every figure the run has data for into run_dir; the file names written, relative to run_dir.

    The figures take plain JSON data (the files' content), so each can be drawn from any run directory."""
    by_agent = report.explored_by_agent or (observer.explored_by_agent if observer is not None else {})
    trajectories = observer.trajectories if observer is not None else {}
    leaders = [e.model_dump() for e in (report.leaders or (observer.leaders if observer is not None else []))]
    end_t = observer.t if observer is not None else report.duration_s
    written = [
        plot_explored(report.explored_timeline, by_agent, run_dir / EXPLORED_PNG),
        plot_trajectories(
            trajectories, report_floor_plan(report) if trajectories else None, run_dir / TRAJECTORIES_PNG
        ),
        plot_leaders(leaders, end_t, run_dir / LEADERS_PNG),
        plot_bytes({k: s.timeline for k, s in summaries.items()}, run_dir / BYTES_PNG),
    ]
    return [path.relative_to(run_dir).as_posix() for path in written if path is not None]
