"""`swarm bench explore`: exploration on many worlds, against one drone and against the oracle.

For every world x swarm size x strategy x repeat it runs a real `swarm run` mission (same seed and start), and for
every world x size the oracle (`swarm.mission.oracle`: routes planned on the true mesh that see 95 % of the
reachable space, at cruise speed, for the same number of drones; cached per world and size in OUT/oracle/).
Worlds: `--worlds SPEC[,SPEC...]`, a spec being a built-in name, a mesh file or `gen:A..B[:options]` (seeds A to
B of the generated worlds, each `gen:SEED[:options]`); `--world` for one. Every spec is loaded before the first
mission, so a bad one is one line and no mission.

Per (strategy, size) the summary gives: the success rate (a mission succeeds when it ends `complete` with at least
95 % explored and no collision), the missions that ended `complete` below 95 % (named: exploration declared done
early, never to be hidden in a median), the distribution (median, quartiles, range) of the time to 95 % and of the
time to done (every drone landed: the mission's duration), and medians over worlds of the per-world ratios of the
time to 95 % to the one-drone time (same strategy, same world) and to the oracle's (same size), plus distance per
drone, overlap (share of the explored space seen by two or more drones), bytes received per agent-second, the
collisions and the closest approach to the world (the simulator's: a near miss shows before a contact does).

Repeats matter: the simulator is deterministic but the agents are not (asyncio scheduling on shared cores, bus
timing), and one drone's time to 95 % in the office has ranged from 101 s to 176 s over identical missions. A
mission that never reached 95 % counts as its whole duration in the time to 95 % (it is at least that slow).
"""

from __future__ import annotations

import hashlib
import json
import logging
import re
import statistics
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console
from rich.table import Table

from swarm.config import SwarmConfig
from swarm.errors import WorldError
from swarm.files import FileFormatError
from swarm.mission.bench import _console_and_root
from swarm.mission.bench_explore_plot import plot_bench_explore
from swarm.mission.report import read_report
from swarm.mission.run import run_mission, was_interrupted
from swarm.sim.collisions import NEAR_GAP_M
from swarm.sim.worlds import load_world

log = logging.getLogger(__name__)

STRATEGIES = ("coordinated", "uncoordinated")
SUCCESS_FRACTION = 0.95
ORACLE_VERSION = 1  # bump when the oracle's method changes: cached plans are then computed again
_GEN_RANGE = re.compile(r"^gen:(?P<range>[^:]*\.\.[^:]*)(?P<options>:.*)?$")
_OPTION = re.compile(r"[a-z_]+=[^:/]*")  # an option of the gen: spec before it, not a world of its own


def expand_worlds(text: str) -> list[str]:
    """The world specs of a comma-separated list, `gen:A..B[:options]` expanded to gen:A[:options] ... gen:B;
    WorldError (one line) for a malformed range. An item `key=value` after a `gen:` spec is one more of its
    options (`gen:1..4:size=20x15,doors=1.1-1.4` and `gen:1..4,doors=1.2` are one range each)."""
    parts: list[str] = []
    for part in (p.strip() for p in text.split(",")):
        if not part:
            raise WorldError(f"empty world in the list '{text}'")
        if _OPTION.fullmatch(part) and parts and parts[-1].startswith("gen:"):
            parts[-1] += f"{',' if ':' in parts[-1][4:] else ':'}{part}"
        else:
            parts.append(part)
    specs: list[str] = []
    for part in parts:
        match = _GEN_RANGE.match(part)
        if match is None:
            specs.append(part)
            continue
        first, _, last = match["range"].partition("..")
        if not (first.isdigit() and last.isdigit()):
            raise WorldError(f"world range '{part}' is not gen:A..B with seeds A <= B (whole numbers)")
        a, b = int(first), int(last)
        if a > b:
            raise WorldError(f"world range '{part}' runs backwards: use gen:{b}..{a}")
        specs.extend(f"gen:{seed}{match['options'] or ''}" for seed in range(a, b + 1))
    return specs


def check_worlds(specs: list[str]) -> None:
    """Load every world once, so that a bad spec fails before the first mission (raises WorldError)."""
    for spec in specs:
        load_world(spec)


