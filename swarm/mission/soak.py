"""`swarm soak`: real missions back to back, each with one random fault and (on the netns radio) random loss,
for a given wall time; reports memory and file-descriptor growth of every agent, missions completed and
patches lost.

Memory: each agent process (a restarted agent is a new process) is sampled by the supervision loop; its
warm-up sample is the first taken WARMUP_S after the process was first seen (imports, connection, take-off and
the first patches are behind it), growth is the peak RSS after that over the warm-up RSS.

Patches lost (`audit_patches`), judged by content: a sealed patch is a file an agent wrote (its bytes are what it
holds and serves), and a patch is lost when some surviving agent (one that finished and wrote its summary) does
not hold it, or holds other bytes under its id (SHA-256 in the summary's `sync.content`), or when its seq is a
hole in its producer's epoch (the seqs sealed in one epoch are 0, 1, 2, ... with none missing). A held id that
was never sealed is counted apart ("unknown"). The soak passes when every mission completes and converges, no
patch is lost, none is unknown, and no agent grows by more than MAX_GROWTH.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import random
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import psutil
from rich.console import Console
from rich.table import Table

from swarm.config import ConfigError, SwarmConfig
from swarm.errors import SwarmError
from swarm.mission.report import held_patch_ids, read_summary
from swarm.mission.run import RunState, run_mission, was_interrupted
from swarm.netem.commands import NetemUnavailable, check_prerequisites
from swarm.patches.patch import PatchId

WARMUP_S = 20.0
MAX_GROWTH = 0.20
LOSS_LEVELS = (0.0, 0.1, 0.2)
FAULT_KINDS = ("kill", "restart", "freeze", "telemetry-loss")


@dataclass
class AgentSample:
    name: str
    pid: int
    first_seen: float
    warm_rss: int | None = None
    peak_rss: int = 0
    warm_fds: int | None = None
    peak_fds: int = 0

    def as_dict(self) -> dict[str, Any]:
        growth = None if self.warm_rss is None else round(self.peak_rss / self.warm_rss - 1.0, 4)
        return {
            "agent": self.name,
            "pid": self.pid,
            "warm_rss_mb": _mb(self.warm_rss),
            "peak_rss_mb": _mb(self.peak_rss),
            "rss_growth": growth,
            "warm_fds": self.warm_fds,
            "peak_fds": self.peak_fds,
        }


def _mb(value: int | None) -> float | None:
    return None if value is None else round(value / 2**20, 1)


@dataclass
class AgentSampler:
    """Samples RSS and open file descriptors of the agent processes on every supervision tick."""

    samples: dict[int, AgentSample] = field(default_factory=dict)
    handles: dict[int, psutil.Process] = field(default_factory=dict)

    def __call__(self, state: RunState) -> None:
        now = time.monotonic()
        for child in state.agents.values():
            if child.poll() is not None:
                continue
            try:
                proc = self.handles.setdefault(child.pid, psutil.Process(child.pid))
                with proc.oneshot():
                    rss, fds = proc.memory_info().rss, proc.num_fds()
            except psutil.Error:
                continue
            if rss <= 0:
                continue  # exited, not reaped yet: a zombie holds no memory, and a warm RSS of 0 divides by zero
            sample = self.samples.setdefault(child.pid, AgentSample(child.name, child.pid, now))
            if now - sample.first_seen < WARMUP_S:
                continue
            if sample.warm_rss is None:
                sample.warm_rss, sample.warm_fds = rss, fds
            sample.peak_rss, sample.peak_fds = max(sample.peak_rss, rss), max(sample.peak_fds, fds)


def random_fault(rng: random.Random, drones: int) -> str:
    kind = rng.choice(FAULT_KINDS)
    agent, at = rng.randint(1, drones), rng.randint(4, 12)
    if kind == "kill":
        return f"kill:agent={agent}@{at}"
    return f"{kind}:agent={agent}@{at}+{rng.randint(2, 8)}"


def _netns_available() -> bool:
    try:
        check_prerequisites()
    except NetemUnavailable:
        return False
    return True


@dataclass
class PatchAudit:
    sealed: int = 0
    missing: int = 0  # sealed, and some survivor does not hold it
    altered: int = 0  # some survivor holds other bytes under its id
    gaps: int = 0  # seqs never sealed between two that were, per producer and epoch
    unknown: int = 0  # held by a survivor, never sealed

    @property
    def lost(self) -> int:
        return self.missing + self.altered + self.gaps


def audit_patches(out: Path, drones: int) -> PatchAudit:
    """What became of every patch sealed in the mission in OUT (see the module doc)."""
    sealed = {str(pid): hashlib.sha256(path.read_bytes()).hexdigest() for pid, path in _patch_files(out)}
    survivors = [
        (held_patch_ids(summary), summary.sync.content)
        for k in range(1, drones + 1)
        if (summary := read_summary(out, k)) is not None
    ]
    return audit(sealed, survivors)


def audit(sealed: dict[str, str], survivors: list[tuple[set[str], dict[str, str]]]) -> PatchAudit:
    """`sealed`: patch id -> SHA-256 of its bytes; `survivors`: each one's (held ids, held id -> SHA-256)."""
    result = PatchAudit(sealed=len(sealed))
    seqs: dict[tuple[int, int], set[int]] = {}
    for text in sealed:
        pid = PatchId.parse(text)
        seqs.setdefault((pid.producer, pid.epoch), set()).add(pid.seq)
    result.gaps = sum(max(held) + 1 - len(held) for held in seqs.values())
    missing: set[str] = set()
    altered: set[str] = set()
    unknown: set[str] = set()
    for held, content in survivors:
        missing |= set(sealed) - held
        unknown |= held - set(sealed)
        altered |= {pid for pid, digest in content.items() if sealed.get(pid, digest) != digest}
    result.missing, result.altered, result.unknown = len(missing), len(altered - missing), len(unknown)
    return result


