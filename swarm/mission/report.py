"""The mission report (`report.json`): a schema later capabilities extend; existing names never change.

Truth comes from the simulator (distance flown, collisions, landed), communication figures from the agents'
own counters, presence, coverage and clusters from the observer. `write_report` also renders the human side of
the report next to it: the figures (`swarm.mission.plots`) and `report.md` (`swarm.mission.report_md`).
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from swarm import __version__
from swarm.agent.summary import AgentSummary
from swarm.files import M, read_model, write_atomic
from swarm.mission.files import (
    NO_COVERAGE,
    AgentRow,
    Bandwidth,
    Defences,
    MissionInfo,
    MissionReport,
    NicenessAsked,
    NicenessGot,
    ObserverStatus,
    Priority,
    ReceivedPatches,
    UnexploredRegion,
    Volume,
)
from swarm.mission.phantoms import phantom_check
from swarm.mission.plots import COVERAGE_TARGET, PLOT_NAMES, write_plots
from swarm.mission.report_md import REPORT_PAGE, write_report_page
from swarm.patches.digest import PatchDigest
from swarm.sim.collisions import GROUND_GAP_M
from swarm.sim.status import SimStatus, VehicleStatus

if TYPE_CHECKING:
    from swarm.mission.run import RunPlan, RunState

log = logging.getLogger(__name__)

TIME_TO_THRESHOLDS = (0.5, 0.9, 0.95, 0.99)

# what the report says when no observer status was ever written: nobody heard, nothing measured
NO_OBSERVER = {
    "done": False,
    "t": 0.0,
    "agents": {},
    "timeline": [],
    "traffic": {},
    "trajectories": {},
    "leaders": [],
    "leader_changes": 0,
    **NO_COVERAGE,
}


def build_report(
    plan: RunPlan, state: RunState, sim: SimStatus | None, observer: ObserverStatus | None
) -> MissionReport:
    vehicles = {v.id: v for v in sim.vehicles} if sim is not None else {}
    routes = {r.drone_id: r for r in plan.routes}
    agents = []
    summaries: dict[int, AgentSummary] = {}
    for k in sorted(state.agents):
        summary = read_summary(plan.out, k)
        if summary is not None:
            summaries[k] = summary
        agents.append(agent_row(k, summary, vehicles.get(k), state.exit_codes.get(k), routes.get(k)))
    status = state.status
    faults = getattr(state, "faults", None)
    must_land = [a for a in agents if faults is None or not faults.killed_for_good(a.id)]
    if status == "complete" and not all(a.landed for a in must_land):
        status, state.reason = "failed", "an agent exited but its vehicle is not landed and disarmed"
    lo, hi = plan.volume
    seen = observer if observer is not None else ObserverStatus.model_validate(NO_OBSERVER)
    explore = getattr(plan.config, "explore", None)
    explored = seen.explored_fraction
    if status == "complete" and _judged_by_coverage(plan.config) and explored < COVERAGE_TARGET:
        status, state.reason = "incomplete", _why_short(explored, agents, seen.unexplored)
    links = state.links.report() if state.links is not None else {}
    return MissionReport(
        status=status,
        reason=state.reason,
        world=plan.world.name,
        run_dir=str(plan.out),
        drones=plan.config.mission.drones,
        duration_s=round(max(0.0, state.finished - state.started), 2) if state.started else 0.0,
        # unix time of the mission clock's zero: an agent log's `t` minus this is the report's mission time
        started_at=round(getattr(state, "started_wall", 0.0), 3),
        collisions=sim.collisions if sim is not None else 0,
        explored_fraction=explored,
        explored_timeline=seen.explored_timeline,
        time_to=time_to(seen.explored_timeline),
        explored_by_agent=seen.explored_by_agent,
        overlap_fraction=seen.overlap_fraction,
        leaders=seen.leaders,
        faults=faults.report() if faults is not None else [],
        leader_changes=seen.leader_changes,
        network=plan.config.mission.network,
        scenario=links.get("scenario"),
        impairments=links.get("impairments", []),
        partitions=links.get("partitions", []),
        convergence_after_heal_s=links.get("convergence_after_heal_s", []),
        map="map.ply" if (plan.out / "map.ply").exists() else None,
        # map surface along the flown paths that the building does not have (drones mapped as obstacles)
        phantoms=phantom_check(
            plan.out / "map.ply", seen.trajectories, plan.world, plan.config.sim.drone_radius_m + GROUND_GAP_M
        ),
        converged=converged(summaries, sealed_patch_ids(plan.out / "agents" / "patches")),
        bandwidth=bandwidth(summaries, seen),
        collision_events=sim.collision_events if sim is not None else [],
        # the simulator's loop ran this late (its process or the machine did not run): no telemetry meanwhile
        sim_stalls=sim.stalls if sim is not None else [],
        priority=run_priority(plan, state),
        agents=agents,
        presence_timeline=seen.timeline,
        mission=MissionInfo(
            name=plan.config.mission.name,
            seed=plan.config.mission.seed,
            max_time_s=plan.config.mission.max_time_s,
            volume=Volume(min=[round(float(v), 3) for v in lo], max=[round(float(v), 3) for v in hi]),
            spawns=[list(s) for s in plan.spawns],
            world=str(plan.config.mission.world),
            strategy=getattr(explore, "strategy", None) or next((s.strategy for s in summaries.values()), None),
        ),
        plots=[],
        report_page=None,
        swarm_version=__version__,
    )


def agent_row(
    k: int, summary: AgentSummary | None, truth: VehicleStatus | None, exit_code: int | None, route: Any
) -> AgentRow:
    """One drone's row: ground truth from the simulator, the rest from its summary. An agent that wrote no
    summary (killed, crashed) has zero counts and phase "unknown"; a vehicle the simulator does not list has
    flown nothing and is not landed."""
    s = summary
    return AgentRow(
        id=k,
        distance_m=round(truth.distance_m, 2) if truth is not None else 0.0,
        closest_world_m=truth.closest_world_m if truth is not None else None,
        closest_world_at=truth.closest_world_at if truth is not None else None,
        closest_drone_m=truth.closest_drone_m if truth is not None else None,
        bytes_sent=s.bytes_sent if s else 0,
        bytes_received=s.bytes_received if s else 0,
        landed=truth is not None and truth.landed_and_disarmed,
        phase=s.phase if s else "unknown",
        exit_code=exit_code,
        route_length_m=round(route.length_m, 2) if route is not None else None,
        peers_seen=s.peers_seen if s else [],
        patches_sealed=s.patches_sealed if s else 0,
        frames=s.frames if s else 0,
        mapping_ms_per_frame=s.mapping_ms_per_frame if s else None,
        frame_rate_hz=s.frame_rate_hz if s else None,
        sensor_stream=s.sensor_stream if s else None,  # camera.source = "zenoh": frames and drops by reason
        patches_held=s.sync.patches_held if s else 0,
        patches_requested=s.sync.patches_requested if s else 0,
        patches_served=s.sync.patches_served if s else 0,
        patches_received=ReceivedPatches(
            push=s.sync.received_by_push if s else 0, pull=s.sync.received_by_pull if s else 0
        ),
        patches_rejected=s.sync.rejected if s else {},
        duration_s=s.duration_s if s else 0.0,
        traffic=s.traffic if s else {},
        targets_assigned=s.targets_assigned if s else 0,
        targets_self_selected=s.targets_self_selected if s else 0,
        exploration_done_reason=(s.exploration_done_reason or None) if s else None,
        frontiers_given_up=s.frontiers_given_up if s else [],
        defences=defences_of(s),
    )


def defences_of(s: AgentSummary | None) -> Defences:
    """The agent's counts of input it left out and writes it could not make (empty without a summary)."""
    if s is None:
        return Defences()
    bus_dropped: Counter[str] = Counter()
    for kind in s.traffic.values():
        bus_dropped.update(kind.dropped)  # adds the counts of every kind, reason by reason
    return Defences(
        exploration_rejected=_nonzero(s.exploration_rejected),
        patches_not_sealed=_nonzero(s.patches_not_sealed),
        patch_store_failures=_nonzero(s.patch_store_failures),
        assembly_dropped=_nonzero(s.sync.assembly_dropped),
        sync_limits=_nonzero(s.sync.limits),
        bus_dropped=_nonzero(dict(sorted(bus_dropped.items()))),
    )