def bench_explore(
    config: SwarmConfig,
    sizes: list[int],
    strategies: list[str] | None = None,
    out: Path | None = None,
    repeats: int = 1,
    worlds: list[str] | None = None,
    resume: bool = False,
) -> int:
    console, root = _console_and_root(out)
    worlds = worlds or [config.mission.world]
    check_worlds(worlds)
    root.mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, Any]] = []
    oracle: dict[str, dict[str, Any]] = {}
    chosen = strategies or list(STRATEGIES)
    interrupted = False
    for w, world in enumerate(worlds, start=1):
        world_config = config.model_copy(deep=True)
        world_config.mission.world = world
        console.print(
            f"bench explore: oracle for '{world}' (world {w} of {len(worlds)}), "
            f"{', '.join(map(str, sizes))} drone(s) ...",
            markup=False,
        )
        oracle[world] = oracle_times(world_config, sizes, root / "oracle")
        where = root if len(worlds) == 1 else root / _slug(world)
        for strategy, n, repeat in _missions(chosen, sizes, repeats):
            if n == 1 and strategy != chosen[0]:
                # one drone is its own leader and picks by Eq. 3.3 either way: the same missions, flown once
                rows.extend(
                    {**r, "strategy": strategy, "same_as": chosen[0]}
                    for r in rows
                    if r["world"] == world and r["drones"] == 1 and r["strategy"] == chosen[0] and r["repeat"] == repeat
                )
                continue
            run_config = world_config.model_copy(deep=True)
            run_config.mission.drones = n
            run_config.explore.strategy = strategy  # type: ignore[assignment]
            run_config.mission.out = where / (f"{strategy}-{n}" if repeats == 1 else f"{strategy}-{n}-{repeat}")
            console.print(
                f"bench explore: {strategy}, {n} drone(s) in '{world}' (world {w} of {len(worlds)}, "
                f"seed {config.mission.seed}), mission {repeat} of {repeats} ...",
                markup=False,
            )
            report = _finished_report(run_config) if resume else None
            if report is not None:
                console.print(f"bench explore: kept the finished mission in {run_config.mission.out}", markup=False)
            else:
                report = run_mission(run_config, live=False)
            rows.append({**_row(strategy, n, report), "world": world, "repeat": repeat})
            _write(root, rows, oracle)
            if was_interrupted(report):
                console.print("bench explore: interrupted", markup=False)
                interrupted = True
                break
        if interrupted:
            break
    summary = summarise(rows, oracle)
    _write(root, rows, oracle)
    _print(console, config, worlds, summary, oracle, repeats)
    plot_bench_explore(root / "bench-explore.png", rows, summary, oracle)
    console.print(
        f"figures: {root / 'bench-explore.json'}, {root / 'bench-explore.png'}; runs (report.md each): {root}"
    )
    return 0 if rows and all(is_success(r) for r in rows) else 1


def _finished_report(config: SwarmConfig) -> dict[str, Any] | None:
    """The report of a mission already flown in `config.mission.out` with the same world, drones, strategy and
    seed, that ran to its end (not interrupted); None otherwise. A bench of 40 missions takes hours: `--resume`
    picks up where an interrupted one stopped."""
    assert config.mission.out is not None
    try:
        report = read_report(config.mission.out / "report.json")
    except OSError:
        return None
    except FileFormatError as exc:
        log.warning("flying it again: %s", exc)
        return None
    mission = report.mission
    same = (mission.world, report.drones, mission.strategy, mission.seed) == (
        str(config.mission.world),
        config.mission.drones,
        config.explore.strategy,
        config.mission.seed,
    )
    data = json.loads(report.to_json())
    return data if same and not was_interrupted(data) else None


def is_success(row: dict[str, Any]) -> bool:
    return row["status"] == "complete" and row["explored_fraction"] >= SUCCESS_FRACTION and row["collisions"] == 0


def oracle_times(config: SwarmConfig, sizes: list[int], cache: Path) -> dict[str, Any]:
    """The oracle's plan summary per size ("1", "3", ...) for the world of `config`, from OUT/oracle/ when a plan
    with the same key (world, settings it depends on, method version) is there."""
    from swarm.mission.oracle import Oracle

    cache.mkdir(parents=True, exist_ok=True)
    key = _oracle_key(config)
    digest = hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:12]
    out: dict[str, Any] = {}
    oracle = None
    for n in sizes:
        path = cache / f"{_slug(config.mission.world)}-{n}-{digest}.json"
        if path.exists():
            try:
                out[str(n)] = json.loads(path.read_text())["plan"]
                continue
            except (OSError, ValueError, KeyError):
                pass  # unreadable: compute again
        if oracle is None:
            oracle = Oracle(load_world(config.mission.world), config)
        plan = oracle.plan(n).to_json()
        summary = {
            k: plan[k]
            for k in (
                "drones",
                "time_to_95_s",
                "coverage",
                "best_possible",
                "route_m",
                "drone_s",
                "candidates",
                "compute_s",
                "notes",
            )
        }
        summary["views"] = len(plan["views"])
        path.write_text(
            json.dumps({"key": key, "plan": summary, "routes": plan["routes"], "views": plan["views"]}, indent=1)
        )
        out[str(n)] = summary
    return out


