"""`swarm run`: a whole simulated swarm on one machine, from one command, with a report at the end.

It is assembled from the same processes a real deployment uses: one `swarm sim` (every vehicle), one
`swarm agent` per drone, and one `swarm observe`. Everything it needs is checked before anything starts
(world, start point, ports), so bad input is one line and leaves no process behind; every child is stopped on
every exit path.

With `mission.network = "netns"` (`swarm run --network netns [--links scenario.toml]`) each agent runs in its own
network namespace of a `swarm.netem.SwarmNetwork`: Zenoh between agents goes over the virtual radio only (the
namespace's eth0), which the scenario impairs (`swarm.mission.links`); the agent's MAVLink to the simulator and
the observer's connection to the agent use the node's control link, which is never impaired. The observer is a
Zenoh peer there, because a router would relay between agents whose radio link is cut. The network and every
rule are removed on every exit path.

Run directory layout: config/ (the exact config each process ran with), logs/ (one log per process),
sim.json and observer.json (live status, final at the end), agents/agent-K.json and agent-K.ply (each agent's
summary and map), agents/patches/ (every sealed patch, wire format), map.ply (the swarm's fused map) and
report.json.
"""

from __future__ import annotations

import datetime as dt
import json
import shutil
import signal
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from swarm.config import (
    TLS_OBSERVER_NAME,
    Box,
    ConfigError,
    SwarmConfig,
    Vec3,
    bus_port,
    dump_config,
    gcs_port,
    gcs_port_shared,
    sim_autopilot_url,
    tls_drone_name,
    vehicle_port,
)
from swarm.deploy.certs import make_certs, make_signing_authority
from swarm.errors import SwarmError
from swarm.mission.faults import FaultInjector
from swarm.mission.files import MissionReport
from swarm.mission.links import LinkController
from swarm.mission.ports import SENSOR_PORT_OFFSET, ensure_free
from swarm.mission.processes import Child, start_child, stop_all, swarm_command
from swarm.mission.progress import ProgressView
from swarm.mission.report import (
    build_report,
    read_observer_status,
    read_sim_status,
    read_summaries,
    run_priority,
    write_report,
)
from swarm.mission.rrd_files import DEPTH_RECORDING_NAME, RECORDING_NAME, run_recording_id
from swarm.netem.commands import NetemUnavailable, check_prerequisites
from swarm.netem.network import SwarmNetwork
from swarm.netem.profile import refuse_delay
from swarm.netem.scenario import Scenario, load_scenario
from swarm.sim.routes import ScriptedRoute, scripted_routes
from swarm.sim.worlds import World, load_world, mission_time_limit_s, mission_volume, spawn_points

READY_TIMEOUT_S = 60.0  # for the simulator and the observer to come up (a loaded machine is slow to start them)
LANDING_GRACE_S = 60.0
POLL_PERIOD_S = 0.25
# The radio carries one TCP link per pair of drones. A second, UDP link per pair (`max_links=2`, so heartbeats
# skip TCP's head-of-line blocking) broke reconnection after a cut heals: Zenoh 1.10.2 re-establishes the two
# links of a router pair inconsistently ("Received router declaration with unknown routing context id", Zenoh
# issues #1886 and #2130), and the healed drone stayed deaf to a peer for the rest of the mission in about one
# cut-and-heal run in four. TCP alone rejoined every time; with the 20 ms rto_min it also holds up at 30 % loss.
RADIO_PROTOCOLS = ("tcp",)
# In `swarm run` the simulated cameras ("sim", the default, or "zenoh" said outright) are `swarm cameras`
# publishing ROS 2 streams, and every agent maps from those streams (camera.source = "zenoh"), as on a real drone.
STREAMED_SOURCES = ("sim", "zenoh")
NO_WORLD_FOR_AGENTS = "no-world-for-agents.ply"  # camera.source = "zenoh": what agents are told the world is
INTERRUPTED = "interrupted"  # the reason of a mission stopped by Ctrl-C or SIGTERM


@dataclass
class RunPlan:
    config: SwarmConfig
    world: World
    out: Path
    spawns: list[Vec3]
    routes: list[ScriptedRoute]
    volume: tuple[np.ndarray, np.ndarray]
    scenario: Scenario | None = None
    sensor_port: int | None = None  # the simulator's sensor router (camera.source = "zenoh")