def _nonzero(counts: dict[str, int]) -> dict[str, int]:
    return {reason: count for reason, count in counts.items() if count}


def _judged_by_coverage(config: Any) -> bool:
    """Missions whose drones explore with a camera end `complete` only at COVERAGE_TARGET explored: below it,
    "exploration done" is a verdict the ground truth contradicts (scripted routes and camera-less runs are not
    judged by it)."""
    explore, camera = getattr(config, "explore", None), getattr(config, "camera", None)
    return getattr(explore, "strategy", "scripted") != "scripted" and getattr(camera, "source", "none") != "none"


def _why_short(explored: float, agents: list[AgentRow], unexplored: Sequence[UnexploredRegion] = ()) -> str:
    reasons = sorted({a.exploration_done_reason for a in agents if a.exploration_done_reason})
    given_up = sum(len(a.frontiers_given_up) for a in agents)
    where = ""
    if unexplored:
        r = unexplored[0]
        box = ", ".join(f"{axis} {a:g}-{b:g}" for axis, a, b in zip("xyz", r.lo, r.hi))
        where = f"; the largest unexplored part: {r.volume_m3:g} m3 in {box} (observer.json unexplored)"
    return (
        f"exploration ended at {math.floor(explored * 1000) / 10:.1f} % explored, below {COVERAGE_TARGET:.0%}: "
        f"{'; '.join(reasons) or 'no agent said why'}; {given_up} frontier(s) given up (agents[].frontiers_given_up)"
        f"{where}"
    )


