"""`swarm experiment dropout`: the same mission under increasing link loss and with a cut-and-heal.

Every condition is one real `swarm run` mission on the same world, seed and start, flown over the virtual radio
(`mission.network = "netns"`) with its own scenario file (`swarm.netem.scenario`), written into the experiment's
root as `<condition>.toml`:
- `loss-P` for each loss level (P in %): one event, `at = 0, link = "all", loss = P/100`; `loss-0` has no event
  and is the baseline, the unimpaired run every other row is compared with (always run, flown on the same
  virtual radio so the comparison is fair);
- `cut-heal` (unless disabled): the highest-numbered drone loses every link at `cut_at_s` and gets them back
  at `heal_at_s` (seconds after take-off).

A condition whose mission does not complete, or cannot run at all (a SwarmError), is a failed row and the
experiment goes on; the exit code is 1 if any condition failed. Out: the table on the console,
`experiment.json` (the rows and run directories, rewritten after every mission) and `dropout.png`.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import tomli_w
from rich.table import Table

from swarm.config import ConfigError, SwarmConfig
from swarm.errors import SwarmError
from swarm.mission.bench import _console_and_root
from swarm.mission.experiment_plot import DROPOUT_PNG, plot_dropout
from swarm.mission.run import run_mission, was_interrupted
from swarm.netem.scenario import load_scenario
from swarm.sim.worlds import mission_time_limit_s

DEFAULT_LEVELS = (0.0, 0.1, 0.3, 0.5)
EXPERIMENT_JSON = "experiment.json"
CUT_HEAL = "cut-heal"

Run = Callable[..., dict[str, Any]]


@dataclass(frozen=True)
class Condition:
    name: str  # the run directory and scenario file name
    label: str  # for people
    loss: float  # the loss on every link (0 for the baseline and the cut-and-heal)
    events: list[dict[str, Any]] = field(default_factory=list)
    cut: bool = False

    @property
    def baseline(self) -> bool:
        return self.loss == 0.0 and not self.cut


def percent(level: float) -> str:
    return f"{round(100.0 * level, 6):g}"


def conditions(
    levels: list[float], cut_and_heal: bool, drones: int, cut_at_s: float, heal_at_s: float
) -> list[Condition]:
    """The baseline (loss 0, added when missing), each loss level in ascending order, then the cut-and-heal."""
    out = []
    for level in sorted({0.0, *levels}):
        label = f"{percent(level)} % loss" + (" (baseline)" if level == 0.0 else "")
        events = [{"at": 0.0, "link": "all", "loss": level}] if level > 0.0 else []
        out.append(Condition(f"loss-{percent(level)}", label, level, events))
    if cut_and_heal:
        k = str(drones)  # the highest id: cut off from every other drone
        events = [{"at": cut_at_s, "link": k, "cut": True}, {"at": heal_at_s, "link": k, "restore": True}]
        out.append(Condition(CUT_HEAL, f"cut drone {k} at {cut_at_s:g} s, heal at {heal_at_s:g} s", 0.0, events, True))
    return out


def validate(config: SwarmConfig, levels: list[float], cut_and_heal: bool, cut_at_s: float, heal_at_s: float) -> None:
    """ConfigError (one line) for inputs the experiment cannot use."""
    for level in levels:
        if not (math.isfinite(level) and 0.0 <= level < 1.0):
            hint = f" ({level:g} % is {level / 100:g})" if 1.0 < level < 100.0 else ""
            raise ConfigError(f"loss level {level:g} is not a fraction in [0, 1){hint}")
    drones = config.mission.drones
    if drones < 2:
        raise ConfigError(f"a dropout experiment needs at least 2 drones: links join drones (got {drones})")
    if cut_and_heal:
        for what, t in (("cut", cut_at_s), ("heal", heal_at_s)):
            if not (math.isfinite(t) and t >= 0.0):
                raise ConfigError(f"the {what} time must be seconds after take-off (got {t:g})")
        if heal_at_s <= cut_at_s:
            raise ConfigError(f"the heal ({heal_at_s:g} s) must come after the cut ({cut_at_s:g} s)")
        max_time_s = mission_time_limit_s(config.mission)
        if heal_at_s >= max_time_s:
            raise ConfigError(f"the heal ({heal_at_s:g} s) would come after the mission's max time ({max_time_s:g} s)")


def write_scenarios(found: list[Condition], root: Path, drones: int) -> dict[str, Path]:
    """Each condition's scenario file in root, read back through load_scenario (ConfigError if unusable)."""
    paths: dict[str, Path] = {}
    for c in found:
        path = root / f"{c.name}.toml"
        tree: dict[str, Any] = {"name": c.name} | ({"event": c.events} if c.events else {})
        path.write_text(tomli_w.dumps(tree))
        load_scenario(path).check_drones(drones)
        paths[c.name] = path
    return paths