def _oracle_key(config: SwarmConfig) -> dict[str, Any]:
    m = config.mission
    key: dict[str, Any] = {
        "version": ORACLE_VERSION,
        "world": m.world,
        "start": m.start,
        "spawn_spacing_m": m.spawn_spacing_m,
        "volume": m.volume.model_dump() if m.volume else None,
        "camera": config.camera.model_dump(mode="json"),
        "altitude_m": config.agent.altitude_m,
        "cruise_speed_m_s": config.agent.cruise_speed_m_s,
        "max_speed_up_m_s": config.sim.max_speed_up_m_s,
        "drone_radius_m": config.sim.drone_radius_m,
        "planning_resolution_m": config.mapping.planning_resolution_m,
        "explore": {
            k: getattr(config.explore, k)
            for k in ("clearance_m", "body_height_m", "min_altitude_m", "ceiling_margin_m", "dwell_s")
        },
    }
    path = Path(m.world)
    if path.is_file():  # a mesh file: a changed file is another world
        stat = path.stat()
        key["file"] = {"size": stat.st_size, "mtime_ns": stat.st_mtime_ns}
    return key


def _slug(spec: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.=-]+", "_", spec).strip("_") or "world"


def _missions(strategies: list[str], sizes: list[int], repeats: int) -> Iterator[tuple[str, int, int]]:
    for strategy in strategies:
        for n in sizes:
            for repeat in range(1, repeats + 1):
                yield strategy, n, repeat


def _write(root: Path, rows: list[dict[str, Any]], oracle: dict[str, dict[str, Any]]) -> None:
    (root / "bench-explore.json").write_text(
        json.dumps({"runs": rows, "oracle": oracle, "summary": summarise(rows, oracle)}, indent=2)
    )


def _row(strategy: str, n: int, report: dict[str, Any]) -> dict[str, Any]:
    agents = report["agents"]
    return {
        "strategy": strategy,
        "drones": n,
        "status": report["status"],
        "reason": report.get("reason", ""),
        "duration_s": report["duration_s"],
        "explored_fraction": report["explored_fraction"],
        "time_to_95_s": report["time_to"]["0.95"],
        "time_to": report["time_to"],
        "distance_per_drone_m": round(sum(a["distance_m"] for a in agents) / max(1, len(agents)), 1),
        "overlap_fraction": report["overlap_fraction"],
        "bytes_per_agent_s": report["bandwidth"]["bytes_per_agent_s"],
        "collisions": report["collisions"],
        "closest_world_m": _smallest(a.get("closest_world_m") for a in agents),
        "run_dir": report["run_dir"],
    }


def _t95(row: dict[str, Any]) -> float:
    """Time to 95 %; a mission that never reached it took at least its whole duration."""
    return row["time_to_95_s"] if row["time_to_95_s"] is not None else row["duration_s"]


def _spread(values: list[float]) -> dict[str, float]:
    q1, median, q3 = (float(v) for v in np.percentile(values, [25, 50, 75]))
    return {"median": median, "q1": q1, "q3": q3, "min": min(values), "max": max(values)}


def _median_or_none(values: list[float]) -> float | None:
    return round(statistics.median(values), 3) if values else None