def run_priority(plan: RunPlan, state: RunState) -> Priority:
    """The niceness asked for the simulator and the agents, the one each got, and whether every one got it."""
    m = plan.config.mission
    got = NicenessGot(
        sim=state.sim.nice if state.sim is not None else None,
        agents={str(k): child.nice for k, child in state.agents.items()},
    )
    granted = got.sim == m.sim_nice and all(n == m.agent_nice for n in got.agents.values())
    return Priority(asked=NicenessAsked(sim=m.sim_nice, agents=m.agent_nice), got=got, granted=granted)


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


def held_patch_ids(summary: AgentSummary) -> set[str]:
    """The patch ids an agent held at the end, from the holdings in its summary."""
    return {str(pid) for pid in PatchDigest.from_wire_model(summary.sync.holdings).ids()}


def converged(summaries: dict[int, AgentSummary], sealed: set[str]) -> bool:
    """Every agent ended holding the same patch set, and it is every patch any agent sealed."""
    if not summaries:
        return False
    return all(held_patch_ids(s) == sealed for s in summaries.values())


def bandwidth(summaries: dict[int, AgentSummary], seen: ObserverStatus | None = None) -> Bandwidth:
    """Bus bytes received per agent-second, against the whole-map baseline in the same run.

    Received bytes are what crossed the network (a publication reaches each peer separately). The baseline is
    what it would have cost for every agent to send its whole fused map to every other agent once per
    exploration loop: the sum, over agents and loops, of the map's wire size times the number of receivers.
    Both are divided by the same agent-seconds (each agent's whole run, flight and linger). From the observer
    (`seen`): the bytes of every sealed patch, once each, against the final map's wire size.
    """
    n = len(summaries)
    agent_seconds = sum(s.duration_s for s in summaries.values())
    received = sum(s.bytes_received for s in summaries.values())
    baselines = [s.whole_map_baseline for s in summaries.values() if s.whole_map_baseline is not None]
    baseline = sum(b.bytes for b in baselines) * max(n - 1, 0)
    loop_s = baselines[0].loop_s if baselines else None
    per_s = received / agent_seconds if agent_seconds > 0 else 0.0
    baseline_per_s = baseline / agent_seconds if agent_seconds > 0 else 0.0
    return Bandwidth(
        bytes_per_agent_s=round(per_s, 1),
        whole_map_baseline_bytes_per_agent_s=round(baseline_per_s, 1),
        baseline_ratio=round(baseline_per_s / per_s, 2) if per_s > 0 else None,
        baseline_loop_s=loop_s,
        agent_seconds=round(agent_seconds, 2),
        patch_bytes=seen.patch_bytes if seen is not None else 0,
        map_bytes=seen.map_bytes if seen is not None else 0,
        patch_to_map_ratio=round(seen.patch_bytes / seen.map_bytes, 2) if seen is not None and seen.map_bytes else None,
    )