def _patch_files(out: Path) -> list[tuple[PatchId, Path]]:
    patches_dir = out / "agents" / "patches"
    files = []
    for path in sorted(patches_dir.glob("*.patch")) if patches_dir.is_dir() else []:
        try:
            files.append((PatchId.parse(path.stem), path))
        except ValueError:
            continue
    return files


def _one_mission(config: SwarmConfig, out: Path, fault: str, loss: float | None) -> dict[str, Any]:
    overrides: dict[str, Any] = {"out": out, "faults": [fault]}
    if loss is not None:
        overrides["network"] = "netns"
    if loss:
        out.parent.mkdir(parents=True, exist_ok=True)
        scenario = out.parent / f"{out.name}-loss.toml"  # the run directory must start empty
        scenario.write_text(f'name = "soak-loss"\n[[event]]\nat = 0\nlink = "all"\nloss = {loss}\n')
        overrides["links"] = scenario
    mission = config.model_copy(
        update={"mission": type(config.mission).model_validate({**config.mission.model_dump(), **overrides})}
    )
    sampler = AgentSampler()
    started = time.monotonic()
    converged = False
    try:
        report = run_mission(mission, live=False, on_tick=sampler)
        status, reason, converged = report["status"], report["reason"], bool(report["converged"])
    except SwarmError as exc:
        status, reason = "failed", str(exc)
    audit = audit_patches(out, config.mission.drones)
    return {
        "out": str(out),
        "fault": fault,
        "loss": loss,
        "status": status,
        "reason": reason,
        "converged": converged,
        "wall_s": round(time.monotonic() - started, 1),
        "patches_sealed": audit.sealed,
        "patches_lost": audit.lost,
        "patches": dataclasses.asdict(audit),
        "agents": [s.as_dict() for s in sampler.samples.values()],
    }


def summarise(missions: list[dict[str, Any]]) -> dict[str, Any]:
    agents = [a for m in missions for a in m["agents"] if a["rss_growth"] is not None]
    worst = max(agents, key=lambda a: a["rss_growth"], default=None)
    fd_growth = max((a["peak_fds"] - a["warm_fds"] for a in agents), default=None)
    summary = {
        "missions": len(missions),
        "completed": sum(m["status"] == "complete" for m in missions),
        "converged": sum(bool(m.get("converged")) for m in missions),
        "patches_sealed": sum(m["patches_sealed"] for m in missions),
        "patches_lost": sum(m["patches_lost"] for m in missions),
        "patches_unknown": sum(m.get("patches", {}).get("unknown", 0) for m in missions),
        "agent_processes_sampled": len(agents),
        "max_rss_growth": worst["rss_growth"] if worst else None,
        "max_fd_growth": fd_growth,
        "max_peak_rss_mb": max((a["peak_rss_mb"] for a in agents), default=None),
    }
    summary["passed"] = bool(
        missions
        and summary["completed"] == len(missions)
        and summary["converged"] == len(missions)
        and summary["patches_lost"] == 0
        and summary["patches_unknown"] == 0
        and summary["max_rss_growth"] is not None
        and summary["max_rss_growth"] <= MAX_GROWTH
    )
    return summary