def summarise(rows: list[dict[str, Any]], oracle: dict[str, dict[str, Any]] | None = None) -> list[dict[str, Any]]:
    """One cell per (strategy, drones), in the order first flown, over every world and repeat (see the module
    docstring). Ratios are per world (medians of its missions) and then the median over the worlds that have
    both figures; `oracle` maps world -> size ("3") -> plan summary with time_to_95_s."""
    oracle = oracle or {}
    cells: dict[tuple[str, int], list[dict[str, Any]]] = {}
    for r in rows:
        cells.setdefault((r["strategy"], r["drones"]), []).append(r)

    def per_world(strategy: str, n: int) -> dict[str, float]:
        by_world: dict[str, list[float]] = {}
        for r in cells.get((strategy, n), []):
            by_world.setdefault(r.get("world", ""), []).append(_t95(r))
        return {w: statistics.median(v) for w, v in by_world.items()}

    summary = []
    for (strategy, n), runs in cells.items():
        t95 = [_t95(r) for r in runs]
        mine, single = per_world(strategy, n), per_world(strategy, 1)
        vs_one = [mine[w] / single[w] for w in mine if single.get(w)]
        vs_oracle = []
        for w, t in mine.items():
            plan = oracle.get(w, {}).get(str(n))
            if plan and plan.get("time_to_95_s"):
                vs_oracle.append(t / plan["time_to_95_s"])
        early = [r for r in runs if r["status"] == "complete" and r["explored_fraction"] < SUCCESS_FRACTION]
        summary.append(
            {
                "strategy": strategy,
                "drones": n,
                "same_as": runs[0].get("same_as"),
                "worlds": len({r.get("world", "") for r in runs}),
                "missions": len(runs),
                "success": sum(is_success(r) for r in runs),
                "success_rate": round(sum(is_success(r) for r in runs) / len(runs), 3),
                "complete": sum(r["status"] == "complete" for r in runs),
                "complete_below_95": [
                    f"{r.get('world', '?')} #{r.get('repeat', 1)}: {100 * r['explored_fraction']:.1f} %" for r in early
                ],
                "reached_95": sum(r["time_to_95_s"] is not None for r in runs),
                "time_to_95_s": _spread(t95),
                "time_to_done_s": _spread([r["duration_s"] for r in runs]),
                "explored_fraction": statistics.median(r["explored_fraction"] for r in runs),
                "distance_per_drone_m": statistics.median(r["distance_per_drone_m"] for r in runs),
                "overlap_fraction": statistics.median(r["overlap_fraction"] for r in runs),
                "bytes_per_agent_s": statistics.median(r["bytes_per_agent_s"] for r in runs),
                "collisions": sum(r["collisions"] for r in runs),
                "closest_world_m": _smallest(r.get("closest_world_m") for r in runs),
                "vs_1_drone": _median_or_none(vs_one),
                "vs_oracle": _median_or_none(vs_oracle),
            }
        )
    return summary


def _smallest(gaps: Iterable[float | None]) -> float | None:
    """The smallest of the measured gaps; None (never under the simulator's NEAR_GAP_M) when none was."""
    measured = [g for g in gaps if g is not None]
    return min(measured) if measured else None


def _print(
    console: Console,
    config: SwarmConfig,
    worlds: list[str],
    summary: list[dict[str, Any]],
    oracle: dict[str, dict[str, Any]],
    repeats: int,
) -> None:
    where = f"'{worlds[0]}'" if len(worlds) == 1 else f"{len(worlds)} worlds"
    table = Table(
        title=f"exploring {where} (seed {config.mission.seed}), {repeats} mission(s) per world and row: "
        "medians (quartiles); vs 1 and vs oracle: medians over worlds of the per-world ratios"
    )
    columns = (
        "strategy",
        "drones",
        "success",
        "done < 95 %",
        "to 95 %, s",
        "to done, s",
        "vs 1",
        "vs oracle",
        "explored",
        "m/drone",
        "overlap",
        "kB/agent-s",
        "collisions",
        "closest, m",
    )
    for column in columns:
        table.add_column(column, justify="right")
    for c in summary:
        table.add_row(
            c["strategy"] + (f" (= {c['same_as'][:5]}.)" if c["same_as"] else ""),
            str(c["drones"]),
            f"{c['success']}/{c['missions']}",
            str(len(c["complete_below_95"])),
            _fmt_spread(c["time_to_95_s"]),
            _fmt_spread(c["time_to_done_s"]),
            _ratio(c["vs_1_drone"]),
            _ratio(c["vs_oracle"]),
            f"{100 * c['explored_fraction']:.1f} %",
            f"{c['distance_per_drone_m']:.1f}",
            f"{c['overlap_fraction']:.2f}",
            f"{c['bytes_per_agent_s'] / 1000:.1f}",
            str(c["collisions"]),
            f"> {NEAR_GAP_M:g}" if c["closest_world_m"] is None else f"{c['closest_world_m']:.3f}",
        )
    console.print(table)
    sizes = sorted({int(n) for plans in oracle.values() for n in plans})
    if oracle and sizes:
        otable = Table(title="oracle: time to 95 % of routes planned on the true mesh, s (views)")
        otable.add_column("world")
        for n in sizes:
            otable.add_column(f"{n} drone(s)", justify="right")
        for world, plans in oracle.items():
            cells = []
            for n in sizes:
                p = plans.get(str(n))
                cells.append(
                    "-"
                    if p is None
                    else "unreachable"
                    if p["time_to_95_s"] is None
                    else f"{p['time_to_95_s']:.1f} ({p['views']})"
                )
            otable.add_row(world, *cells)
        console.print(otable)
    for c in summary:
        for name in c["complete_below_95"]:
            console.print(f"[bold red]declared complete below 95 %:[/] {c['strategy']}, {c['drones']} drone(s), {name}")


def _fmt_spread(s: dict[str, float]) -> str:
    return f"{s['median']:.1f} ({s['q1']:.0f}-{s['q3']:.0f})"


def _ratio(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f}"
