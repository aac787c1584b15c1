"""`swarm bench flight`: CPU and memory of every process of a real scripted mission, for several swarm sizes.

CPU is measured from each process's own CPU times (user + system) over the flight window, which starts
WARMUP_S after the agents are launched (imports and connection are excluded) and ends at the last sample
taken while the process was alive; it is reported in % of one core. Memory is the peak RSS seen.
"""

from __future__ import annotations

import json
import re
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import psutil
from rich.console import Console
from rich.table import Table

from swarm.config import SwarmConfig
from swarm.mission.run import RunState, run_mission, was_interrupted

WARMUP_S = 8.0


@dataclass
class ProcessSample:
    first_cpu: float | None = None
    first_t: float = 0.0
    last_cpu: float = 0.0
    last_t: float = 0.0
    peak_rss: int = 0
    threads: int = 0

    @property
    def cpu_percent(self) -> float:
        if self.first_cpu is None or self.last_t <= self.first_t:
            return float("nan")
        return 100.0 * (self.last_cpu - self.first_cpu) / (self.last_t - self.first_t)


@dataclass
class Sampler:
    samples: dict[str, ProcessSample] = field(default_factory=dict)
    handles: dict[int, psutil.Process] = field(default_factory=dict)

    def __call__(self, state: RunState) -> None:
        now = time.monotonic()
        in_window = now - state.started >= WARMUP_S
        for child in state.children:
            try:
                proc = self.handles.setdefault(child.pid, psutil.Process(child.pid))
                with proc.oneshot():
                    times, rss, threads = proc.cpu_times(), proc.memory_info().rss, proc.num_threads()
            except psutil.Error:
                continue
            s = self.samples.setdefault(child.name, ProcessSample())
            s.peak_rss, s.threads = max(s.peak_rss, rss), max(s.threads, threads)
            if in_window and child.poll() is None:
                cpu = times.user + times.system
                if s.first_cpu is None:
                    s.first_cpu, s.first_t = cpu, now
                s.last_cpu, s.last_t = cpu, now


def _console_and_root(out: Path | None) -> tuple[Console, Path]:
    console = Console()
    if not console.is_terminal:
        console = Console(width=160)  # logs and pipes: never truncate the figures
    return console, out or Path(tempfile.mkdtemp(prefix="swarm-bench-"))


def bench_flight(config: SwarmConfig, sizes: list[int], out: Path | None) -> int:
    console, root = _console_and_root(out)
    results: list[dict[str, Any]] = []
    for n in sizes:
        run_config = config.model_copy(deep=True)
        run_config.mission.drones = n
        run_config.explore.strategy = "scripted"  # the same flights at every size: comparable figures
        run_config.mission.out = root / f"flight-{n}"
        sampler = Sampler()
        console.print(f"bench flight: {n} drone(s) in '{config.mission.world}' ...")
        report = run_mission(run_config, live=False, on_tick=sampler)
        results.append(_summarise(n, report, sampler))
        if was_interrupted(report):
            console.print("bench flight: interrupted")
            break
    _print(console, results)
    path = root / "bench-flight.json"
    path.write_text(json.dumps(results, indent=2))
    console.print(f"figures: {path}")
    return 0 if all(r["status"] == "complete" for r in results) else 1


def _summarise(n: int, report: dict[str, Any], sampler: Sampler) -> dict[str, Any]:
    processes = {
        name: {
            "cpu_percent": round(s.cpu_percent, 1),
            "peak_rss_mb": round(s.peak_rss / 2**20, 1),
            "threads": s.threads,
        }
        for name, s in sorted(sampler.samples.items())
    }
    agents = [p for name, p in processes.items() if name.startswith("agent-")]
    return {
        "drones": n,
        "status": report["status"],
        "duration_s": report["duration_s"],
        "collisions": report["collisions"],
        "processes": processes,
        "agent_cpu_percent_mean": round(sum(a["cpu_percent"] for a in agents) / max(1, len(agents)), 1),
        "agent_rss_mb_max": max((a["peak_rss_mb"] for a in agents), default=0.0),
        "total_cpu_percent": round(sum(p["cpu_percent"] for p in processes.values()), 1),
    }