def write_report(out: Path, report: MissionReport) -> Path:
    """Render the figures and report.md from the run directory's files, then write report.json.

    Rendering comes first so report.json names what was written; it never stops report.json being written.
    """
    finish_report(out, report, read_observer_status(out), read_summaries(out, report))
    path = out / "report.json"
    write_atomic(path, report.to_json().encode())
    return path


def finish_report(
    out: Path, report: MissionReport, observer: ObserverStatus | None, summaries: dict[int, AgentSummary]
) -> None:
    """Write the PNG figures and report.md into `out`, filling `plots` and `report_page` in the report.

    A figure that cannot be drawn (a missing world mesh, a matplotlib failure) is logged and recorded as
    `plots_error`; the page is still written, with whatever figures exist, because the numbers matter more.
    """
    try:
        report.plots = write_plots(out, report, observer, summaries)
    except Exception as exc:  # noqa: BLE001 - a figure must never cost the run its report
        log.warning("plots not written: %s", exc, exc_info=True)
        report.plots = [name for name in PLOT_NAMES if (out / name).exists()]  # the ones drawn before
        report.plots_error = f"{type(exc).__name__}: {exc}"
    try:
        write_report_page(out, report)
        report.report_page = REPORT_PAGE
    except OSError as exc:
        log.warning("report page not written: %s", exc)
        report.report_page = None


def read_summaries(out: Path, report: MissionReport) -> dict[int, AgentSummary]:
    """The agents' summaries (agents/agent-K.json) of the report's agents; missing ones are left out."""
    summaries = {agent.id: read_summary(out, agent.id) for agent in report.agents}
    return {k: s for k, s in summaries.items() if s is not None}


def read_summary(out: Path, agent_id: int) -> AgentSummary | None:
    """Agent K's summary, or None when it wrote none (killed, crashed); FileFormatError when it is invalid."""
    return read_optional(out / "agents" / f"agent-{agent_id}.json", AgentSummary)


def read_sim_status(out: Path) -> SimStatus | None:
    """The simulator's `sim.json`, or None before it is first written."""
    return read_optional(out / "sim.json", SimStatus)


def read_observer_status(out: Path) -> ObserverStatus | None:
    """The observer's `observer.json`, or None before it is first written."""
    return read_optional(out / "observer.json", ObserverStatus)


def read_optional(path: Path, model: type[M]) -> M | None:
    """The file as `model`, or None while it does not exist; FileFormatError when it exists and is invalid."""
    try:
        return read_model(path, model)
    except FileNotFoundError:
        return None


def read_report(path: Path) -> MissionReport:
    """A report.json; FileFormatError (one line) when it is not a valid one."""
    return read_model(path, MissionReport)