@dataclass
class RunState:
    sim: Child | None = None
    cameras: Child | None = None  # `swarm cameras`, with camera.source = "zenoh"
    observer: Child | None = None
    agents: dict[int, Child] = field(default_factory=dict)
    exit_codes: dict[int, int] = field(default_factory=dict)
    net: SwarmNetwork | None = None
    links: LinkController | None = None
    faults: FaultInjector | None = None
    agent_argv: dict[int, list[str]] = field(default_factory=dict)
    started: float = 0.0
    started_wall: float = 0.0
    stream_to: str | None = None  # a live viewer's gRPC proxy URL (swarm run --view)
    finished: float = 0.0
    status: str = "failed"
    reason: str = ""

    @property
    def children(self) -> list[Child]:
        return [c for c in (*self.agents.values(), self.observer, self.cameras, self.sim) if c is not None]


def prepare(config: SwarmConfig) -> RunPlan:
    """Validate everything and plan the flights; raises SwarmError (one line) before any process starts."""
    world = load_world(config.mission.world)
    lo, hi = mission_volume(world, config.mission.volume)
    config = with_time_limit(config, world)
    m = config.mission
    spawns = spawn_points(world, m.start, m.drones, m.spawn_spacing_m)
    scenario = None
    if m.network == "netns":
        scenario = _netns_scenario(config)
    else:
        host = config.sim.host
        for k in range(1, m.drones + 1):
            ensure_free(host, vehicle_port(config.sim, k), "udp", f"vehicle {k}")
            if not gcs_port_shared(k):  # a shared one is no agent's: theirs dial their vehicles
                ensure_free(host, gcs_port(config.sim, k), "udp", f"autopilot link of agent {k}")
        for k in range(0, m.drones + 1):
            what = "observer bus" if k == 0 else f"bus of agent {k}"
            ensure_free("127.0.0.1", bus_port(config.bus, k), "tcp", what)
    routes: list[ScriptedRoute] = []
    if config.explore.strategy == "scripted":
        routes = scripted_routes(world, spawns, lo, hi, config.sim.drone_radius_m, config.agent.cruise_speed_m_s)
    out = m.out or Path("runs") / f"{dt.datetime.now():%Y%m%d-%H%M%S}-{world.name}"
    if out.exists() and any(out.iterdir()):
        raise SwarmError(f"output directory {out} is not empty")
    sensor_port = None
    if m.record and config.camera.source not in STREAMED_SOURCES:
        raise ConfigError(
            f'mission.record needs camera.source = "sim" or "zenoh", not "{config.camera.source}": '
            "only the simulated cameras' streams can be recorded"
        )
    if config.camera.source in STREAMED_SOURCES:
        sensor_port = bus_port(config.bus, SENSOR_PORT_OFFSET)
        if m.network == "loopback":
            ensure_free(config.sim.host, sensor_port, "tcp", "sensor streams")
    return RunPlan(config, world, out, spawns, routes, (lo, hi), scenario, sensor_port)


def with_time_limit(config: SwarmConfig, world: World) -> SwarmConfig:
    """`config` with `mission.max_time_s` set (`mission_time_limit_s`)."""
    limit = mission_time_limit_s(config.mission, world)
    return config.model_copy(update={"mission": config.mission.model_copy(update={"max_time_s": limit})})


def _netns_scenario(config: SwarmConfig) -> Scenario:
    """Root and the tools, and a scenario this backend can apply in full (an empty one without --links)."""
    check_prerequisites()
    m = config.mission
    if m.links is None:
        return Scenario(name="unimpaired")
    scenario = load_scenario(m.links)
    scenario.check_drones(m.drones)
    for event in scenario.events:
        try:
            refuse_delay(event.profile())
        except NetemUnavailable as exc:
            raise NetemUnavailable(f"{m.links}: the event at {event.at:g} s: {exc}") from None
        if event.rate_kbit:
            raise NetemUnavailable(
                f"{m.links}: the event at {event.at:g} s asks for a rate limit; the netns run "
                "applies loss and cuts only (rates: swarm netem apply)"
            )
    return scenario


def _bus_for(config: SwarmConfig, index: int) -> dict[str, Any]:
    """Loopback endpoints: process `index` (0 = observer, k = agent k) listens on its port, dials lower ones."""
    return {
        "listen": [f"tcp/127.0.0.1:{bus_port(config.bus, index)}"],
        "connect": [f"tcp/127.0.0.1:{bus_port(config.bus, j)}" for j in range(index)],
    }


