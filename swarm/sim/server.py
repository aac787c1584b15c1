"""The simulator process: every vehicle of the swarm in one single-threaded selectors loop.

Vehicle k (MAVLink sysid k) binds UDP sim.host:vehicle_port(k) and sends to sim.host:gcs_port(k), as PX4
multi-vehicle SITL does (vehicles 10 and up share the last GCS port, as SITL's do); it answers whoever last sent
it MAVLink, so `udpout://` clients work too, and are how the agents of vehicles sharing a GCS port connect. Physics and
collision checks run at sim.physics_hz; telemetry streams at their own rates (at most once per physics step).
"""

from __future__ import annotations

import errno
import selectors
import signal
import socket
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import cast

import numpy as np

from swarm.bus.session import zenoh_error_text
from swarm.config import ConfigError, SwarmConfig, gcs_port, gcs_port_shared, vehicle_port
from swarm.errors import PortInUseError, SwarmError, WorldError
from swarm.files import FileFormatError, read_model, write_model
from swarm.sim.collisions import CRUISE_HEIGHT_M, CollisionMonitor
from swarm.sim.px4 import FlightMode
from swarm.sim.sensors import OdometryPublisher
from swarm.sim.status import SimControl, SimStatus, VehicleStatus
from swarm.sim.vehicle import Downlink, SimVehicle
from swarm.sim.worlds import World, load_world, mission_volume, spawn_points

STATUS_PERIOD_S = 0.5
MAX_CATCHUP_STEPS = 10  # after a longer stall (e.g. the machine was suspended) the simulation skips time
FLOOR_PROBE_LIFT = np.array([0.0, 0.0, 0.1])  # m above a vehicle's feet
STALL_REPORT_S = 0.5  # a loop iteration this late is reported in the status (`stalls`)
MAX_STALLS_KEPT = 100