def soak(config: SwarmConfig, minutes: float, out: Path, seed: int, console: Console | None = None) -> dict[str, Any]:
    """Missions until `minutes` of wall time have passed (at least one); writes OUT/soak.json."""
    console = console or Console(stderr=True)
    rng = random.Random(seed)
    netns = _netns_available()
    if not netns:
        console.print("swarm soak: no network namespaces here (root, ip and nft needed): loopback, no loss")
    deadline = time.monotonic() + minutes * 60.0
    missions: list[dict[str, Any]] = []
    while not missions or time.monotonic() < deadline:
        index = len(missions) + 1
        fault = random_fault(rng, config.mission.drones)
        loss = rng.choice(LOSS_LEVELS) if netns else None
        console.print(f"swarm soak: mission {index}: {fault}, loss {loss if loss is not None else '-'}")
        result = _one_mission(config, out / f"mission-{index:03d}", fault, loss)
        missions.append(result)
        if was_interrupted(result):
            console.print("swarm soak: interrupted")
            break
        growth = [a["rss_growth"] for a in result["agents"] if a["rss_growth"] is not None]
        console.print(
            f"  {result['status']}{'' if result['converged'] else ' (not converged)'} in {result['wall_s']} s, "
            f"patches sealed {result['patches_sealed']}, lost {result['patches_lost']} {result['patches']}, "
            "max agent memory growth "
            f"{max(growth) * 100 if growth else float('nan'):.1f} %"
        )
    result = {
        "minutes": minutes,
        "seed": seed,
        "network": "netns" if netns else "loopback",
        "summary": summarise(missions),
        "missions": missions,
    }
    out.mkdir(parents=True, exist_ok=True)
    (out / "soak.json").write_text(json.dumps(result, indent=2, default=str))
    return result


def _print(console: Console, result: dict[str, Any]) -> None:
    table = Table(title=f"swarm soak: {result['minutes']} min, {result['network']}")
    for column in ("#", "fault", "loss", "end", "converged", "s", "sealed", "lost", "agent RSS growth", "fd growth"):
        table.add_column(column)
    for i, m in enumerate(result["missions"], 1):
        growth = [a["rss_growth"] for a in m["agents"] if a["rss_growth"] is not None]
        fds = [a["peak_fds"] - a["warm_fds"] for a in m["agents"] if a["warm_fds"] is not None]
        table.add_row(
            str(i),
            m["fault"],
            "-" if m["loss"] is None else f"{m['loss']:.0%}",
            m["status"],
            "yes" if m.get("converged") else "no",
            str(m["wall_s"]),
            str(m["patches_sealed"]),
            str(m["patches_lost"]),
            f"{max(growth) * 100:+.1f} %" if growth else "-",
            str(max(fds)) if fds else "-",
        )
    console.print(table)
    s = result["summary"]
    memory_growth = "n/a" if s["max_rss_growth"] is None else f"{s['max_rss_growth'] * 100:.1f} %"
    console.print(
        f"missions {s['missions']}, completed {s['completed']}, converged {s['converged']}, patches sealed "
        f"{s['patches_sealed']}, lost {s['patches_lost']}, unknown {s['patches_unknown']}, max agent memory growth "
        f"after warm-up {memory_growth} (limit {MAX_GROWTH:.0%}), max fd growth {s['max_fd_growth']}, peak agent RSS "
        f"{s['max_peak_rss_mb']} MB: {'PASS' if s['passed'] else 'FAIL'}"
    )


def soak_command(config: SwarmConfig, minutes: float, out: Path | None, seed: int) -> int:
    if not 0 < minutes <= 24 * 60:
        raise ConfigError(f"--minutes must be more than 0 and at most 1440, got {minutes}")
    out = out or config.mission.out or Path("runs") / f"soak-{time.strftime('%Y%m%d-%H%M%S')}"
    console = Console()
    result = soak(config, minutes, out, seed, console)
    _print(console, result)
    console.print(f"soak: {out / 'soak.json'}")
    return 0 if result["summary"]["passed"] else 1