def _with_tls(plan: RunPlan, bus: dict[str, Any], name: str) -> dict[str, Any]:
    """With mission.tls, the same endpoints over mutual TLS, with certificate `name` from OUT/certs."""
    if not plan.config.mission.tls:
        return bus

    def secure(endpoints: list[str]) -> list[str]:
        return ["tls/" + e.removeprefix("tcp/") if e.startswith("tcp/") else e for e in endpoints]

    return {
        **bus,
        "listen": secure(bus["listen"]),
        "connect": secure(bus["connect"]),
        "tls_dir": plan.out / "certs",
        "tls_name": name,
    }


def _keys_dir(plan: RunPlan) -> Path:
    """Without TLS, the mission's own patch signing authority and the drones' signing keys."""
    return plan.out / "keys"


def _write_config(path: Path, config: SwarmConfig) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(tomli_w.dumps(dump_config(config)))
    return path


def run_mission(
    config: SwarmConfig,
    *,
    live: bool | None = None,
    on_tick: Callable[[RunState], None] | None = None,
    plan: RunPlan | None = None,
    stream_to: str | None = None,
) -> dict[str, Any]:
    """Run the mission to its end and return the report (also written to OUT/report.json); with `stream_to` (a
    Rerun viewer's gRPC proxy URL) its recording is also streamed there live."""
    plan = plan or prepare(config)
    out = plan.out
    out.mkdir(parents=True, exist_ok=True)
    state = RunState(stream_to=stream_to if config.mission.rrd else None)
    view = ProgressView(plan, live=live)
    try:
        if plan.scenario is not None:
            state.net = SwarmNetwork(plan.config.mission.drones).up()
            state.links = LinkController(state.net, plan.scenario, plan.config.mission.drones)
        _start_simulator(plan, state)
        _start_swarm(plan, state)
        _warn_unless_prioritised(plan, state)
        if plan.config.mission.faults:
            state.faults = FaultInjector(
                plan.config.mission.faults, _control_path(plan), lambda k, n: _restart_agent(plan, state, k, n)
            )
        with view:
            _supervise(plan, state, view, on_tick)
    except KeyboardInterrupt:
        state.status, state.reason = "failed", INTERRUPTED
        _land_agents(state)
    finally:
        if state.faults is not None:
            state.faults.finish()
        codes = stop_all(state.children, grace_s=10.0)
        for k, child in state.agents.items():
            state.exit_codes.setdefault(k, codes.get(child.name, -1))
        if not state.finished:
            state.finished = time.monotonic()
        if state.net is not None:
            state.net.down()
        if state.links is not None:
            state.links.finish(state.finished - state.started)
        shutil.rmtree(_agents_tmp(plan), ignore_errors=True)
    report = build_report(plan, state, read_sim_status(out), read_observer_status(out))
    write_report(out, report)
    if plan.config.mission.rrd:
        _record_report(plan, state, report)
    return json.loads(report.to_json())  # the report as report.json holds it


def _record_report(plan: RunPlan, state: RunState, report: MissionReport) -> None:
    """Add the harness's part to OUT/run.rrd; a recording that cannot be written never costs the run its report."""
    from swarm.mission.agent_views import record_agent_views
    from swarm.mission.recording import add_report  # rerun: 0.5 s to import

    recording_id = run_recording_id(plan.out, state.started_wall)
    summaries = read_summaries(plan.out, report)
    try:
        add_report(plan.out, recording_id, report, summaries, state.stream_to)
    except Exception as exc:  # noqa: BLE001 - as the figures: the report stands without it
        print(f"swarm run: warning: {RECORDING_NAME} not completed: {type(exc).__name__}: {exc}", file=sys.stderr)
    try:
        record_agent_views(
            plan.out, recording_id, state.started_wall, plan.config, plan.volume, summaries, state.stream_to
        )
    except Exception as exc:  # noqa: BLE001 - likewise
        print(f"swarm run: warning: agents' own recordings not written: {type(exc).__name__}: {exc}", file=sys.stderr)


def was_interrupted(report: dict[str, Any]) -> bool:
    """The mission ended on Ctrl-C or SIGTERM (it landed and cleaned up): a caller running several stops here."""
    return report.get("reason") == INTERRUPTED


