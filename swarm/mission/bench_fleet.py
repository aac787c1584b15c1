"""`swarm bench fleet`: exploring missions of growing size on this machine, and what each agent's stages cost.

For every swarm size it runs a real exploring `swarm run` mission (the configured strategy, coordinated by
default) and prints, per process, CPU (% of one core over the flight, as `swarm bench flight`: from each process's
own CPU times, after WARMUP_S) and peak RSS, per agent its camera rate (frames integrated per second in the air)
and the cost of each stage (`swarm.stages`, from the agent's summary): per call (median, worst) and per second of
the agent's run (total time / run time: 1000 ms/s is one core). It names the largest size at which every agent
integrated at least FLEET_RATE_SHARE of the camera rate (9 Hz of 10) and the mission completed.

With `--profile`, a sampling profile of agent 1 (py-spy, every thread, 50 samples a second) is written into each
run's directory as `profile-agent-1.svg` (a flame graph; open it in a browser). py-spy attaches with ptrace: it
needs root or CAP_SYS_PTRACE; when it cannot, the run goes on and the table says "no profile".
"""

from __future__ import annotations

import json
import shutil
import statistics
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.table import Table

from swarm.agent.summary import AgentSummary
from swarm.config import SwarmConfig
from swarm.errors import SwarmError
from swarm.files import FileFormatError
from swarm.mission.bench import Sampler, _console_and_root
from swarm.mission.report import read_summary
from swarm.mission.run import RunState, run_mission, was_interrupted

FLEET_RATE_SHARE = 0.9  # an agent keeps up when it integrates this share of the camera rate (9 Hz of 10)
PROFILE_AGENT = 1
PROFILE_RATE_HZ = 50
# the stages in data-flow order (swarm.stages names); any other a summary holds is listed after them
STAGE_ORDER = (
    "mask_peers",
    "integrate",
    "store_patch",
    "fuse_patch",
    "occupancy",
    "planning_grid",
    "frontiers",
    "view_gain",
    "assignment",
    "decision",
    "decision_on_last_view",
    "planning",
    "whole_map_baseline",
)


def py_spy() -> str:
    """The py-spy executable (beside this Python's, as a virtual environment installs it, or on PATH); SwarmError
    (one line) when it is not installed."""
    beside = Path(sys.executable).parent / "py-spy"
    found = str(beside) if beside.is_file() else shutil.which("py-spy")
    if found is None:
        raise SwarmError("--profile needs py-spy (pip install py-spy)")
    return found


@dataclass
class Profiler:
    """Starts py-spy on one agent's process as soon as it is running (on_tick); py-spy stops when it exits."""

    executable: str
    out: Path
    agent: int = PROFILE_AGENT
    process: subprocess.Popen[bytes] | None = None
    pid: int | None = None
    log_path: Path = field(init=False)

    def __post_init__(self) -> None:
        self.log_path = self.out / "logs" / f"py-spy-agent-{self.agent}.log"

    @property
    def svg(self) -> Path:
        return self.out / f"profile-agent-{self.agent}.svg"

    def __call__(self, state: RunState) -> None:
        child = state.agents.get(self.agent)
        if self.process is not None or child is None or child.poll() is not None:
            return
        self.pid = child.pid
        self.log_path.parent.mkdir(parents=True, exist_ok=True)
        argv = [self.executable, "record", "--pid", str(child.pid), "--rate", str(PROFILE_RATE_HZ), "--threads"]
        argv += ["--nonblocking", "--format", "flamegraph", "--output", str(self.svg)]
        with self.log_path.open("wb") as log:
            self.process = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)

    def finish(self, timeout_s: float = 30.0) -> bool:
        """Wait for py-spy to write its profile (it ends with the agent); whether the profile is there."""
        if self.process is not None:
            try:
                self.process.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                self.process.terminate()
                self.process.wait(timeout=5)
        return self.svg.exists()