class SimServer:
    """Hosts the vehicles; `open()` binds every port, `run(stop)` loops until the event is set."""

    def __init__(self, config: SwarmConfig, world: World, start_time: float | None = None) -> None:
        """`start_time` (monotonic seconds, default now) is t = 0; tests that call step() pick their own clock."""
        self.config = config
        self.world = world
        sim, mission = config.sim, config.mission
        homes = list(sim.spawns) or spawn_points(world, mission.start, mission.drones, mission.spawn_spacing_m)
        _check_homes(world, homes)
        self.ids = list(range(1, len(homes) + 1))
        self._start = time.monotonic() if start_time is None else start_time
        self.vehicles = {
            vid: SimVehicle(
                vid,
                home,
                config,
                Downlink(None, (sim.host, gcs_port(sim, vid))),
                self._start,
                floor_below=self._floor_below,
            )
            for vid, home in zip(self.ids, homes)
        }
        self.collisions = CollisionMonitor(world, self.ids, sim.drone_radius_m)
        self._sockets: dict[int, socket.socket] = {}
        self._lock = threading.Lock()
        self._t = 0.0
        self.stalls: list[dict[str, float]] = []  # late loop iterations (see _note_stall)
        self._ready = False
        self._control_mtime: int | None = None
        self._done = False
        self.odometry: OdometryPublisher | None = None  # opened by open() when sim.sensor_listen is set

    def _floor_below(self, position: np.ndarray) -> float:
        """The world's first surface under a vehicle (looked for from just above its feet, so the floor it
        stands on is found, not the one below that)."""
        return float(self.world.floor_below((np.asarray(position) + FLOOR_PROBE_LIFT)[None, :])[0])

    # --- life cycle --------------------------------------------------------------------------------------------

    def open(self, check_gcs_ports: bool = True) -> None:
        """Bind every vehicle port and (unless told not to) check every GCS port is free; PortInUseError names the
        first taken one. A GCS port is taken legitimately when that drone's agent started first: callers that
        allow this start order pass check_gcs_ports=False (see taken_gcs_ports)."""
        sim = self.config.sim
        vehicle_ports = {vid: vehicle_port(sim, vid) for vid in self.ids}
        gcs_ports: dict[int, int] = {}  # port -> the first vehicle sending there
        for vid in self.ids:
            gcs_ports.setdefault(gcs_port(sim, vid), vid)  # a shared port is checked once
        shared = set(vehicle_ports.values()) & set(gcs_ports)
        if shared:
            raise ConfigError(f"UDP port {min(shared)} is both a vehicle port and a GCS port: separate the port ranges")
        try:
            for vid, port in vehicle_ports.items():
                self._sockets[vid] = _bind_udp(sim.host, port, f"vehicle {vid}")
            if check_gcs_ports:
                for port, vid in gcs_ports.items():
                    _bind_udp(sim.host, port, f"GCS of vehicle {vid}").close()
        except BaseException:
            self.close()
            raise
        for vid, sock in self._sockets.items():
            self.vehicles[vid].downlink.sock = sock
        if sim.sensor_listen:
            try:
                self.odometry = OdometryPublisher(sim.sensor_listen, self.config.camera.stream, self.ids)
            except Exception as exc:
                self.close()
                raise SwarmError(f"sensor streams on {sim.sensor_listen}: {zenoh_error_text(exc)}") from None
        self._ready = True

    def taken_gcs_ports(self) -> list[tuple[int, int]]:
        """(vehicle id, port) of every GCS port something already holds."""
        taken = []
        for vid in self.ids:
            port = gcs_port(self.config.sim, vid)
            if gcs_port_shared(vid):  # its agent dials the vehicle: it never holds this port
                continue
            try:
                _bind_udp(self.config.sim.host, port, "probe").close()
            except PortInUseError:
                taken.append((vid, port))
        return taken

    def close(self) -> None:
        if self.odometry is not None:
            self.odometry.close()
            self.odometry = None
        for vid, sock in self._sockets.items():
            self.vehicles[vid].downlink.sock = None
            sock.close()
        self._sockets.clear()

    def __enter__(self) -> SimServer:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def endpoints(self) -> list[dict]:
        host = self.config.sim.host
        return [
            {
                "id": vid,
                "sysid": vid,
                "vehicle_port": vehicle_port(self.config.sim, vid),
                "gcs_port": gcs_port(self.config.sim, vid),
                "host": host,
                "connect_url": (
                    f"udpout://{host}:{vehicle_port(self.config.sim, vid)}"
                    if gcs_port_shared(vid)
                    else f"udpin://0.0.0.0:{gcs_port(self.config.sim, vid)}"
                ),
            }
            for vid in self.ids
        ]

    def set_telemetry_enabled(self, drone_id: int, enabled: bool) -> None:
        """Fault injection: silence (or restore) everything vehicle `drone_id` sends."""
        vehicle = self._vehicle(drone_id)
        with self._lock:
            vehicle.telemetry_enabled = enabled

    def hold(self, drone_id: int) -> None:
        """Fault injection: switch vehicle `drone_id` to HOLD as a late, retried command would."""
        vehicle = self._vehicle(drone_id)
        with self._lock:
            vehicle.autopilot.set_mode(FlightMode.HOLD, time.monotonic())

    def _vehicle(self, drone_id: int) -> SimVehicle:
        if drone_id not in self.vehicles:
            raise ValueError(f"no vehicle with id {drone_id}")
        return self.vehicles[drone_id]

    def _read_control(self) -> None:
        """Fault injection from `swarm run`: `sim.control_path` holds a `SimControl`. A missing file means no
        fault; an invalid one is reported once (one line) and changes nothing."""
        path = self.config.sim.control_path
        if path is None:
            return
        try:
            stat = path.stat()
        except FileNotFoundError:
            return
        if stat.st_mtime_ns == self._control_mtime:
            return
        self._control_mtime = stat.st_mtime_ns
        try:
            off = set(read_model(path, SimControl).telemetry_off)
        except (OSError, FileFormatError) as exc:
            print(f"swarm sim: ignoring control file {path}: {exc}", file=sys.stderr, flush=True)
            return
        for vid in self.ids:
            self.set_telemetry_enabled(vid, vid not in off)

    # --- the loop ----------------------------------------------------------------------------------------------

    def run(self, stop: threading.Event, on_ready: Callable[[list[dict]], None] | None = None) -> dict:
        """Simulate until `stop` is set; return the final status. Call open() first."""
        if not self._ready:
            raise RuntimeError("SimServer.open() must be called before run()")
        if on_ready is not None:
            on_ready(self.endpoints())
        dt = 1.0 / self.config.sim.physics_hz
        status_path = self.config.sim.status_path
        with selectors.DefaultSelector() as selector:
            for vid, sock in self._sockets.items():
                selector.register(sock, selectors.EVENT_READ, self.vehicles[vid])
            next_step = time.monotonic()
            next_status = next_step
            next_odometry = next_step
            last = next_step
            while not stop.is_set():
                ready = selector.select(max(0.0, next_step - time.monotonic()))
                now = time.monotonic()
                self._note_stall(now - last)
                last = now
                with self._lock:
                    for key, _ in ready:
                        _drain(cast(socket.socket, key.fileobj), key.data, now)
                    if now >= next_step:
                        lag = int((now - next_step) / dt)
                        if lag > MAX_CATCHUP_STEPS:
                            next_step += lag * dt
                        while next_step <= now:
                            self.step(dt, next_step)
                            next_step += dt
                        for vehicle in self.vehicles.values():
                            vehicle.tick(now)
                        if self.odometry is not None and now >= next_odometry:
                            for vid, vehicle in self.vehicles.items():
                                self.odometry.publish(vid, vehicle.autopilot.body)
                            next_odometry = max(next_odometry + 1.0 / self.config.sim.odometry_hz, now)
                    for vehicle in self.vehicles.values():
                        vehicle.downlink.flush()  # replies and telemetry of this iteration, in order
                if status_path is not None and now >= next_status:
                    self.write_status(status_path)
                    next_status = max(next_status + STATUS_PERIOD_S, now)
                    self._read_control()
        self._done = True
        if status_path is not None:
            self.write_status(status_path)
        return self.status()

    def _note_stall(self, gap: float) -> None:
        """Remember a loop iteration that came this late: the process (or the machine) did not run meanwhile,
        and no vehicle sent anything. Agents whose telemetry stops for telemetry_timeout_s fail safe, so a
        mission that ends in failsafe landings is told apart from one where the simulator stalled."""
        if gap >= STALL_REPORT_S and len(self.stalls) < MAX_STALLS_KEPT:
            self.stalls.append({"t": round(self._t, 2), "s": round(gap, 2)})

    def step(self, dt: float, now: float) -> None:
        """One physics step of every vehicle at time `now` (monotonic seconds), then the collision check."""
        for vehicle in self.vehicles.values():
            vehicle.step(dt, now)
        self._t = now - self._start
        aps = [v.autopilot for v in self.vehicles.values()]
        positions = np.array([ap.position for ap in aps])
        airborne = np.array([ap.airborne for ap in aps])
        cruising = np.array([ap.height > CRUISE_HEIGHT_M for ap in aps])
        self.collisions.update(self._t, positions, airborne, cruising)

    # --- status ------------------------------------------------------------------------------------------------

    def status(self) -> dict:
        """The status as plain JSON data (what `sim.json` holds), for in-process callers and tests."""
        return self.status_model().model_dump(mode="json")

    def status_model(self) -> SimStatus:
        with self._lock:
            vehicles = []
            for vid, vehicle in self.vehicles.items():
                v = vehicle.status()
                vehicles.append(
                    VehicleStatus(
                        **{
                            "id": vid,
                            "vehicle_port": vehicle_port(self.config.sim, vid),
                            "gcs_port": gcs_port(self.config.sim, vid),
                            "home": v["home"],
                            "position": v["position"],
                            "velocity": v["velocity"],
                            "armed": v["armed"],
                            "mode": v["mode"],
                            "landed_state": v["landed_state"],
                            "distance_m": v["distance_m"],
                            "battery": v["battery"],
                            "global_position": v["global_position"],
                            "local_origin": v["local_origin"],
                            "collisions": self.collisions.counts[vid],
                            "closest_world_m": _rounded(self.collisions.closest_world(vid)),
                            "closest_world_at": _rounded_point(self.collisions.closest_world_at(vid)),
                            "closest_drone_m": _rounded(self.collisions.closest_drone(vid)),
                            "gcs_seen": v["gcs_seen"],
                            "last_gcs_message_age_s": v["last_gcs_message_age_s"],
                        }
                    )
                )
            return SimStatus.model_validate(
                {
                    "ready": self._ready,
                    "done": self._done,
                    "t": round(self._t, 3),
                    "world": self.world.name,
                    "collisions": self.collisions.total,
                    "collision_events": [e.to_json() for e in self.collisions.events],
                    "stalls": list(self.stalls),
                    "vehicles": vehicles,
                }
            )

    def write_status(self, path: Path) -> None:
        """Write the status JSON atomically (temp file + rename), so a reader never sees half a file."""
        path = Path(path)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            write_model(path, self.status_model(), indent=None)
        except OSError as exc:
            raise SwarmError(f"cannot write simulator status to {path}: {exc.strerror or exc}") from None


