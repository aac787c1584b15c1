"""`swarm deploy mission`: the ground station of a compose deployment, in the observer's container.

`swarm run` is one process that starts the others, watches them end and writes `report.json`. In a compose
project nobody holds the agents' processes, so this command does the orchestrator's remaining part from the
files every container writes into the shared results directory:

1. it starts `swarm observe` (this container's whole reason to be: presence, leaders, the fused map);
2. the mission has ended when every agent has written its summary (`agents/agent-K.json`, written as it
   exits, after landing), or at the time limit: `mission.max_time_s` (each agent's own `timeout`) plus the
   landing grace and START_MARGIN_S for containers that start late;
3. it stops the observer (SIGTERM: it writes `map.ply` and its last `observer.json`) and writes `report.json`
   with `swarm.mission.report.build_report`, as `swarm run` does. Each agent's exit code is the one its phase
   gives (landed 0, failsafe 3, else 1), the code `swarm agent` exits with. `network` is "compose" and
   `scenario.backend` / `impairments` name what each agent's `swarm deploy netem` applied (its
   `agents/radio-K.json`), so the report never claims a loss that no container applied.

It exits 0 when the report says complete, 1 otherwise: `docker compose wait observer` (`podman wait
<project>_observer_1`) returns with the mission and says how it went. Not `up --exit-code-from observer`: that
stops every container when the first one exits, and the first agent to land exits while the others still
linger to finish their patch exchange.
"""

from __future__ import annotations

import signal
import time
from pathlib import Path
from typing import Any

from swarm.agent.main import EXIT_FAILSAFE, EXIT_FLIGHT_FAILED, EXIT_OK
from swarm.config import SwarmConfig
from swarm.deploy.radio import RadioImpairment
from swarm.errors import SwarmError
from swarm.files import FileFormatError, read_model
from swarm.mission.files import NicenessGot, Priority
from swarm.mission.processes import start_child, stop_all, swarm_command
from swarm.mission.report import build_report, read_observer_status, read_sim_status, read_summary, write_report
from swarm.mission.run import RunPlan, RunState
from swarm.sim.status import SimStatus
from swarm.sim.worlds import load_world, mission_time_limit_s, mission_volume, spawn_points

POLL_S = 1.0
START_MARGIN_S = 120.0  # the agents start after the simulator is ready, which is after this container started
LANDING_GRACE_S = 60.0  # as compose.AGENT_STOP_GRACE_S: an agent at its time limit lands first
OBSERVER_GRACE_S = 60.0  # the final map of a large mission takes a while
_PHASE_EXIT = {"landed": EXIT_OK, "failsafe": EXIT_FAILSAFE}


def radio_record_path(results: Path, k: int) -> Path:
    return results / "agents" / f"radio-{k}.json"


def link_report(results: Path, drones: int) -> dict[str, Any]:
    """`scenario` and `impairments` of the report from the agents' radio records (missing ones named)."""
    impairments: list[dict[str, Any]] = []
    backends: set[str] = set()
    missing: list[int] = []
    for k in range(1, drones + 1):
        path = radio_record_path(results, k)
        if not path.exists():
            missing.append(k)
            continue
        radio = read_model(path, RadioImpairment)
        if radio.backend is None:
            continue
        backends.add(radio.backend)
        profile = f"loss {radio.loss:g}" + (f", delay {radio.delay_ms:g} ms" if radio.delay_ms else "")
        impairments.append({"t": 0.0, "at": 0.0, "link": f"radio-{k}", "profile": profile, "backend": radio.backend})
    backend = ",".join(sorted(backends)) if backends else None
    scenario = {"name": "compose radio", "takeoff_t": None, "backend": backend, "unrecorded_radios": missing}
    return {"scenario": scenario, "impairments": impairments}


def _plan(config: SwarmConfig, results: Path) -> RunPlan:
    m = config.mission
    world = load_world(m.world)
    lo, hi = mission_volume(world, m.volume)
    spawns = spawn_points(world, m.start, m.drones, m.spawn_spacing_m)
    return RunPlan(config, world, results, spawns, [], (lo, hi))