def _start_simulator(plan: RunPlan, state: RunState) -> None:
    sim_config = plan.config.model_copy(deep=True)
    sim_config.sim.spawns = plan.spawns
    if state.net is not None:
        sim_config.sim.host = state.net.layout.control_host_address
    sim_config.sim.status_path = plan.out / "sim.json"
    if plan.sensor_port is not None:
        sim_config.sim.sensor_listen = [f"tcp/{sim_config.sim.host}:{plan.sensor_port}"]
    if plan.config.mission.faults:
        sim_config.sim.control_path = _control_path(plan)
    path = _write_config(plan.out / "config" / "sim.toml", sim_config)
    state.sim = start_child(
        "sim",
        swarm_command("sim", "--config", str(path)),
        plan.out / "logs" / "sim.log",
        nice=plan.config.mission.sim_nice,
    )

    def ready() -> bool:
        status = read_sim_status(plan.out)
        return status is not None and status.ready

    _wait_until_ready(state.sim, "simulator", ready)


def _wait_until_ready(child: Child, what: str, ready: Callable[[], bool]) -> None:
    """Block until `ready()`; a clear error if the child exits first or is not ready in time."""
    deadline = time.monotonic() + READY_TIMEOUT_S
    while not ready():
        if child.poll() is not None:
            raise SwarmError(f"{what} exited early: {child.last_log_line() or 'no output'}")
        if time.monotonic() > deadline:
            raise SwarmError(f"{what} not ready within {READY_TIMEOUT_S:.0f} s (see {child.log_path})")
        time.sleep(0.1)


def _sensor_endpoint(plan: RunPlan, host: str) -> str:
    assert plan.sensor_port is not None
    return f"tcp/{host}:{plan.sensor_port}"


def _start_cameras(plan: RunPlan, state: RunState, host: str) -> None:
    """With camera.source = "zenoh", the simulated cameras as ROS 2 camera drivers, on the simulator's odometry."""
    if plan.sensor_port is None:
        return
    config = plan.config.model_copy(deep=True)
    config.camera.stream = config.camera.stream.model_copy(
        update={"connect": [_sensor_endpoint(plan, host)], "mode": "client", "listen": []}
    )
    path = _write_config(plan.out / "config" / "cameras.toml", config)
    state.cameras = start_child(
        "cameras",
        swarm_command("cameras", "--config", str(path), *_depth_recording_flags(plan, state)),
        plan.out / "logs" / "cameras.log",
        nice=plan.config.mission.sim_nice,
    )


def _agent_camera(plan: RunPlan, state: RunState, k: int) -> dict[str, Any]:
    """Agent k's camera and mission volume updates: with camera.source = "zenoh" it hears /drone<k>'s camera
    through the simulator's sensor router, and knows the mission volume from its config, not from a world."""
    if plan.sensor_port is None:
        return {}
    host = state.net.layout.control_host_address if state.net is not None else plan.config.sim.host
    stream = plan.config.camera.stream.under_vehicle(k).model_copy(
        update={"connect": [_sensor_endpoint(plan, host)], "mode": "client", "listen": []}
    )
    lo, hi = plan.volume
    # The agent is given no world at all: a path that does not exist, so that any attempt to load one fails.
    mission = plan.config.mission.model_copy(
        update={
            "volume": Box(
                min=(float(lo[0]), float(lo[1]), float(lo[2])), max=(float(hi[0]), float(hi[1]), float(hi[2]))
            ),
            "world": str(plan.out / "config" / NO_WORLD_FOR_AGENTS),
        }
    )
    record = plan.out / "bags" / f"agent-{k}" if plan.config.mission.record else None
    camera = plan.config.camera.model_copy(update={"source": "zenoh", "stream": stream, "record": record})
    return {"camera": camera, "mission": mission}


def _netns_bus_for(config: SwarmConfig, net: SwarmNetwork, index: int) -> dict[str, Any]:
    """Agent k listens on its radio and its control link and dials lower ids over the radio only;
    the observer (index 0) is a peer on the host that dials every agent's control link (a peer never relays)."""
    layout = net.layout
    if index == 0:
        return {
            "mode": "peer",
            "listen": ["tcp/127.0.0.1:0"],
            "connect": [f"tcp/{layout.control_address(k)}:{bus_port(config.bus, k)}" for k in layout.node_ids],
        }
    port = bus_port(config.bus, index)
    return {
        "listen": [f"{proto}/{net.address(index)}:{port}" for proto in RADIO_PROTOCOLS]
        + [f"tcp/{layout.control_address(index)}:{port}"],
        "connect": [
            f"{proto}/{net.address(j)}:{bus_port(config.bus, j)}" for j in range(1, index) for proto in RADIO_PROTOCOLS
        ],
    }