def _check_homes(world: World, homes: list[tuple[float, float, float]]) -> None:
    feet = np.array(homes, dtype=np.float64).reshape(-1, 3) + [0.0, 0.0, 0.1]
    for k, inside in enumerate(world.is_inside_solid(feet), start=1):
        if inside:
            x, y, z = homes[k - 1]
            raise WorldError(f"home of vehicle {k} ({x:g}, {y:g}, {z:g}) is inside a wall or another solid")


def _bind_udp(host: str, port: int, role: str) -> socket.socket:
    """A non-blocking UDP socket bound WITHOUT SO_REUSEADDR, so a port someone holds is refused."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.bind((host, port))
    except OSError as exc:
        sock.close()
        if exc.errno == errno.EADDRINUSE:
            raise PortInUseError(f"UDP port {port} ({role}) is already in use") from None
        raise SwarmError(f"cannot bind UDP {host}:{port} ({role}): {exc.strerror or exc}") from None
    sock.setblocking(False)
    return sock


def _drain(sock: socket.socket, vehicle: SimVehicle, now: float) -> None:
    while True:
        try:
            data, addr = sock.recvfrom(65535)
        except ConnectionRefusedError:
            continue  # an ICMP error queued on the socket: this call consumed it
        except OSError:  # BlockingIOError: drained
            return
        vehicle.receive(data, addr, now)


def run_simulator(
    config: SwarmConfig,
    world: World,
    stop: threading.Event,
    on_ready: Callable[[list[dict]], None] | None = None,
    check_gcs_ports: bool = True,
) -> dict:
    """Bind every vehicle (PortInUseError before anything runs), call on_ready(endpoints), simulate until `stop`
    is set, and return the final status."""
    server = SimServer(config, world)
    server.open(check_gcs_ports)
    try:
        return server.run(stop, on_ready)
    finally:
        server.close()


def sim_command(config: SwarmConfig) -> int:
    """`swarm sim`: host the vehicles of config.mission.world until SIGINT/SIGTERM.

    Agents may be started before the simulator (they wait for its heartbeat), so a GCS port that is already
    bound is reported as a warning on stderr rather than refused: it is most likely that drone's agent.
    """
    world = load_world(config.mission.world)
    if not config.sim.sensor_listen and config.camera.source != "none":
        # Alone, the simulator is the robot side's Zenoh router (rmw_zenohd's place): its odometry is where
        # `swarm cameras` and the agents' sensor sessions dial by default (camera.stream.connect).
        config = config.model_copy(
            update={"sim": config.sim.model_copy(update={"sensor_listen": list(config.camera.stream.connect)})}
        )
    server = SimServer(config, world)
    server.open(check_gcs_ports=False)
    stop = threading.Event()
    handlers = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        for vid, port in server.taken_gcs_ports():
            print(
                f"swarm sim: warning: UDP port {port} (GCS of vehicle {vid}) is already bound; fine if it is "
                f"agent {vid}, but a second listener there would split its traffic",
                file=sys.stderr,
            )
        lo, hi = mission_volume(world, config.mission.volume)
        volume = f"mission.volume={{min=[{', '.join(f'{v:g}' for v in lo)}],max=[{', '.join(f'{v:g}' for v in hi)}]}}"
        status = server.run(stop, on_ready=lambda endpoints: _print_endpoints(endpoints, volume, config))
    finally:
        server.close()
        for sig, handler in handlers.items():
            signal.signal(sig, handler)
    print(summary_line(status), flush=True)
    return 0


def _print_endpoints(endpoints: list[dict], volume: str, config: SwarmConfig) -> None:
    """Each vehicle's MAVLink link and its agent's command line (the mission volume: agents load no world)."""
    for ep in endpoints:
        print(
            f"vehicle {ep['id']}: MAVLink udp {ep['host']}:{ep['vehicle_port']} -> {ep['host']}:{ep['gcs_port']}"
            f"  (agent: swarm agent --id {ep['id']} --autopilot {ep['connect_url']} --set agent.px4_params=set"
            f" --set '{volume}')"  # px4_params: with PX4's defaults a dead agent's drone would Return
        )
    if config.sim.sensor_listen:
        print(
            f"sensor streams: odometry on {', '.join(config.sim.sensor_listen)} (the depth cameras: swarm cameras "
            f"--world {config.mission.world} --vehicles {len(endpoints)})"
        )
    sys.stdout.flush()


def _rounded(gap: float | None) -> float | None:
    return None if gap is None else round(gap, 3)


def _rounded_point(point: list[float] | None) -> list[float] | None:
    return None if point is None else [round(c, 3) for c in point]


def summary_line(status: dict) -> str:
    kinds = [e["kind"] for e in status["collision_events"]]
    distances = ", ".join(f"{v['id']}: {v['distance_m']:.1f} m" for v in status["vehicles"])
    return (
        f"sim stopped after {status['t']:.1f} s: {status['collisions']} collisions "
        f"({kinds.count('world')} world, {kinds.count('drone')} drone); distance flown: {distances}"
    )