def bench_fleet(config: SwarmConfig, sizes: list[int], out: Path | None, profile: bool = False) -> int:
    """Run one exploring mission per size; 0 when every mission completed and the largest size kept every agent at
    FLEET_RATE_SHARE of the camera rate, else 1."""
    console, root = _console_and_root(out)
    executable = py_spy() if profile else None
    rate = config.camera.rate_hz
    results: list[dict[str, Any]] = []
    for n in sizes:
        run_config = config.model_copy(deep=True)
        run_config.mission.drones = n
        run_config.mission.out = root / f"fleet-{n}"
        sampler = Sampler()
        profiler = Profiler(executable, run_config.mission.out) if executable is not None else None

        def tick(state: RunState, sampler: Sampler = sampler, profiler: Profiler | None = profiler) -> None:
            sampler(state)
            if profiler is not None:
                profiler(state)

        console.print(f"bench fleet: {n} drone(s) exploring '{config.mission.world}' ...")
        report = run_mission(run_config, live=False, on_tick=tick)
        profiled = profiler.finish() if profiler is not None else None
        result = summarise(n, report, sampler, read_summaries(run_config.mission.out, n), rate)
        result["profile"] = str(profiler.svg) if profiler is not None and profiled else None
        results.append(result)
        print_size(console, result)
        if was_interrupted(report):
            console.print("bench fleet: interrupted")
            break
    print_sizes(console, results, rate)
    largest = largest_sustained(results)
    path = root / "bench-fleet.json"
    path.write_text(json.dumps({"world": str(config.mission.world), "rate_hz": rate, "results": results}, indent=2))
    verdict = "none" if largest is None else f"{largest} drones"
    console.print(
        f"largest swarm with every agent at {FLEET_RATE_SHARE * rate:g} Hz or more and the mission complete: "
        f"{verdict}; figures: {path}"
    )
    return 0 if results and largest == results[-1]["drones"] and len(results) == len(sizes) else 1


def read_summaries(out: Path, drones: int) -> dict[int, AgentSummary]:
    summaries = {}
    for k in range(1, drones + 1):
        try:
            summary = read_summary(out, k)
        except FileFormatError:
            summary = None
        if summary is not None:
            summaries[k] = summary
    return summaries


def summarise(
    n: int, report: dict[str, Any], sampler: Sampler, summaries: dict[int, AgentSummary], rate_hz: float
) -> dict[str, Any]:
    """One size's figures: the mission's, every process's CPU and memory, every agent's rate and stages."""
    processes = {
        name: {"cpu_percent": round(s.cpu_percent, 1), "peak_rss_mb": round(s.peak_rss / 2**20, 1)}
        for name, s in sorted(sampler.samples.items())
    }
    agents: dict[str, dict[str, Any]] = {}
    for k, s in sorted(summaries.items()):
        run_s = max(s.duration_s, 1e-9)
        agents[str(k)] = {
            "frame_rate_hz": s.frame_rate_hz,
            "frames": s.frames,
            "frames_skipped": s.frames_skipped,
            "mapping_ms_per_frame": s.mapping_ms_per_frame,
            "decision_ms_p50": s.decision_ms_p50,
            "decision_ms_max": s.decision_ms_max,
            "bytes_received_per_s": round(s.bytes_received / run_s, 1),
            "cpu_percent": processes.get(f"agent-{k}", {}).get("cpu_percent"),
            "peak_rss_mb": processes.get(f"agent-{k}", {}).get("peak_rss_mb"),
            "memory_mb": dict(s.memory_mb),
            "stages": {n: {**c.model_dump(), "ms_per_s": round(c.total_ms / run_s, 1)} for n, c in s.stages.items()},
        }
    rates = [s.frame_rate_hz for s in summaries.values()]
    time_to = report.get("time_to", {})
    return {
        "drones": n,
        "status": report["status"],
        "duration_s": report["duration_s"],
        "explored_fraction": report["explored_fraction"],
        "time_to_95_s": time_to.get("0.95"),
        "collisions": report["collisions"],
        "bytes_per_agent_s": report["bandwidth"]["bytes_per_agent_s"],
        "patch_to_map_ratio": report["bandwidth"].get("patch_to_map_ratio"),
        "min_frame_rate_hz": min(rates) if len(rates) == n else 0.0,  # an agent with no summary kept no rate
        "sustained": len(rates) == n and min(rates) >= FLEET_RATE_SHARE * rate_hz,
        "processes": processes,
        "agents": agents,
    }


def largest_sustained(results: list[dict[str, Any]]) -> int | None:
    """The largest size whose mission completed with every agent at the rate, or None."""
    kept = [r["drones"] for r in results if r["sustained"] and r["status"] == "complete"]
    return max(kept) if kept else None


