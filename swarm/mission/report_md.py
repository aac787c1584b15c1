"""report.md and report.html: the mission report as a page a person reads (report.json stays the one for programs).

Everything on it comes from the `MissionReport`, so the page and report.json can never disagree; the figures are
the PNG files `swarm.mission.plots` wrote beside it, linked by relative name so the run directory can be moved.
report.html is the same page rendered by markdown-it with the figures inline (data URIs): one file that opens in
any browser, sent or copied alone.
"""

from __future__ import annotations

import base64
import html
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from markdown_it import MarkdownIt

from swarm.mission.rrd_files import RECORDING_NAME

if TYPE_CHECKING:
    from swarm.mission.files import LeaderEntry, MissionReport

REPORT_PAGE = "report.md"
REPORT_HTML = "report.html"
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
    ratio, repeat = report.bandwidth.baseline_ratio, report.bandwidth.patch_to_map_ratio
    rows = [("duration", _seconds(report.duration_s)), ("explored fraction", f"{report.explored_fraction:.3f}")]
    rows += [(f"time to {float(th):.0%}", _seconds(t)) for th, t in report.time_to.items()]
    rows += [
        ("collisions", str(report.collisions)),
        ("overlap fraction", f"{report.overlap_fraction:.3f}"),
        ("converged", _cell(report.converged)),
        ("phantom obstacles along the flown paths", str(report.phantoms.phantoms if report.phantoms else "-")),
        ("bandwidth (bytes per agent-second)", f"{report.bandwidth.bytes_per_agent_s}"),
        ("whole-map baseline ratio", "-" if ratio is None else f"{ratio}x"),
        ("patch bytes against the final map's", "-" if repeat is None else f"{repeat}x"),
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
        f"[`{RECORDING_NAME}`]({RECORDING_NAME}): the whole mission in 3D on a timeline (map, drones, targets, "
        "frontiers, leaders, faults; each drone's own map, paths and log in `agents/agent-K.rrd`). "
        f"Open it with `swarm view {run_dir}` (or `swarm view --web {run_dir}` without a display); "
        f"`swarm export {run_dir} --mcap BAG` writes it as a ROS 2 bag.",
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


HTML_STYLE = """
body { font-family: system-ui, sans-serif; max-width: 60rem; margin: 2rem auto; padding: 0 1rem; color: #222; }
table { border-collapse: collapse; margin: 0.5rem 0 1rem; }
th, td { border: 1px solid #ccc; padding: 0.2rem 0.6rem; text-align: left; }
th { background: #f2f2f2; }
img { max-width: 100%; }
code { background: #f4f4f4; padding: 0 0.2rem; }
"""


def render_report_html(page: str, run_dir: Path) -> str:
    """The report page as one HTML document; a figure found in run_dir is inlined as a PNG data URI, any other
    image keeps its link."""
    md = MarkdownIt("commonmark", {"html": False}).enable("table")  # text from agents is text, never markup

    def image(self: Any, tokens: Any, idx: int, options: Any, env: Any) -> str:
        name = str(tokens[idx].attrGet("src") or "")
        src, figure = name, run_dir / name
        if name and "/" not in name and figure.is_file():
            src = "data:image/png;base64," + base64.b64encode(figure.read_bytes()).decode()
        alt = html.escape(FIGURE_CAPTIONS.get(name, name), quote=True)
        return f'<img src="{html.escape(src, quote=True)}" alt="{alt}">'

    md.add_render_rule("image", image)
    title = html.escape(page.splitlines()[0].lstrip("# ") if page else "Exploration report")
    return (
        f'<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n<title>{title}</title>\n'
        f"<style>{HTML_STYLE}</style>\n</head>\n<body>\n{md.render(page)}</body>\n</html>\n"
    )


def write_report_page(run_dir: Path, report: MissionReport) -> Path:
    """Write report.md and report.html into run_dir and return report.md's path."""
    path = run_dir / REPORT_PAGE
    page = render_report_page(report, recording=(run_dir / RECORDING_NAME).exists())
    path.write_text(page)
    (run_dir / REPORT_HTML).write_text(render_report_html(page, run_dir))
    return path