def run_ground_station(config: SwarmConfig, config_path: Path, results: Path) -> dict[str, Any]:
    """Observe until the agents are done (or the time limit), then write results/report.json; returns it."""
    plan = _plan(config, results)
    drones = config.mission.drones
    limit = mission_time_limit_s(config.mission, plan.world) + LANDING_GRACE_S + START_MARGIN_S
    state = RunState(started=time.monotonic(), started_wall=time.time())
    observer = start_child(
        "observer",
        swarm_command(
            "observe",
            "--config",
            str(config_path),
            "--status",
            str(results / "observer.json"),
            "--patches",
            str(results / "agents" / "patches"),
            "--map",
            str(results / "map.ply"),
            "--since",
            f"{state.started_wall:.3f}",
        ),
        results / "observer.log",
    )
    stopping: list[int] = []
    previous = signal.signal(signal.SIGTERM, lambda signum, frame: stopping.append(signum))
    try:
        while True:
            summaries = {k: read_summary(results, k) for k in range(1, drones + 1)}
            done = {k: s for k, s in summaries.items() if s is not None}
            elapsed = time.monotonic() - state.started
            if len(done) == drones:
                state.status, state.reason = "complete", "exploration done and every drone landed"
                break
            if observer.poll() is not None:
                state.status, state.reason = "failed", f"observer died: {observer.last_log_line()}"
                break
            if stopping:
                state.status, state.reason = "interrupted", "the ground station was stopped (SIGTERM)"
                break
            if elapsed > limit:
                missing = sorted(set(range(1, drones + 1)) - set(done))
                state.status, state.reason = "timeout", f"after {limit:.0f} s agents {missing} had not finished"
                break
            time.sleep(POLL_S)
        state.finished = time.monotonic()
        for k, summary in done.items():
            state.exit_codes[k] = _PHASE_EXIT.get(summary.phase, EXIT_FLIGHT_FAILED)
        failed = {k: c for k, c in state.exit_codes.items() if c != EXIT_OK}
        if state.status == "complete" and failed:
            state.status, state.reason = "failed", f"agents exited with errors: {failed}"
    finally:
        stop_all([observer], grace_s=OBSERVER_GRACE_S)
        signal.signal(signal.SIGTERM, previous)
    state.agents = {k: observer for k in range(1, drones + 1)}  # build_report lists the agents it is given
    report = build_report(plan, state, read_sim_status(results), read_observer_status(results))
    report.network = "compose"
    # the niceness of processes in other containers is not known here: none is claimed
    report.priority = Priority(asked=report.priority.asked, got=NicenessGot(sim=None, agents={}), granted=False)
    links = link_report(results, drones)
    report.scenario, report.impairments = links["scenario"], links["impairments"]
    write_report(results, report)
    return {"status": report.status, "reason": report.reason, "explored": report.explored_fraction}


def wait_for_simulator(status: Path, timeout_s: float) -> None:
    """Return once the simulator's status file says ready; SwarmError (one line) after `timeout_s`."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            if read_model(status, SimStatus).ready:
                return
        except (FileNotFoundError, FileFormatError):
            pass  # not written yet
        time.sleep(POLL_S / 2)
    raise SwarmError(f"the simulator did not say ready in {status} within {timeout_s:g} s")


def wait_sim_command(status: Path, timeout_s: float) -> int:
    wait_for_simulator(status, timeout_s)
    print(f"simulator ready ({status})", flush=True)
    return 0


def deploy_mission_command(config: SwarmConfig, config_path: Path, results: Path) -> int:
    if not results.is_dir():
        raise SwarmError(f"results directory {results} does not exist (mount it)")
    outcome = run_ground_station(config, config_path, results)
    print(
        f"mission {outcome['status']}: {outcome['reason']}; explored {outcome['explored']:.3f}; "
        f"report {results / 'report.json'}",
        flush=True,
    )
    return 0 if outcome["status"] == "complete" else 1
