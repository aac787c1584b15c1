"""report.md: the mission report as a page a person reads (report.json stays the one for programs).

Everything on it comes from the report dict, so the page and report.json can never disagree; the figures are
the PNG files `swarm.mission.plots` wrote beside it, linked by relative name so the run directory can be moved.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

REPORT_PAGE = "report.md"
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


def headline_rows(report: dict[str, Any]) -> list[tuple[str, str]]:
    """The figures a run is judged by, formatted: how fast and how much it explored, and what it cost."""
    bandwidth = report.get("bandwidth", {})
    ratio = bandwidth.get("baseline_ratio")
    rows = [
        ("duration", _seconds(report.get("duration_s", 0.0))),
        ("explored fraction", f"{float(report.get('explored_fraction', 0.0)):.3f}"),
    ]
    rows += [(f"time to {float(th):.0%}", _seconds(t)) for th, t in report.get("time_to", {}).items()]
    rows += [
        ("collisions", str(report.get("collisions", 0))),
        ("overlap fraction", f"{float(report.get('overlap_fraction', 0.0)):.3f}"),
        ("converged", _cell(report.get("converged"))),
        ("phantom obstacles along the flown paths", str((report.get("phantoms") or {}).get("phantoms", "-"))),
        ("bandwidth (bytes per agent-second)", f"{bandwidth.get('bytes_per_agent_s', 0.0)}"),
        ("whole-map baseline ratio", "-" if ratio is None else f"{ratio}x"),
    ]
    return rows


def agent_rows(report: dict[str, Any]) -> list[list[Any]]:
    return [
        [
            a.get("id"),
            a.get("distance_m"),
            a.get("patches_sealed"),
            a.get("patches_held"),
            a.get("targets_assigned", 0),
            a.get("targets_self_selected", 0),
            a.get("landed"),
            a.get("exit_code"),
        ]
        for a in report.get("agents", [])
    ]


def leader_lines(leaders: Sequence[dict[str, Any]], limit: int = LEADER_ENTRIES_SHOWN) -> list[str]:
    """The first `limit` cluster entries as list items; the rest are counted, not listed (they are in the JSON)."""
    if not leaders:
        return ["No cluster was reported."]
    lines = [
        f"- {float(e['t']):.1f} s: drone {e['leader']} leads {', '.join(str(m) for m in e['members'])}"
        for e in leaders[:limit]
    ]
    if len(leaders) > limit:
        lines.append(f"- ... {len(leaders) - limit} more entries in report.json")
    return lines


def render_report_page(report: dict[str, Any]) -> str:
    mission = report.get("mission", {})
    strategy = mission.get("strategy") or "unspecified"
    lines = [
        f"# Exploration report: {report.get('world', '?')}, {report.get('drones', '?')} drones, strategy {strategy}",
        "",
        f"**Status: {report.get('status', '?')}**: {report.get('reason', '')}",
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
        *leader_lines(report.get("leaders", [])),
        "",
    ]
    for name in report.get("plots", []):
        lines += [f"## {FIGURE_CAPTIONS.get(name, name)}", "", f"![]({name})", ""]
    return "\n".join(lines)


def write_report_page(run_dir: Path, report: dict[str, Any]) -> Path:
    """Write report.md into run_dir and return its path."""
    path = run_dir / REPORT_PAGE
    path.write_text(render_report_page(report))
    return path