def _start_swarm(plan: RunPlan, state: RunState) -> None:
    config = plan.config
    net = state.net
    if config.mission.tls:  # the CA signs the drones' TLS and patch signing certificates
        make_certs(plan.out / "certs", config.mission.drones)
    elif config.sync.signing_dir is None:  # no TLS: a per-mission authority signs the patch signing certificates
        make_signing_authority(_keys_dir(plan), config.mission.drones)
    observer_bus = _netns_bus_for(config, net, 0) if net is not None else _bus_for(config, 0)
    observer_bus = _with_tls(plan, observer_bus, TLS_OBSERVER_NAME)
    observer_config = config.model_copy(update={"bus": config.bus.model_copy(update=observer_bus)})
    path = _write_config(plan.out / "config" / "observer.toml", observer_config)
    (plan.out / "agents" / "patches").mkdir(parents=True, exist_ok=True)
    state.started, state.started_wall = time.monotonic(), time.time()
    state.observer = start_child(
        "observer",
        swarm_command(
            "observe",
            "--config",
            str(path),
            "--status",
            str(plan.out / "observer.json"),
            "--patches",
            str(plan.out / "agents" / "patches"),
            "--map",
            str(plan.out / "map.ply"),
            "--since",
            f"{state.started_wall:.3f}",
            *_recording_flags(plan, state),
        ),
        plan.out / "logs" / "observer.log",
    )
    _start_cameras(plan, state, state.net.layout.control_host_address if state.net is not None else config.sim.host)
    # The observer writes its first status once subscribed. Agents start after that, so the report's timeline and
    # trajectories cover the whole mission even when a loaded machine takes many seconds to start the observer.
    _wait_until_ready(state.observer, "observer", lambda: read_observer_status(plan.out) is not None)
    routes = {route.drone_id: route for route in plan.routes}
    for k in range(1, config.mission.drones + 1):
        if net is not None:
            autopilot = f"udpout://{net.layout.control_host_address}:{vehicle_port(config.sim, k)}"
        else:
            autopilot = sim_autopilot_url(config.sim, k)
        update: dict[str, Any] = {
            "id": k,
            "autopilot": autopilot,
            "out_dir": plan.out / "agents",
            "state_dir": plan.out / "agents" / "state" / f"agent-{k}",
        }
        if not config.sim.gps:  # indoor vehicles: each agent is told where its vehicle's local origin lies
            spawn, offset = plan.spawns[k - 1], config.sim.local_origin_offset
            update |= {"frame": "local", "local_origin": tuple(a + b for a, b in zip(spawn, offset, strict=True))}
        if "px4_params" not in config.agent.model_fields_set:
            update["px4_params"] = "set"  # simulated vehicles: a killed agent's drone holds (docs/architecture.md)
        if k in routes:
            route = routes[k]
            update |= {
                "altitude_m": route.altitude_m,
                "waypoints": route.waypoints,
                "start_delay_s": route.start_delay_s,
            }
        agent = config.agent.model_copy(update=update)
        bus = _netns_bus_for(config, net, k) if net is not None else _bus_for(config, k)
        bus = _with_tls(plan, bus, tls_drone_name(k))
        sync = config.sync
        if not config.mission.tls and sync.signing_dir is None:
            sync = sync.model_copy(update={"signing_dir": _keys_dir(plan)})
        agent_config = config.model_copy(
            update={
                "agent": agent,
                "bus": config.bus.model_copy(update=bus),
                "sync": sync,
                **_agent_camera(plan, state, k),
            }
        )
        path = _write_config(plan.out / "config" / f"agent-{k}.toml", agent_config)
        argv = swarm_command("agent", "--config", str(path))
        if net is not None:
            argv = net.exec_argv(k, argv)
        state.agent_argv[k] = argv
        state.agents[k] = start_child(
            f"agent-{k}", argv, plan.out / "logs" / f"agent-{k}.log", _agent_env(plan), nice=config.mission.agent_nice
        )


def _recording_flags(plan: RunPlan, state: RunState, name: str = RECORDING_NAME) -> list[str]:
    """A recording process's flags: its file OUT/name, the run's recording id, the live viewer if any."""
    if not plan.config.mission.rrd:
        return []
    recording_id = run_recording_id(plan.out, state.started_wall)
    live = ["--stream-to", state.stream_to] if state.stream_to is not None else []
    return ["--record", str(plan.out / name), "--recording-id", recording_id, *live]


def _depth_recording_flags(plan: RunPlan, state: RunState) -> list[str]:
    """With mission.view_depth, the camera driver records each drone's depth image beside run.rrd."""
    if not (plan.config.mission.rrd and plan.config.mission.view_depth):
        return []
    return [*_recording_flags(plan, state, DEPTH_RECORDING_NAME), "--since", f"{state.started_wall:.3f}"]


