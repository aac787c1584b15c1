"""report.md: the mission report as a page a person reads (report.json stays the one for programs).

Everything on it comes from the `MissionReport`, so the page and report.json can never disagree; the figures are
the PNG files `swarm.mission.plots` wrote beside it, linked by relative name so the run directory can be moved.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from swarm.mission.files import LeaderEntry, MissionReport

REPORT_PAGE = "report.md"
RECORDING = "run.rrd"  # swarm.mission.recording.RECORDING_NAME (not imported: that module imports rerun)
LEADER_ENTRIES_SHOWN = 20

FIGURE_CAPTIONS = {
    "explored.png": "Explored fraction over time",
    "trajectories.png": "Trajectories",
    "leaders.png": "Clusters over time",
    "bytes.png": "Received traffic per drone",
}


def _cell(value: Any) -> str:
    """A table cell: pipes escaped (they would split the cell), None as a dash."""
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    return str(value).replace("|", "\\|")


def _table(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(_cell(v) for v in row) + " |" for row in rows]
    return lines


def _seconds(value: Any) -> str:
    return "never" if value is None else f"{float(value):.1f} s"


def headline_rows(report: MissionReport) -> list[tuple[str, str]]:
    """The figures a run is judged by, formatted: how fast and how much it explored, and what it cost."""
    ratio = report.bandwidth.baseline_ratio
    rows = [("duration", _seconds(report.duration_s)), ("explored fraction", f"{report.explored_fraction:.3f}")]
    rows += [(f"time to {float(th):.0%}", _seconds(t)) for th, t in report.time_to.items()]
    rows += [
        ("collisions", str(report.collisions)),
        ("overlap fraction", f"{report.overlap_fraction:.3f}"),
        ("converged", _cell(report.converged)),
        ("phantom obstacles along the flown paths", str(report.phantoms.phantoms if report.phantoms else "-")),
        ("bandwidth (bytes per agent-second)", f"{report.bandwidth.bytes_per_agent_s}"),
        ("whole-map baseline ratio", "-" if ratio is None else f"{ratio}x"),
    ]
    return rows


def agent_rows(report: MissionReport) -> list[list[Any]]:
    return [
        [
            a.id,
            a.distance_m,
            a.patches_sealed,
            a.patches_held,
            a.targets_assigned,
            a.targets_self_selected,
            a.landed,
            a.exit_code,
        ]
        for a in report.agents
    ]


def leader_lines(leaders: Sequence[LeaderEntry], limit: int = LEADER_ENTRIES_SHOWN) -> list[str]:
    """The first `limit` cluster entries as list items; the rest are counted, not listed (they are in the JSON)."""
    if not leaders:
        return ["No cluster was reported."]
    lines = [f"- {e.t:.1f} s: drone {e.leader} leads {', '.join(str(m) for m in e.members)}" for e in leaders[:limit]]
    if len(leaders) > limit:
        lines.append(f"- ... {len(leaders) - limit} more entries in report.json")
    return lines


def recording_lines(run_dir: str) -> list[str]:
    """How to open the run's recording."""
    return [
        "## Recording",
        "",
        f"[`{RECORDING}`]({RECORDING}): the whole mission in 3D on a timeline (map, drones, targets, frontiers, "
        "leaders, faults). Open it with `swarm view " + run_dir + "` (or `swarm view --web " + run_dir + "` "
        "without a display); `swarm export " + run_dir + " --mcap BAG` writes it as a ROS 2 bag.",
        "",
    ]


def defence_lines(report: MissionReport) -> list[str]:
    """One line per drone that left input out or failed to store, naming the counts; one line when none did."""
    lines = []
    for agent in report.agents:
        parts = [
            f"{name.replace('_', ' ')}: " + ", ".join(f"{reason} {count}" for reason, count in counts.items())
            for name, counts in agent.defences.model_dump().items()
            if counts
        ]
        if parts:
            lines.append(f"- drone {agent.id}: " + "; ".join(parts))
    return lines or ["No drone dropped, rejected or failed to store anything."]


def render_report_page(report: MissionReport, recording: bool = False) -> str:
    strategy = report.mission.strategy or "unspecified"
    lines = [
        f"# Exploration report: {report.world}, {report.drones} drones, strategy {strategy}",
        "",
        f"**Status: {report.status}**: {report.reason}",
        "",
        "## Headline figures",
        "",
        *_table(["figure", "value"], headline_rows(report)),
        "",
        "## Drones",
        "",
        *_table(
            [
                "drone",
                "distance (m)",
                "patches sealed",
                "patches held",
                "targets assigned",
                "targets self-selected",
                "landed",
                "exit code",
            ],
            agent_rows(report),
        ),
        "",
        "## Leader timeline",
        "",
        *leader_lines(report.leaders),
        "",
        "## Input left out (defences)",
        "",
        *defence_lines(report),
        "",
        *(recording_lines(report.run_dir) if recording else []),
    ]
    for name in report.plots:
        lines += [f"## {FIGURE_CAPTIONS.get(name, name)}", "", f"![]({name})", ""]
    return "\n".join(lines)


def write_report_page(run_dir: Path, report: MissionReport) -> Path:
    """Write report.md into run_dir and return its path."""
    path = run_dir / REPORT_PAGE
    path.write_text(render_report_page(report, recording=(run_dir / RECORDING).exists()))
    return path
