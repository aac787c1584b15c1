"""The mission report (`report.json`): a schema later capabilities extend; existing names never change.

Truth comes from the simulator (distance flown, collisions, landed), communication figures from the agents'
own counters, presence from the observer.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

from swarm import __version__
from swarm.files import write_json_atomic

if TYPE_CHECKING:
    from swarm.mission.run import RunPlan, RunState


def build_report(
    plan: RunPlan, state: RunState, sim: dict[str, Any] | None, observer: dict[str, Any] | None
) -> dict[str, Any]:
    vehicles = {v["id"]: v for v in (sim or {}).get("vehicles", [])}
    routes = {r.drone_id: r for r in plan.routes}
    agents = []
    for k in sorted(state.agents):
        summary = read_json(plan.out / "agents" / f"agent-{k}.json") or {}
        truth = vehicles.get(k, {})
        agents.append(
            {
                "id": k,
                "distance_m": round(float(truth.get("distance_m", 0.0)), 2),
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
            }
        )
    status = state.status
    if status == "complete" and not all(a["landed"] for a in agents):
        status, state.reason = "failed", "an agent exited but its vehicle is not landed and disarmed"
    lo, hi = plan.volume
    return {
        "status": status,
        "reason": state.reason,
        "world": plan.world.name,
        "run_dir": str(plan.out),
        "drones": plan.config.mission.drones,
        "duration_s": round(max(0.0, state.finished - state.started), 2) if state.started else 0.0,
        "collisions": int((sim or {}).get("collisions", 0)),
        "explored_fraction": float((observer or {}).get("explored_fraction", 0.0)),
        "explored_timeline": (observer or {}).get("explored_timeline", []),
        "map": "map.ply" if (plan.out / "map.ply").exists() else None,
        "collision_events": (sim or {}).get("collision_events", []),
        "agents": agents,
        "presence_timeline": (observer or {}).get("timeline", []),
        "mission": {
            "name": plan.config.mission.name,
            "seed": plan.config.mission.seed,
            "max_time_s": plan.config.mission.max_time_s,
            "volume": {"min": [round(float(v), 3) for v in lo], "max": [round(float(v), 3) for v in hi]},
            "spawns": [list(s) for s in plan.spawns],
        },
        "swarm_version": __version__,
    }


def write_report(out: Path, report: dict[str, Any]) -> Path:
    path = out / "report.json"
    write_json_atomic(path, report, indent=2)
    return path


def read_json(path: Path) -> dict[str, Any] | None:
    """A JSON status file, or None while it is missing or being replaced."""
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None
