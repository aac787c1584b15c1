"""Complete, valid examples of the files processes exchange, for tests to start from and override."""

from __future__ import annotations

from typing import Any

from swarm.agent.summary import NO_MAPPING, SCRIPTED_EXPLORATION, AgentSummary
from swarm.mission.files import NO_COVERAGE, MissionReport, ObserverStatus
from swarm.patches.digest import PatchDigest
from swarm.patches.patch import PatchId
from swarm.sim.status import SimStatus, VehicleStatus

TRAFFIC = {"state": {"sent_msgs": 3, "sent_bytes": 300, "recv_msgs": 6, "recv_bytes": 600, "dropped": {}}}


def sync_stats(held_seqs: tuple[int, ...] = (0, 1)) -> dict[str, Any]:
    return {
        "patches_held": len(held_seqs),
        "patches_requested": 1,
        "patches_served": 1,
        "patches_pushed": 1,
        "received_by_push": 1,
        "received_by_pull": 1,
        "duplicate_chunks": 0,
        "requests_served": 1,
        "requests_refused": 0,
        "request_timeouts": 0,
        "push_chunks_dropped_on_purpose": 0,
        "rejected": {},
        "assembly_dropped": {},
        "limits": {},
        "received_from": {"2": 1},
        "served_to": {"2": 1},
        "holdings": PatchDigest.of(PatchId(1, 1, s) for s in held_seqs).to_wire(),
    }


def agent_summary_data(agent_id: int = 1, **overrides: Any) -> dict[str, Any]:
    return {
        "id": agent_id,
        "epoch": 1,
        "phase": "landed",
        "landed": True,
        "distance_m": 12.5,
        "duration_s": 30.0,
        "bytes_sent": 1000,
        "bytes_received": 2000,
        "traffic": TRAFFIC,
        "peers_seen": [2],
        "peer_events": [{"t": 1.5, "event": "joined", "peer": 2, "cause": "heartbeat"}],
        "mavsdk_released": True,
        "sync": sync_stats(),
        "heartbeats_on_wrong_key": 0,
        "stale_heartbeats": 0,
        "bus_route_refreshes": 0,
        "give_way": 0,
        "battery_min_fraction": 0.8,
        "timeline": [[float(i), 100 * i, 200 * i] for i in range(5)],
        **SCRIPTED_EXPLORATION,
        **NO_MAPPING,
        "stages": {"integrate": {"calls": 10, "total_ms": 52.0, "p50_ms": 5.1, "max_ms": 8.3}},
        **overrides,
    }


def agent_summary(agent_id: int = 1, **overrides: Any) -> AgentSummary:
    return AgentSummary.model_validate(agent_summary_data(agent_id, **overrides))


def vehicle_status(vehicle_id: int = 1, **overrides: Any) -> VehicleStatus:
    return VehicleStatus.model_validate(
        {
            "id": vehicle_id,
            "vehicle_port": 14540 + vehicle_id,
            "gcs_port": 14640 + vehicle_id,
            "home": [0.0, 0.0, 0.0],
            "position": [1.0, 2.0, 0.0],
            "velocity": [0.0, 0.0, 0.0],
            "armed": False,
            "mode": "HOLD",
            "landed_state": "on_ground",
            "distance_m": 12.5,
            "battery": 0.9,
            "global_position": True,
            "local_origin": [0.0, 0.0, 0.0],
            "collisions": 0,
            "closest_world_m": None,
            "closest_world_at": None,
            "closest_drone_m": 1.5,
            "gcs_seen": True,
            "last_gcs_message_age_s": 0.1,
            **overrides,
        }
    )


def sim_status(*vehicles: VehicleStatus, **overrides: Any) -> SimStatus:
    return SimStatus.model_validate(
        {
            "ready": True,
            "done": False,
            "t": 10.0,
            "world": "box",
            "collisions": 0,
            "collision_events": [],
            "stalls": [],
            "vehicles": [v.model_dump() for v in (vehicles or (vehicle_status(),))],
            **overrides,
        }
    )