def condition_config(config: SwarmConfig, run_dir: Path, scenario: Path) -> SwarmConfig:
    """The mission of one condition: the experiment's config on the virtual radio with the condition's links."""
    mission = config.mission.model_copy(update={"out": run_dir, "network": "netns", "links": scenario})
    return config.model_copy(deep=True, update={"mission": mission})


def summarise(report: dict[str, Any]) -> dict[str, Any]:
    """The figures of one mission's report that the experiment compares."""
    heals = [h.get("s") for h in report.get("convergence_after_heal_s") or []]
    return {
        "status": report.get("status", "failed"),
        "reason": report.get("reason", ""),
        "duration_s": report.get("duration_s"),
        "explored_fraction": report.get("explored_fraction"),
        "time_to_95_s": (report.get("time_to") or {}).get("0.95"),
        "converged": report.get("converged"),
        "heals": len(heals),
        "heals_unconverged": sum(s is None for s in heals),
        "convergence_after_heal_s": max(heals) if heals and None not in heals else None,
        "bytes_per_agent_s": (report.get("bandwidth") or {}).get("bytes_per_agent_s"),
        "bytes_received": sum(int(a.get("bytes_received", 0)) for a in report.get("agents") or []),
        "leader_changes": report.get("leader_changes"),
        "collisions": report.get("collisions"),
        "impairments_applied": len(report.get("impairments") or []),
        "partitions": len(report.get("partitions") or []),
    }


def make_row(
    c: Condition, run_dir: Path, scenario: Path, report: dict[str, Any] | None, error: str = ""
) -> dict[str, Any]:
    """One condition's row: its figures, or only status "failed" and the error when its mission could not run."""
    row: dict[str, Any] = {"condition": c.name, "label": c.label, "loss": c.loss, "cut": c.cut, "baseline": c.baseline}
    row |= summarise(report) if report is not None else {"status": "failed", "reason": error}
    return row | {"run_dir": str(run_dir), "scenario": str(scenario)}


def _ratio(value: Any, base: Any) -> float | None:
    return round(value / base, 3) if value is not None and base else None


def relative(rows: list[dict[str, Any]]) -> None:
    """Fill each non-baseline row's `vs_baseline`: ratios of times and bandwidth, differences of the rest."""
    base = next((r for r in rows if r["baseline"] and "duration_s" in r), None)
    for r in rows:
        if r["baseline"] or base is None or "duration_s" not in r:
            r["vs_baseline"] = None
            continue
        explored = (r["explored_fraction"], base["explored_fraction"])
        leaders = (r["leader_changes"], base["leader_changes"])
        r["vs_baseline"] = {
            "duration": _ratio(r["duration_s"], base["duration_s"]),
            "time_to_95": _ratio(r["time_to_95_s"], base["time_to_95_s"]),
            "bytes_per_agent_s": _ratio(r["bytes_per_agent_s"], base["bytes_per_agent_s"]),
            "explored_points": round(100 * (explored[0] - explored[1]), 2) if None not in explored else None,
            "leader_changes": leaders[0] - leaders[1] if None not in leaders else None,
        }


def cells(r: dict[str, Any]) -> list[str]:
    """One table row: each figure, and in brackets how it compares with the baseline's."""
    if "duration_s" not in r:
        return [r["label"], r["status"]] + ["-"] * 7
    vs = r.get("vs_baseline") or {}

    def num(value: Any, fmt: str, rel: str | None = None) -> str:
        return "-" if value is None else format(value, fmt) + (f" ({rel})" if rel else "")

    def times(key: str) -> str | None:
        return None if vs.get(key) is None else f"×{vs[key]:.2f}"

    explored = None if r["explored_fraction"] is None else 100 * r["explored_fraction"]
    heal = "-" if not r["heals"] else ("never" if r["heals_unconverged"] else f"{r['convergence_after_heal_s']:.1f}")
    t95 = "never" if r["time_to_95_s"] is None else num(r["time_to_95_s"], ".1f", times("time_to_95"))
    kb = None if r["bytes_per_agent_s"] is None else r["bytes_per_agent_s"] / 1000
    points, leaders = vs.get("explored_points"), vs.get("leader_changes")
    return [
        r["label"],
        r["status"],
        num(r["duration_s"], ".1f", times("duration")),
        "-" if explored is None else f"{explored:.1f} %" + ("" if points is None else f" ({points:+.1f} pt)"),
        t95,
        {True: "yes", False: "NO"}.get(r["converged"], "-"),
        heal,
        num(kb, ".1f", times("bytes_per_agent_s")),
        num(r["leader_changes"], "d", None if leaders is None else f"{int(leaders):+d}"),
    ]


