"""The mission report (`report.json`): a schema later capabilities extend; existing names never change.

Truth comes from the simulator (distance flown, collisions, landed), communication figures from the agents'
own counters, presence, coverage and clusters from the observer. `write_report` also renders the human side of
the report next to it: the figures (`swarm.mission.plots`) and `report.md` (`swarm.mission.report_md`).
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from swarm import __version__
from swarm.files import write_json_atomic
from swarm.mission.phantoms import phantom_check
from swarm.mission.plots import COVERAGE_TARGET, PLOT_NAMES, write_plots
from swarm.mission.report_md import REPORT_PAGE, write_report_page
from swarm.patches.digest import PatchDigest
from swarm.sim.collisions import GROUND_GAP_M

if TYPE_CHECKING:
    from swarm.mission.run import RunPlan, RunState

log = logging.getLogger(__name__)

TIME_TO_THRESHOLDS = (0.5, 0.9, 0.95, 0.99)


def build_report(
    plan: RunPlan, state: RunState, sim: dict[str, Any] | None, observer: dict[str, Any] | None
) -> dict[str, Any]:
    vehicles = {v["id"]: v for v in (sim or {}).get("vehicles", [])}
    routes = {r.drone_id: r for r in plan.routes}
    agents = []
    summaries: dict[int, dict[str, Any]] = {}
    for k in sorted(state.agents):
        summary = read_json(plan.out / "agents" / f"agent-{k}.json") or {}
        sync = summary.get("sync", {})
        truth = vehicles.get(k, {})
        agents.append(
            {
                "id": k,
                "distance_m": round(float(truth.get("distance_m", 0.0)), 2),
                "closest_world_m": truth.get("closest_world_m"),
                "closest_world_at": truth.get("closest_world_at"),
                "closest_drone_m": truth.get("closest_drone_m"),
                "bytes_sent": int(summary.get("bytes_sent", 0)),
                "bytes_received": int(summary.get("bytes_received", 0)),
                "landed": truth.get("landed_state") == "on_ground" and not truth.get("armed", True),
                "phase": summary.get("phase", "unknown"),
                "exit_code": state.exit_codes.get(k),
                "route_length_m": round(routes[k].length_m, 2) if k in routes else None,
                "peers_seen": summary.get("peers_seen", []),
                "patches_sealed": int(summary.get("patches_sealed", 0)),
                "frames": int(summary.get("frames", 0)),
                "mapping_ms_per_frame": summary.get("mapping_ms_per_frame"),
                "frame_rate_hz": summary.get("frame_rate_hz"),
                "sensor_stream": summary.get("sensor_stream"),  # camera.source = "zenoh": frames and drops by reason
                "patches_held": int(sync.get("patches_held", 0)),
                "patches_requested": int(sync.get("patches_requested", 0)),
                "patches_served": int(sync.get("patches_served", 0)),
                "patches_received": {
                    "push": int(sync.get("received_by_push", 0)),
                    "pull": int(sync.get("received_by_pull", 0)),
                },
                "patches_rejected": sync.get("rejected", {}),
                "duration_s": float(summary.get("duration_s", 0.0)),
                "traffic": summary.get("traffic", {}),
                "targets_assigned": int(summary.get("targets_assigned", 0)),
                "targets_self_selected": int(summary.get("targets_self_selected", 0)),
                "exploration_done_reason": summary.get("exploration_done_reason") or None,
                "frontiers_given_up": summary.get("frontiers_given_up", []),
            }
        )
        summaries[k] = summary
    status = state.status
    faults = getattr(state, "faults", None)
    must_land = [a for a in agents if faults is None or not faults.killed_for_good(a["id"])]
    if status == "complete" and not all(a["landed"] for a in must_land):
        status, state.reason = "failed", "an agent exited but its vehicle is not landed and disarmed"
    lo, hi = plan.volume
    explored_timeline = (observer or {}).get("explored_timeline", [])
    explore = getattr(plan.config, "explore", None)
    explored = float((observer or {}).get("explored_fraction", 0.0))
    if status == "complete" and _judged_by_coverage(plan.config) and explored < COVERAGE_TARGET:
        status, state.reason = "incomplete", _why_short(explored, agents)
    links = state.links.report() if state.links is not None else {}
    return {
        "status": status,
        "reason": state.reason,
        "world": plan.world.name,
        "run_dir": str(plan.out),
        "drones": plan.config.mission.drones,
        "duration_s": round(max(0.0, state.finished - state.started), 2) if state.started else 0.0,
        # unix time of the mission clock's zero: an agent log's `t` minus this is the report's mission time
        "started_at": round(getattr(state, "started_wall", 0.0), 3),
        "collisions": int((sim or {}).get("collisions", 0)),
        "explored_fraction": explored,
        "explored_timeline": explored_timeline,
        "time_to": time_to(explored_timeline),
        "explored_by_agent": (observer or {}).get("explored_by_agent", {}),
        "overlap_fraction": float((observer or {}).get("overlap_fraction", 0.0)),
        "leaders": (observer or {}).get("leaders", []),
        "faults": faults.report() if faults is not None else [],
        "leader_changes": int((observer or {}).get("leader_changes", 0)),
        "network": plan.config.mission.network,
        "scenario": links.get("scenario"),
        "impairments": links.get("impairments", []),
        "partitions": links.get("partitions", []),
        "convergence_after_heal_s": links.get("convergence_after_heal_s", []),
        "map": "map.ply" if (plan.out / "map.ply").exists() else None,
        # map surface along the flown paths that the building does not have (drones mapped as obstacles)
        "phantoms": phantom_check(
            plan.out / "map.ply",
            (observer or {}).get("trajectories", {}),
            plan.world,
            plan.config.sim.drone_radius_m + GROUND_GAP_M,
        ),
        "converged": converged(summaries, sealed_patch_ids(plan.out / "agents" / "patches")),
        "bandwidth": bandwidth(summaries),
        "collision_events": (sim or {}).get("collision_events", []),
        # the simulator's loop ran this late (its process or the machine did not run): no telemetry meanwhile
        "sim_stalls": (sim or {}).get("stalls", []),
        "priority": run_priority(plan, state),
        "agents": agents,
        "presence_timeline": (observer or {}).get("timeline", []),
        "mission": {
            "name": plan.config.mission.name,
            "seed": plan.config.mission.seed,
            "max_time_s": plan.config.mission.max_time_s,
            "volume": {"min": [round(float(v), 3) for v in lo], "max": [round(float(v), 3) for v in hi]},
            "spawns": [list(s) for s in plan.spawns],
            "world": str(plan.config.mission.world),
            "strategy": getattr(explore, "strategy", None)
            or next((s["strategy"] for s in summaries.values() if "strategy" in s), None),
        },
        "plots": [],
        "report_page": None,
        "swarm_version": __version__,
    }


def _judged_by_coverage(config: Any) -> bool:
    """Missions whose drones explore with a camera end `complete` only at COVERAGE_TARGET explored: below it,
    "exploration done" is a verdict the ground truth contradicts (scripted routes and camera-less runs are not
    judged by it)."""
    explore, camera = getattr(config, "explore", None), getattr(config, "camera", None)
    return getattr(explore, "strategy", "scripted") != "scripted" and getattr(camera, "source", "none") != "none"


def _why_short(explored: float, agents: list[dict[str, Any]]) -> str:
    reasons = sorted({a["exploration_done_reason"] for a in agents if a.get("exploration_done_reason")})
    given_up = sum(len(a.get("frontiers_given_up") or []) for a in agents)
    return (
        f"exploration ended at {math.floor(explored * 1000) / 10:.1f} % explored, below {COVERAGE_TARGET:.0%}: "
        f"{'; '.join(reasons) or 'no agent said why'}; {given_up} frontier(s) given up (agents[].frontiers_given_up)"
    )


def run_priority(plan: RunPlan, state: RunState) -> dict[str, Any]:
    """The niceness asked for the simulator and the agents, the one each got, and whether every one got it."""
    m = plan.config.mission
    got: dict[str, Any] = {
        "sim": state.sim.nice if state.sim is not None else None,
        "agents": {k: child.nice for k, child in state.agents.items()},
    }
    granted = got["sim"] == m.sim_nice and all(n == m.agent_nice for n in got["agents"].values())
    return {"asked": {"sim": m.sim_nice, "agents": m.agent_nice}, "got": got, "granted": granted}


def time_to(
    timeline: Iterable[Sequence[float]], thresholds: Sequence[float] = TIME_TO_THRESHOLDS
) -> dict[str, float | None]:
    """For each threshold, the first t of the (t, fraction) timeline at which the fraction reached it, or None.

    t is the observer's clock (seconds since it started, which is when the swarm started), so these are the
    mission's times to 50/90/95/99 % coverage, the speed figures exploration strategies are compared on.
    """
    points = [(float(t), float(f)) for t, f in timeline]
    return {str(th): next((t for t, f in points if f >= th), None) for th in thresholds}


def sealed_patch_ids(patches_dir: Path) -> set[str]:
    """Every patch the agents sealed (the files they wrote), as "producer.epoch.seq"."""
    return {path.stem for path in patches_dir.glob("*.patch")} if patches_dir.is_dir() else set()


def held_patch_ids(summary: dict[str, Any]) -> set[str]:
    """The patch ids an agent held at the end, from the holdings in its summary."""
    holdings = summary.get("sync", {}).get("holdings", {"entries": []})
    return {str(pid) for pid in PatchDigest.from_wire(holdings).ids()}


def converged(summaries: dict[int, dict[str, Any]], sealed: set[str]) -> bool:
    """Every agent ended holding the same patch set, and it is every patch any agent sealed."""
    if not summaries or any("sync" not in s for s in summaries.values()):
        return False
    return all(held_patch_ids(s) == sealed for s in summaries.values())


def bandwidth(summaries: dict[int, dict[str, Any]]) -> dict[str, Any]:
    """Bus bytes received per agent-second, against the whole-map baseline in the same run.

    Received bytes are what crossed the network (a publication reaches each peer separately). The baseline is
    what it would have cost for every agent to send its whole fused map to every other agent once per
    exploration loop: the sum, over agents and loops, of the map's wire size times the number of receivers.
    Both are divided by the same agent-seconds (each agent's whole run, flight and linger).
    """
    n = len(summaries)
    agent_seconds = sum(float(s.get("duration_s", 0.0)) for s in summaries.values())
    received = sum(int(s.get("bytes_received", 0)) for s in summaries.values())
    baseline = sum(int(s.get("whole_map_baseline", {}).get("bytes", 0)) for s in summaries.values()) * max(n - 1, 0)
    loop_s = next((s["whole_map_baseline"]["loop_s"] for s in summaries.values() if "whole_map_baseline" in s), None)
    per_s = received / agent_seconds if agent_seconds > 0 else 0.0
    baseline_per_s = baseline / agent_seconds if agent_seconds > 0 else 0.0
    return {
        "bytes_per_agent_s": round(per_s, 1),
        "whole_map_baseline_bytes_per_agent_s": round(baseline_per_s, 1),
        "baseline_ratio": round(baseline_per_s / per_s, 2) if per_s > 0 else None,
        "baseline_loop_s": loop_s,
        "agent_seconds": round(agent_seconds, 2),
    }


def write_report(out: Path, report: dict[str, Any]) -> Path:
    """Render the figures and report.md from the run directory's files, then write report.json.

    Rendering comes first so report.json names what was written; it never stops report.json being written.
    """
    finish_report(out, report, read_json(out / "observer.json"), read_summaries(out, report))
    path = out / "report.json"
    write_json_atomic(path, report, indent=2)
    return path


def finish_report(
    out: Path, report: dict[str, Any], observer: dict[str, Any] | None, summaries: dict[int, dict[str, Any]]
) -> None:
    """Write the PNG figures and report.md into `out`, filling `plots` and `report_page` in the report.

    A figure that cannot be drawn (a missing world mesh, a matplotlib failure) is logged and recorded as
    `plots_error`; the page is still written, with whatever figures exist, because the numbers matter more.
    """
    try:
        report["plots"] = write_plots(out, report, observer, summaries)
    except Exception as exc:  # noqa: BLE001 - a figure must never cost the run its report
        log.warning("plots not written: %s", exc, exc_info=True)
        report["plots"] = [name for name in PLOT_NAMES if (out / name).exists()]  # the ones drawn before
        report["plots_error"] = f"{type(exc).__name__}: {exc}"
    try:
        write_report_page(out, report)
        report["report_page"] = REPORT_PAGE
    except OSError as exc:
        log.warning("report page not written: %s", exc)
        report["report_page"] = None


def read_summaries(out: Path, report: dict[str, Any]) -> dict[int, dict[str, Any]]:
    """The agents' summaries (agents/agent-K.json) of the report's agents; missing ones are left out."""
    summaries: dict[int, dict[str, Any]] = {}
    for agent in report.get("agents", []):
        summary = read_json(out / "agents" / f"agent-{agent['id']}.json")
        if summary is not None:
            summaries[int(agent["id"])] = summary
    return summaries


def read_json(path: Path) -> dict[str, Any] | None:
    """A JSON status file, or None while it is missing or being replaced."""
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None