def _print(console: Console, results: list[dict[str, Any]]) -> None:
    table = Table(title="swarm bench flight (CPU in % of one core over the flight; peak RSS)")
    for column in (
        "drones",
        "status",
        "flight s",
        "sim CPU %",
        "sim MB",
        "agent CPU % (mean)",
        "agent MB (max)",
        "observer CPU %",
        "total CPU %",
    ):
        table.add_column(column, justify="right")
    for r in results:
        p = r["processes"]
        sim, observer = p.get("sim", {}), p.get("observer", {})
        table.add_row(
            str(r["drones"]),
            r["status"],
            f"{r['duration_s']:.0f}",
            str(sim.get("cpu_percent")),
            str(sim.get("peak_rss_mb")),
            str(r["agent_cpu_percent_mean"]),
            str(r["agent_rss_mb_max"]),
            str(observer.get("cpu_percent")),
            str(r["total_cpu_percent"]),
        )
    console.print(table)


def bench_mapping_swarm(config: SwarmConfig, drones: int, out: Path | None) -> int:
    """The depth frame rate each agent sustains while N agents map at once on this machine (a real mission)."""
    console, root = _console_and_root(out)
    run_config = config.model_copy(deep=True)
    run_config.mission.drones = drones
    run_config.mission.out = root / f"mapping-swarm-{drones}"
    run_config.explore.strategy = "scripted"  # the same flights at every size: comparable figures

    console.print(
        f"bench mapping: {drones} agents mapping at {config.camera.rate_hz:g} Hz in '{config.mission.world}' ..."
    )
    report = run_mission(run_config, live=False)
    table = Table(title=f"{drones} agents mapping at once on this machine (target {config.camera.rate_hz:g} Hz each)")
    for column in ("drone", "frames", "sustained Hz", "mapping ms/frame (mask peers+integrate+seal)", "patches"):
        table.add_column(column, justify="right")
    for a in report["agents"]:
        table.add_row(
            str(a["id"]),
            str(a["frames"]),
            str(a["frame_rate_hz"]),
            str(a["mapping_ms_per_frame"]),
            str(a["patches_sealed"]),
        )
    console.print(table)
    rates = [a["frame_rate_hz"] or 0.0 for a in report["agents"]]
    render_ms = camera_render_ms(run_config.mission.out / "logs" / "cameras.log")
    sustained = sustains(rates, config.camera.rate_hz)
    summary = {
        "drones": drones,
        "status": report["status"],
        "explored_fraction": report["explored_fraction"],
        "min_frame_rate_hz": min(rates),
        "sustained": sustained,
        "camera_render_ms": render_ms,
        "agents": report["agents"],
    }
    (root / "bench-mapping-swarm.json").write_text(json.dumps(summary, indent=2))
    render = "not logged" if render_ms is None else f"{render_ms:.1f} ms a camera frame (with the other drones)"
    console.print(f"simulated cameras: render {render}")
    verdict = "met" if sustained else "NOT met"
    console.print(
        f"slowest agent: {min(rates):.2f} Hz: {verdict} (every agent at {SUSTAINED_SHARE:.0%} of "
        f"{config.camera.rate_hz:g} Hz or more); figures: {root / 'bench-mapping-swarm.json'}"
    )
    return 0 if report["status"] == "complete" and sustained else 1


# An agent sustains the camera rate when it integrates at least this share of it over its time in the air: the
# first and last frames of a flight (take-off, touch-down) fall partly outside that time.
SUSTAINED_SHARE = 0.95
RENDER_LINE = re.compile(r"render ([0-9.]+) ms each")


def sustains(rates: list[float], rate_hz: float) -> bool:
    """Whether every agent's integrated frame rate (frames per second in the air) keeps up with the camera."""
    return bool(rates) and min(rates) >= SUSTAINED_SHARE * rate_hz


def camera_render_ms(log: Path) -> float | None:
    """The simulated camera driver's mean render time per frame, from the line `swarm cameras` ends with."""
    try:
        text = log.read_text(errors="replace")
    except OSError:
        return None
    found = RENDER_LINE.findall(text)
    return float(found[-1]) if found else None