def _warn_unless_prioritised(plan: RunPlan, state: RunState) -> None:
    p = run_priority(plan, state)
    if not p.granted:
        print(
            f"swarm run: warning: niceness {p.asked.model_dump()} asked, {p.got.model_dump()} given "
            "(lowering it needs root or CAP_SYS_NICE): a burst of load on this machine can stall the simulator's "
            "telemetry for longer than the agents' telemetry timeout and land every drone",
            file=sys.stderr,
            flush=True,
        )


def _control_path(plan: RunPlan) -> Path:
    return plan.out / "sim-control.json"


def _restart_agent(plan: RunPlan, state: RunState, k: int, restart: int) -> Child:
    """A restart fault: agent k again, with the same config and a log of its own (the new process takes a new
    epoch and takes its drone over in the air)."""
    return start_child(
        f"agent-{k}",
        state.agent_argv[k],
        plan.out / "logs" / f"agent-{k}.restart{restart}.log",
        _agent_env(plan),
        nice=plan.config.mission.agent_nice,
    )


def _agent_env(plan: RunPlan) -> dict[str, str]:
    """MAVSDK makes a temporary directory per vehicle it meets and never removes it: the agents' go in the run
    directory (removed at the end of the run), not in /tmp."""
    tmp = _agents_tmp(plan)
    tmp.mkdir(parents=True, exist_ok=True)
    return {"TMPDIR": str(tmp)}


def _agents_tmp(plan: RunPlan) -> Path:
    return plan.out / "agents" / "tmp"


def _supervise(plan: RunPlan, state: RunState, view: ProgressView, on_tick: Callable[[RunState], None] | None) -> None:
    max_time = mission_time_limit_s(plan.config.mission, plan.world)
    while True:
        restarting = state.faults.restarting if state.faults is not None else set()
        for k, child in state.agents.items():
            code = child.poll()
            if code is not None and k not in state.exit_codes and k not in restarting:
                state.exit_codes[k] = code
        elapsed = time.monotonic() - state.started
        sim, observer = read_sim_status(plan.out), read_observer_status(plan.out)
        view.update(elapsed, sim, observer, state.exit_codes)
        if state.links is not None:
            try:
                state.links.tick(elapsed, sim, observer)
            except NetemUnavailable as exc:
                state.status, state.reason = "failed", f"link scenario: {exc}"
                _land_agents(state)
                return
        if state.faults is not None:
            state.faults.tick(elapsed, sim, state.agents)
        if on_tick is not None:
            on_tick(state)
        if len(state.exit_codes) == len(state.agents) and not (state.faults and state.faults.restarting):
            state.finished = time.monotonic()
            failed = {k: c for k, c in state.exit_codes.items() if c != 0 and not _excused(state, k, c)}
            state.status = "failed" if failed else "complete"
            state.reason = f"agents exited with errors: {failed}" if failed else _success_reason(plan.config)
            return
        # without the simulator there is no vehicle; without the cameras the agents would fly blind
        for name, process in (("simulator", state.sim), ("cameras", state.cameras)):
            if process is not None and process.poll() is not None:
                state.status, state.reason = "failed", f"{name} died: {process.last_log_line()}"
                _land_agents(state)
                return
        if elapsed > max_time:
            state.status, state.reason = "timeout", f"max time {max_time:.0f} s reached"
            _land_agents(state)
            state.finished = time.monotonic()
            return
        time.sleep(POLL_PERIOD_S)


def _excused(state: RunState, k: int, code: int) -> bool:
    return state.faults is not None and state.faults.excuses(k, code)


def _success_reason(config: SwarmConfig) -> str:
    if config.explore.strategy == "scripted":
        return "every drone flew its route and landed"
    return "exploration done and every drone landed"


def _land_agents(state: RunState) -> None:
    """SIGTERM makes every agent land and exit; give them time to do it."""
    if state.faults is not None:
        state.faults.finish()  # a frozen agent cannot land
    for child in state.agents.values():
        child.signal(signal.SIGTERM)
    deadline = time.monotonic() + LANDING_GRACE_S
    for k, child in state.agents.items():
        while child.poll() is None and time.monotonic() < deadline:
            time.sleep(0.1)
        if child.poll() is not None:
            state.exit_codes.setdefault(k, child.poll())  # type: ignore[arg-type]