def stage_rows(agents: dict[str, dict[str, Any]]) -> list[tuple[str, float, float, float, float]]:
    """Per stage over the agents: (name, median of their p50 ms, worst max ms, mean ms/s, worst ms/s)."""
    names = {name for a in agents.values() for name in a["stages"]}
    ordered = [s for s in STAGE_ORDER if s in names] + sorted(names - set(STAGE_ORDER))
    rows = []
    for name in ordered:
        costs = [a["stages"][name] for a in agents.values() if name in a["stages"]]
        rows.append(
            (
                name,
                statistics.median(c["p50_ms"] for c in costs),
                max(c["max_ms"] for c in costs),
                statistics.fmean(c["ms_per_s"] for c in costs),
                max(c["ms_per_s"] for c in costs),
            )
        )
    return rows


MEMORY_COLUMNS = (  # (summary key, heading): the parts an agent counts, then the whole process
    ("rss_at_start", "at start"),
    ("fused_map", "fused map"),
    ("held_back", "held back"),
    ("patch_bytes", "patches"),
    ("open_patch", "open patch"),
    ("rss_peak_in_flight", "peak before mesh"),
)


def print_memory(console: Console, r: dict[str, Any]) -> None:
    """Where each agent's memory went (MB): what it held at landing, its peak before the final mesh, its peak."""
    table = Table(title=f"{r['drones']} drone(s): agent memory, MB (the parts at landing; RSS peaks)")
    for column in ("drone", *(heading for _, heading in MEMORY_COLUMNS), "peak"):
        table.add_column(column, justify="right")
    for k, a in r["agents"].items():
        memory = a.get("memory_mb", {})
        cells = [f"{memory[key]:.0f}" if key in memory else "-" for key, _ in MEMORY_COLUMNS]
        table.add_row(k, *cells, str(a["peak_rss_mb"]))
    console.print(table)


def print_size(console: Console, r: dict[str, Any]) -> None:
    agents = Table(title=f"{r['drones']} drone(s): {r['status']}, every agent")
    for column in ("drone", "Hz", "skipped", "CPU %", "MB", "mapping ms/frame", "decision ms p50/max", "recv kB/s"):
        agents.add_column(column, justify="right")
    for k, a in r["agents"].items():
        agents.add_row(
            k,
            f"{a['frame_rate_hz']:.2f}",
            str(a["frames_skipped"]),
            str(a["cpu_percent"]),
            str(a["peak_rss_mb"]),
            f"{a['mapping_ms_per_frame']:.1f}",
            f"{a['decision_ms_p50']}/{a['decision_ms_max']}",
            f"{a['bytes_received_per_s'] / 1000:.1f}",
        )
    console.print(agents)
    print_memory(console, r)
    stages = Table(title=f"{r['drones']} drone(s): stage costs (ms/s: share of one core, 1000 = all of it)")
    for column in ("stage", "per call p50 ms (median agent)", "worst call ms", "ms/s (mean agent)", "ms/s (worst)"):
        stages.add_column(column, justify="right")
    for name, p50, worst, mean_s, worst_s in stage_rows(r["agents"]):
        stages.add_row(name, f"{p50:.2f}", f"{worst:.1f}", f"{mean_s:.1f}", f"{worst_s:.1f}")
    console.print(stages)


def print_sizes(console: Console, results: list[dict[str, Any]], rate_hz: float) -> None:
    table = Table(title=f"swarm bench fleet (target: every agent at {FLEET_RATE_SHARE * rate_hz:g} Hz or more)")
    columns = ["drones", "status", "explored", "95 % at s", "slowest Hz", "agent CPU % (mean)", "agent MB (max)"]
    columns += ["sim CPU %", "observer CPU %", "recv kB/agent-s", "patches/map"]
    for column in columns:
        table.add_column(column, justify="right")
    for r in results:
        p, agents = r["processes"], list(r["agents"].values())
        cpu = [a["cpu_percent"] for a in agents if a["cpu_percent"] is not None]
        rss = [a["peak_rss_mb"] for a in agents if a["peak_rss_mb"] is not None]
        table.add_row(
            str(r["drones"]),
            r["status"],
            f"{r['explored_fraction']:.1%}",
            "-" if r["time_to_95_s"] is None else f"{r['time_to_95_s']:.0f}",
            f"{r['min_frame_rate_hz']:.2f}",
            f"{statistics.fmean(cpu):.0f}" if cpu else "-",
            f"{max(rss):.0f}" if rss else "-",
            str(p.get("sim", {}).get("cpu_percent", "-")),
            str(p.get("observer", {}).get("cpu_percent", "-")),
            f"{r['bytes_per_agent_s'] / 1000:.1f}",
            "-" if r["patch_to_map_ratio"] is None else f"{r['patch_to_map_ratio']:.2f}",
        )
    console.print(table)