COLUMNS = (
    "condition",
    "end",
    "mission time, s",
    "explored",
    "time to 95 %, s",
    "converged",
    "convergence after heal, s",
    "kB/agent-s",
    "leader changes",
)


def table(config: SwarmConfig, rows: list[dict[str, Any]]) -> Table:
    m = config.mission
    t = Table(
        title=f"link dropout: {m.drones} drones in '{m.world}' (seed {m.seed}), one mission per row; "
        "(×ratio / difference) against the unimpaired baseline"
    )
    for column in COLUMNS:
        t.add_column(column, justify="left" if column == "condition" else "right")
    for r in rows:
        t.add_row(*cells(r), style=None if r["status"] == "complete" else "red")
    return t


def experiment_dropout(
    config: SwarmConfig,
    levels: list[float],
    cut_and_heal: bool,
    out: Path | None,
    cut_at_s: float = 20.0,
    heal_at_s: float = 50.0,
    run: Run = run_mission,
) -> int:
    validate(config, levels, cut_and_heal, cut_at_s, heal_at_s)
    found = conditions(levels, cut_and_heal, config.mission.drones, cut_at_s, heal_at_s)
    console, root = _console_and_root(out)
    busy = [root / c.name for c in found if (root / c.name).is_dir() and any((root / c.name).iterdir())]
    if busy:
        raise ConfigError(f"output directory {busy[0]} is not empty (choose another --out)")
    root.mkdir(parents=True, exist_ok=True)
    scenarios = write_scenarios(found, root, config.mission.drones)
    m = config.mission
    summary: dict[str, Any] = {
        "experiment": "dropout",
        "world": str(m.world),
        "drones": m.drones,
        "seed": m.seed,
        "levels": [c.loss for c in found if not c.cut],
        "cut_and_heal": {"drone": m.drones, "cut_at_s": cut_at_s, "heal_at_s": heal_at_s} if cut_and_heal else None,
        "rows": [],
        "plot": None,
    }
    rows: list[dict[str, Any]] = summary["rows"]
    for i, c in enumerate(found, 1):
        console.print(
            f"experiment dropout ({i}/{len(found)}): {c.label}, {m.drones} drones in '{m.world}' (seed {m.seed}) ...",
            markup=False,
        )
        rows.append(_run_condition(config, c, root / c.name, scenarios[c.name], run))
        console.print(f"  {_outcome(rows[-1])}", markup=False)
        relative(rows)
        (root / EXPERIMENT_JSON).write_text(json.dumps(summary, indent=2))
        if was_interrupted(rows[-1]):
            console.print("experiment dropout: interrupted", markup=False)
            break
    console.print(table(config, rows))
    failed = [r for r in rows if r["status"] != "complete"]
    for r in failed:
        console.print(f"{r['condition']}: {_outcome(r)}", style="red", markup=False)
    try:
        title = f"link dropout: {m.drones} drones in '{m.world}' (seed {m.seed})"
        summary["plot"] = plot_dropout(rows, root / DROPOUT_PNG, title).name
    except Exception as exc:  # noqa: BLE001 - the table and the runs are kept; say what went wrong, and fail
        console.print(f"figure not written: {type(exc).__name__}: {exc}", style="red", markup=False)
    (root / EXPERIMENT_JSON).write_text(json.dumps(summary, indent=2))
    console.print(f"scenarios: {root}/<condition>.toml; runs (report.md each): {root}/<condition>/", markup=False)
    figure = f"; figure: {root / summary['plot']}" if summary["plot"] else ""
    console.print(f"table: {root / EXPERIMENT_JSON}{figure}", markup=False)
    return 1 if failed or not summary["plot"] else 0


def _run_condition(config: SwarmConfig, c: Condition, run_dir: Path, scenario: Path, run: Run) -> dict[str, Any]:
    try:
        report = run(condition_config(config, run_dir, scenario), live=False)
    except SwarmError as exc:  # the mission could not run (or stopped); the others still can
        return make_row(c, run_dir, scenario, None, str(exc))
    return make_row(c, run_dir, scenario, report)


def _outcome(row: dict[str, Any]) -> str:
    return row["status"] + (f": {row['reason']}" if row["status"] != "complete" and row["reason"] else "")