def observer_status_data(**overrides: Any) -> dict[str, Any]:
    return {
        "done": False,
        "t": 10.0,
        "agents": {"1": {"heartbeats": 3, "alive": True, "phase": "flying", "role": "leader", "leader": 1}},
        "timeline": [{"t": 0.5, "event": "joined", "agent": 1}],
        "traffic": TRAFFIC,
        "trajectories": {"1": [[0.5, 1.0, 2.0, 1.0]]},
        "leaders": [{"t": 0.5, "leader": 1, "members": [1]}],
        "leader_changes": 0,
        **NO_COVERAGE,
        **overrides,
    }


def observer_status(**overrides: Any) -> ObserverStatus:
    return ObserverStatus.model_validate(observer_status_data(**overrides))


def agent_row_data(agent_id: int = 1, **overrides: Any) -> dict[str, Any]:
    return {
        "id": agent_id,
        "distance_m": 12.5,
        "closest_world_m": None,
        "closest_world_at": None,
        "closest_drone_m": 1.5,
        "bytes_sent": 1000,
        "bytes_received": 2000,
        "landed": True,
        "phase": "landed",
        "exit_code": 0,
        "route_length_m": None,
        "peers_seen": [2],
        "patches_sealed": 7,
        "frames": 40,
        "mapping_ms_per_frame": 6.0,
        "frame_rate_hz": 5.0,
        "sensor_stream": None,
        "patches_held": 14,
        "patches_requested": 2,
        "patches_served": 1,
        "patches_received": {"push": 5, "pull": 2},
        "patches_rejected": {},
        "duration_s": 30.0,
        "traffic": TRAFFIC,
        "targets_assigned": 3,
        "targets_self_selected": 0,
        "exploration_done_reason": None,
        "frontiers_given_up": [],
        **overrides,
    }


def mission_report_data(**overrides: Any) -> dict[str, Any]:
    return {
        "schema_version": 1,
        "status": "complete",
        "reason": "every drone explored and landed",
        "world": "box",
        "run_dir": "runs/test",
        "drones": 1,
        "duration_s": 23.4,
        "started_at": 1_700_000_000.0,
        "collisions": 0,
        "explored_fraction": 1.0,
        "explored_timeline": [[0.0, 0.0], [10.0, 1.0]],
        "time_to": {"0.5": 10.0, "0.9": 10.0, "0.95": 10.0, "0.99": 10.0},
        "explored_by_agent": {"1": [[0.0, 0.0], [10.0, 1.0]]},
        "overlap_fraction": 0.0,
        "leaders": [{"t": 0.5, "leader": 1, "members": [1]}],
        "faults": [],
        "leader_changes": 0,
        "network": "loopback",
        "scenario": None,
        "impairments": [],
        "partitions": [],
        "convergence_after_heal_s": [],
        "map": None,
        "phantoms": None,
        "converged": True,
        "bandwidth": {
            "bytes_per_agent_s": 4321.5,
            "whole_map_baseline_bytes_per_agent_s": 74548.0,
            "baseline_ratio": 17.25,
            "baseline_loop_s": 2.0,
            "agent_seconds": 30.0,
        },
        "collision_events": [],
        "sim_stalls": [],
        "priority": {"asked": {"sim": -5, "agents": 0}, "got": {"sim": 0, "agents": {"1": 0}}, "granted": False},
        "agents": [agent_row_data()],
        "presence_timeline": [{"t": 0.5, "event": "joined", "agent": 1}],
        "mission": {
            "name": "test",
            "seed": 1,
            "max_time_s": 300.0,
            "volume": {"min": [0.0, 0.0, 0.0], "max": [10.0, 10.0, 3.0]},
            "spawns": [[1.0, 1.0, 0.0]],
            "world": "box",
            "strategy": "coordinated",
        },
        "plots": [],
        "report_page": None,
        "swarm_version": "0.0.0",
        **overrides,
    }


def mission_report(**overrides: Any) -> MissionReport:
    return MissionReport.model_validate(mission_report_data(**overrides))
