"""Every setting of the swarm, in one place.

The whole configuration is one `SwarmConfig` made of eight sections (mission, agent, sim, bus, camera, mapping,
sync, explore). It loads from a TOML file whose tables have the same names, and any field can be overridden on the
command line with a dotted key (`--set agent.altitude_m=2.0`). A value that does not validate is reported as
one line naming the field; the CLI turns `ConfigError` into exit code 2.

Frames: the world frame is z-up (x east, y north, z up), in metres. The autopilot's local frame is NED with its
origin at the vehicle's home; `GeoOrigin` is the geodetic point that the world origin maps to, shared by the
simulator and every agent so they agree on one world frame.
"""

from __future__ import annotations

import re
import tomllib
from collections.abc import Iterable
from pathlib import Path
from typing import Annotated, Any, Literal, SupportsFloat

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from swarm.errors import SwarmError, validation_problem

# The one 3-vector type of every package: a point or vector, in the world frame (x east, y north, z up) unless named
# otherwise, in metres, m/s or degrees as its field says.
Vec3 = tuple[float, float, float]


def vec3(values: Iterable[SupportsFloat]) -> Vec3:
    """The Vec3 of three numbers (a numpy array, a list, a generator), as plain floats; ValueError for any other
    count."""
    x, y, z = (float(v) for v in values)
    return x, y, z


PositiveFloat = Annotated[float, Field(gt=0)]

_NAME_RE = re.compile(r"^[A-Za-z0-9_-]{1,64}$")

# Port layout, as PX4 multi-vehicle SITL (ROMFS/px4fmu_common/init.d-posix/px4-rc.mavlink: instance i's offboard
# link listens on 14580 + i and sends to 14540 + i, capped at 14549 for i > 9): vehicle with id k (k >= 1,
# MAVLink sysid k) binds vehicle_base_port + k - 1 and sends to gcs_base_port + min(k, SITL_GCS_PORTS) - 1, where
# that drone's agent listens; vehicles SITL_GCS_PORTS and up share the last GCS port, so their agents dial the
# vehicle port instead (udpout: the vehicle answers whoever talks to it), never a GCS port of their own.
DEFAULT_GCS_BASE_PORT = 14540
DEFAULT_VEHICLE_BASE_PORT = 14580
DEFAULT_BUS_BASE_PORT = 7450
SITL_GCS_PORTS = 10


class ConfigError(SwarmError):
    """A configuration that cannot be used; the message is one line meant for a person."""


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", validate_assignment=True)


class GeoOrigin(_Section):
    """The geodetic point of the world frame's origin (PX4 SITL's default home)."""

    lat_deg: float = Field(47.397742, ge=-89.0, le=89.0)
    lon_deg: float = Field(8.545594, ge=-180.0, le=180.0)
    alt_amsl_m: float = 488.0


class Box(_Section):
    """An axis-aligned box in the world frame."""

    min: Vec3
    max: Vec3

    @model_validator(mode="after")
    def _ordered(self) -> Box:
        if any(lo >= hi for lo, hi in zip(self.min, self.max)):
            raise ValueError(f"box min {self.min} must be below max {self.max} on every axis")
        return self


FaultKind = Literal["kill", "restart", "freeze", "telemetry-loss"]
_FAULT_RE = re.compile(r"^(?P<kind>[a-z-]+):agent=(?P<agent>\d+)@(?P<at>\d+(\.\d*)?)(\+(?P<duration>\d+(\.\d*)?))?$")
FAULT_SYNTAX = "KIND:agent=K@T[+D], KIND one of kill, restart, freeze, telemetry-loss (e.g. freeze:agent=3@40+10)"


class FaultSpec(_Section):
    """One fault injected into a `swarm run` mission `at` seconds after take-off (`swarm.mission.faults`).

    kill: SIGKILL the agent. restart: SIGKILL it and start it again `duration` s later (0 when unset).
    freeze: SIGSTOP it for `duration` s. telemetry-loss: the simulated vehicle sends nothing for `duration` s.
    """

    kind: FaultKind
    agent: int = Field(ge=1, le=16)
    at: float = Field(ge=0.0, le=86400.0)
    duration: float | None = Field(None, ge=0.0, le=3600.0)

    @model_validator(mode="before")
    @classmethod
    def _from_text(cls, value: Any) -> Any:
        if not isinstance(value, str):
            return value
        match = _FAULT_RE.match(value.strip())
        if match is None:
            raise ValueError(f"fault {value!r} is not {FAULT_SYNTAX}")
        return {k: v for k, v in match.groupdict().items() if v is not None}

    @model_validator(mode="after")
    def _duration_fits_kind(self) -> FaultSpec:
        if self.kind in ("freeze", "telemetry-loss") and not self.duration:
            raise ValueError(f"a {self.kind} fault needs a duration: {self.kind}:agent={self.agent}@{self.at:g}+D")
        if self.kind == "kill" and self.duration is not None:
            raise ValueError("a kill fault has no duration (restart:agent=K@T+D kills and starts again)")
        return self

    def __str__(self) -> str:
        tail = f"+{self.duration:g}" if self.duration is not None else ""
        return f"{self.kind}:agent={self.agent}@{self.at:g}{tail}"


DEFAULT_MAX_TIME_S = 420.0
# A lone drone needed 909 s to finish the warehouse (6,400 m^3), three drones 299 s: 0.25 s/m^3 per drone leaves
# room for the slower runs and still ends a stuck mission.
MAX_TIME_S_PER_M3_PER_DRONE = 0.25
VIEW_MODES = ("native", "web")  # mission.view: a viewer swarm run starts; or a running viewer's URL
VIEW_URL_SCHEMES = ("rerun+http://", "rerun+https://", "rerun://")


class MissionSettings(_Section):
    """What the swarm is asked to do, and where."""

    name: str = Field("default", description="mission name; every key expression lives under swarm/<name>/")
    drones: int = Field(3, ge=1, le=16)
    world: str = Field(
        "office",
        description="a built-in world name, a generated building gen:SEED[:options] or a path to a .ply/.obj/.stl mesh",
    )
    start: Vec3 | None = Field(None, description="take-off area centre; the world's default when unset")
    spawn_spacing_m: PositiveFloat = 1.5
    volume: Box | None = Field(None, description="mission volume; the world mesh bounds when unset")
    max_time_s: PositiveFloat | None = Field(
        None,
        description=f"the mission stops (drones land) after this long; unset: {DEFAULT_MAX_TIME_S:g} s, or "
        f"{MAX_TIME_S_PER_M3_PER_DRONE:g} s per cubic metre of mission volume per drone when that is longer",
    )
    seed: int = 0
    out: Path | None = Field(None, description="run directory; runs/<timestamp>-<world> when unset")
    origin: GeoOrigin = GeoOrigin()
    network: Literal["loopback", "netns"] = Field(
        "loopback",
        description="loopback: every process on 127.0.0.1; netns: each agent in its own network namespace on a "
        "virtual radio that link-loss scenarios can impair (root, ip and nft needed)",
    )
    links: Path | None = Field(None, description="link scenario TOML (swarm.netem.scenario); needs network = netns")
    faults: list[FaultSpec] = Field(
        default_factory=list, max_length=64, description=f"faults injected during the mission: {FAULT_SYNTAX}"
    )
    tls: bool = Field(
        False,
        description="swarm run: a fresh CA and certificates in OUT/certs; every session on mutual TLS with "
        "access control (a drone publishes only under its own id)",
    )
    # The simulator stands in for each drone's autopilot, which on a real drone runs on its own processor and is
    # never starved by the companion computer's load; the agents stand in for those companion computers. Above
    # the rest of the machine (niceness 0), a burst of other processes does not stall their telemetry.
    record: bool = Field(
        False,
        description="swarm run: each agent records its sensor streams to OUT/bags/agent-K "
        '(needs camera.source = "zenoh")',
    )
    rrd: bool = Field(
        True,
        description="swarm run: the observer and the harness record the run to OUT/run.rrd (Rerun; headless, "
        "open it with swarm view OUT)",
    )
    view: str | None = Field(
        None,
        description='swarm run: stream the recording live to a Rerun viewer while the swarm flies: "native" (a '
        'window; needs a display), "web" (the web viewer at http://127.0.0.1:<view_port>) or the gRPC proxy URL '
        "of a viewer already running (rerun+http://HOST:PORT/proxy)",
    )
    view_port: int = Field(9090, ge=1, le=65535, description='swarm run: the web viewer\'s port (view = "web")')
    view_depth: bool = Field(
        False,
        description="swarm run: the recording also holds each drone's depth image (once a second) under its "
        "camera's pose (OUT/cameras.rrd)",
    )
    sim_nice: int = Field(
        -10,
        ge=-20,
        le=19,
        description="swarm run: the simulator's niceness (below 0 needs root or CAP_SYS_NICE; "
        "when not permitted it runs at the harness's, and the report says so)",
    )
    agent_nice: int = Field(-5, ge=-20, le=19, description="swarm run: each agent's niceness (as sim_nice)")

    def time_limit_s(self, volume_m3: float) -> float:
        """`max_time_s`, or when unset the default for a mission volume of `volume_m3` and these drones."""
        if self.max_time_s is not None:
            return self.max_time_s
        return max(DEFAULT_MAX_TIME_S, MAX_TIME_S_PER_M3_PER_DRONE * volume_m3 / self.drones)

    @field_validator("view")
    @classmethod
    def _view_is_a_mode_or_a_viewer(cls, view: str | None) -> str | None:
        if view is None or view in VIEW_MODES or view.startswith(VIEW_URL_SCHEMES):
            return view
        raise ValueError(f"must be {' or '.join(VIEW_MODES)} or a viewer's rerun+http://HOST:PORT/proxy URL")

    @model_validator(mode="after")
    def _links_need_netns(self) -> MissionSettings:
        if self.links is not None and self.network != "netns":
            raise ValueError('a link scenario (links) needs network = "netns"')
        return self

    @model_validator(mode="after")
    def _faults_name_drones(self) -> MissionSettings:
        for fault in self.faults:
            if fault.agent > self.drones:
                raise ValueError(f"fault {fault} names agent {fault.agent} but the mission has {self.drones} drones")
        return self

    @field_validator("name")
    @classmethod
    def _key_safe(cls, v: str) -> str:
        if not _NAME_RE.match(v):
            raise ValueError("must be 1-64 characters of letters, digits, '_' or '-'")
        return v


class AgentSettings(_Section):
    """One drone's agent process."""

    id: int = Field(1, ge=1, le=250, description="drone id, also its MAVLink system id; lowest id leads")
    autopilot: str = Field(
        f"udpin://0.0.0.0:{DEFAULT_GCS_BASE_PORT}", description="MAVSDK connection URL of the autopilot"
    )
    altitude_m: PositiveFloat = Field(1.5, description="take-off and cruise altitude above home")
    cruise_speed_m_s: PositiveFloat = 1.5
    heartbeat_hz: float = Field(5.0, ge=5.0, le=50.0)
    connect_timeout_s: PositiveFloat = 20.0
    health_timeout_s: PositiveFloat = 20.0
    command_timeout_s: PositiveFloat = 5.0
    telemetry_timeout_s: PositiveFloat = Field(1.5, description="no telemetry for this long: hold, then land")
    peer_timeout_s: PositiveFloat = Field(3.0, description="a peer silent for this long has left")
    waypoint_tolerance_m: PositiveFloat = 0.3
    waypoints: list[Vec3] = Field(default_factory=list, description="scripted route, world frame")
    hover_s: float = Field(0.0, ge=0.0, description="hold at the end of the route before landing")
    start_delay_s: float = Field(0.0, ge=0.0, description="wait on the ground this long once healthy before arming")
    crew_wait_s: float = Field(
        30.0,
        ge=0.0,
        description="when drones keep apart (explore.separation_m), wait on the ground at most this long once "
        "healthy to hear every other drone of the mission (mission.drones) before arming: a drone cannot keep clear "
        "of peers it has not heard; it then takes off with those it has (the log's crew event says which); 0: "
        "do not wait",
    )
    out_dir: Path | None = Field(None, description="where the agent writes its summary and logs")
    state_dir: Path | None = Field(
        None,
        description="the agent keeps its own sealed patches here; started again, it reloads those of its "
        "earlier runs (other epochs) before it asks its peers",
    )
    mavsdk_threads: int = Field(8, ge=2, le=64)
    frame: Literal["global", "local"] = Field(
        "global",
        description="how the world frame is tied to the autopilot's: 'global' through its home position's latitude, "
        "longitude and altitude (GPS, or a global origin set on the vehicle); 'local' (indoors, no GPS) through "
        "agent.local_origin and agent.local_north_deg, the autopilot's local NED frame placed in the world",
    )
    local_origin: Vec3 | None = Field(
        None, description='agent.frame = "local": the world position of the autopilot\'s local (EKF) origin'
    )
    local_north_deg: float = Field(
        0.0,
        ge=-180.0,
        le=180.0,
        description='agent.frame = "local": the world bearing of the local frame\'s north axis, degrees '
        "counter-clockwise from the world's +y",
    )
    battery_home_fraction: float = Field(
        0.25,
        gt=0.0,
        lt=1.0,
        description="below this remaining battery (fraction, from the autopilot's battery telemetry) the agent "
        "ends its mission, flies back above its take-off point and lands; above PX4's BAT_LOW_THR (0.15) so "
        "that the vehicle's own battery failsafe never has to act",
    )
    px4_params: Literal["set", "check", "off"] = Field(
        "check",
        description="the PX4 parameters that decide what the vehicle does when this agent dies or a link is lost "
        "(swarm/agent/px4_params.py), read before take-off: 'check' refuses to take off when an agent death would "
        "make the vehicle climb or return (PX4's defaults do: Return at 60 m); 'set' writes safe indoor values "
        "(Hold) and reads them back; 'off' leaves them alone. swarm run uses 'set' for its simulated vehicles",
    )

    @model_validator(mode="after")
    def _local_frame_placed(self) -> AgentSettings:
        if self.frame == "local" and self.local_origin is None:
            raise ValueError('agent.frame = "local" needs agent.local_origin (the world position of the local origin)')
        return self

    @field_validator("autopilot")
    @classmethod
    def _known_scheme(cls, v: str) -> str:
        schemes = ("udpin://", "udpout://", "tcpin://", "tcpout://", "serial://", "udp://", "tcp://")
        if not v.startswith(schemes):
            raise ValueError(f"'{v}' is not a MAVSDK connection URL (use one of {', '.join(schemes)})")
        return v


class SimSettings(_Section):
    """The simulated autopilots (one process hosts every vehicle)."""

    host: str = "127.0.0.1"
    vehicle_base_port: int = Field(DEFAULT_VEHICLE_BASE_PORT, ge=1024, le=65000)
    gcs_base_port: int = Field(DEFAULT_GCS_BASE_PORT, ge=1024, le=65000)
    physics_hz: float = Field(50.0, ge=10.0, le=500.0)
    telemetry_hz: float = Field(20.0, ge=1.0, le=100.0)
    heartbeat_hz: float = Field(2.0, ge=0.5, le=10.0)
    max_speed_xy_m_s: PositiveFloat = 3.0
    max_speed_up_m_s: PositiveFloat = 1.5
    max_speed_down_m_s: PositiveFloat = 1.0
    max_accel_m_s2: PositiveFloat = 3.0
    # PX4's position and velocity loops, with PX4's defaults (MPC_XY_P, MPC_Z_P, MPC_XY_VEL_P_ACC,
    # MPC_Z_VEL_P_ACC): the horizontal response overshoots a little, the vertical one does not
    position_gain_xy: PositiveFloat = Field(0.95, description="MPC_XY_P: velocity command per m of error, 1/s")
    position_gain_z: PositiveFloat = Field(1.0, description="MPC_Z_P, 1/s")
    velocity_gain_xy: PositiveFloat = Field(1.8, description="MPC_XY_VEL_P_ACC: acceleration per m/s of error, 1/s")
    velocity_gain_z: PositiveFloat = Field(4.0, description="MPC_Z_VEL_P_ACC, 1/s")
    land_speed_m_s: PositiveFloat = 0.7
    takeoff_alt_m: PositiveFloat = Field(1.5, description="MIS_TAKEOFF_ALT default")
    drone_radius_m: PositiveFloat = Field(0.2, description="collision sphere radius")
    offboard_timeout_s: PositiveFloat = Field(1.0, description="no setpoint for this long: hold (as PX4)")
    battery_minutes: PositiveFloat = Field(
        30.0,
        description="a full battery hovers this long (faster flight drains it sooner, swarm/sim/battery.py); "
        "the default leaves ordinary missions (the default 420 s limit; a lone drone's 15 min warehouse) well "
        "above agent.battery_home_fraction",
    )
    battery_start: float = Field(1.0, ge=0.0, le=1.0, description="each vehicle's battery at start (fraction)")
    battery_starts: dict[int, Annotated[float, Field(ge=0.0, le=1.0)]] = Field(
        default_factory=dict, description="vehicle id -> its battery at start, for those not at sim.battery_start"
    )
    gps: bool = Field(
        True,
        description="False: indoor vehicles without GPS (EKF2_GPS_CTRL 0 at boot, local position from vision): "
        "no global position, no HOME_POSITION, no Hold or Return mode until a SET_GPS_GLOBAL_ORIGIN; swarm run "
        'then gives each agent agent.frame = "local" and its vehicle\'s local origin',
    )
    estimator_warmup_s: float = Field(
        0.0, ge=0.0, le=120.0, description="after boot, how long each vehicle has no position estimate (not armable)"
    )
    local_origin_offset: Vec3 = Field(
        (0.0, 0.0, 0.0),
        description="where each vehicle's local (EKF) origin lies from its spawn point, world frame: PX4's origin is "
        "where its estimator started (a vision system's start), not its home",
    )
    spawns: list[Vec3] = Field(default_factory=list, description="vehicle home positions; set by swarm run")
    sensor_listen: list[str] = Field(
        default_factory=list,
        description="when set, the simulator publishes each vehicle's odometry (ROS 2, in "
        "camera.stream's layout, under /drone<k>) on a Zenoh router listening here, for `swarm cameras` and the "
        'agents with camera.source = "zenoh"',
    )
    odometry_hz: float = Field(50.0, ge=5.0, le=500.0, description="odometry rate (sensor_listen)")
    status_path: Path | None = Field(None, description="where the simulator writes its status JSON")
    control_path: Path | None = Field(
        None, description='fault injection: a JSON file the simulator polls, {"telemetry_off": [drone ids]}'
    )


TLS_OBSERVER_NAME = "observer"


def tls_drone_name(agent_id: int) -> str:
    """The certificate name (TLS common name) of drone `agent_id`: what access control keys on."""
    return f"drone-{agent_id}"


class ReceiveLimits(_Section):
    """Received messages per key expression, counted and dropped before any decoding past these (a flood, or a
    member whose messages are costly to decode). Each key has a token bucket of messages and one of decode CPU
    time; the subscription as a whole has the same, `total_keys` times larger, for floods spread over many keys.
    Legitimate rates, far below: heartbeats at most 50 Hz (`agent.heartbeat_hz` <= 50, extra ones >= 50 ms
    apart); patch chunks in bursts of at most 512 (a patch of `mapping.max_patch_bytes`, 4 MiB, in 8 kB chunks)
    about every 1.5 s; frontier reports and assignments about once per `explore.loop_s`. Decoding a heartbeat
    costs 0.03 ms (7 ms with holdings at every bound), a chunk 0.02 ms."""

    per_key_hz: dict[str, PositiveFloat] = Field(
        default_factory=lambda: {"state": 200.0, "patch_chunk": 2000.0},
        description="messages a second per key, by message kind; burst: one second's worth",
    )
    default_hz: PositiveFloat = Field(50.0, description="messages a second per key of any other kind")
    decode_cpu: float = Field(
        0.1, gt=0.0, le=1.0, description="CPU a key's messages may take to decode, as a fraction of a core"
    )
    total_keys: int = Field(32, ge=1, le=1024, description="the subscription's buckets are this many keys' worth")
    max_keys: int = Field(1024, ge=1, le=1 << 16, description="keys with a bucket of their own; the rest share one")

    def hz(self, kind: str) -> float:
        return self.per_key_hz.get(kind, self.default_hz)


class BusSettings(_Section):
    """The Zenoh session of a swarm process."""

    mode: Literal["peer", "router"] = Field(
        "router", description="router: sessions forward between drones that cannot reach each other (multi-hop)"
    )
    listen: list[str] = Field(default_factory=list, description="Zenoh listen endpoints, e.g. tcp/127.0.0.1:7451")
    connect: list[str] = Field(default_factory=list, description="Zenoh endpoints to connect to")
    multicast_scouting: bool = False
    lease_ms: int = Field(1000, ge=200, le=60000, description="lost-peer detection time")
    keep_alive: int = Field(4, ge=1, le=20)
    data_queue_batches: int = Field(
        16,
        ge=1,
        le=16,
        description="Zenoh's transmit queue for data (patch chunks, pull replies), in 64 kB batches per link: a "
        "burst beyond it is dropped after 1 ms (Zenoh's default, 2, dropped a healed partition's pull replies)",
    )
    shared_memory: bool = False
    base_port: int = Field(DEFAULT_BUS_BASE_PORT, ge=1024, le=65000, description="loopback ports for swarm run")
    tls_dir: Path | None = Field(
        None,
        description="mutual TLS and access control: the directory `swarm deploy certs` wrote (ca.pem and "
        "this process's certificate); every endpoint must then be tls/",
    )
    tls_name: str | None = Field(
        None,
        pattern=r"^(drone-[1-9][0-9]{0,2}|observer)$",
        description="which certificate in tls_dir: drone-<id> (an agent's default) or observer",
    )
    receive: ReceiveLimits = Field(default_factory=ReceiveLimits)

    @model_validator(mode="after")
    def _tls_endpoints_only(self) -> BusSettings:
        if self.tls_dir is not None:
            plain = [e for e in self.listen + self.connect if not e.startswith("tls/")]
            if plain:
                raise ValueError(f"with tls_dir set every endpoint must be tls/..., not {plain[0]}")
        return self


_ROS_NAME = r"^/?[A-Za-z_~][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*$"


class CameraMount(_Section):
    """Where the camera sits on the vehicle: its link in the body frame (FLU), URDF-style (docs: "Mapping")."""

    translation_m: Vec3 = Field((0.0, 0.0, 0.0), description="camera link origin in the body frame, metres")
    rpy_deg: Vec3 = Field((0.0, 0.0, 0.0), description="roll, pitch (positive looks down), yaw of the link, deg")


class SensorStreamSettings(_Section):
    """Where a camera on ROS 2 publishes, as seen through Zenoh (camera.source = "zenoh")."""

    layout: Literal["rmw_zenoh", "bridge"] = Field(
        "rmw_zenoh",
        description="rmw_zenoh: keys <domain>/<topic>/<type>/<hash> (hash matched by *); bridge: "
        "zenoh-bridge-ros2dds, keys [<namespace>/]<topic>",
    )
    domain_id: int = Field(0, ge=0, le=232, description="ROS_DOMAIN_ID (rmw_zenoh layout)")
    namespace: str = Field("", pattern=r"^([A-Za-z0-9_]+(/[A-Za-z0-9_]+)*)?$", description="bridge key prefix")
    depth_topic: str = Field("/camera/depth/image_rect_raw", pattern=_ROS_NAME, description="sensor_msgs/Image")
    info_topic: str = Field("/camera/depth/camera_info", pattern=_ROS_NAME, description="sensor_msgs/CameraInfo")
    pose_topic: str = Field("/odom", pattern=_ROS_NAME, description="the vehicle's pose in the world frame (ENU)")
    pose_type: Literal["odometry", "pose_stamped"] = Field(
        "odometry", description="nav_msgs/Odometry or geometry_msgs/PoseStamped"
    )
    mode: Literal["peer", "client"] = Field(
        "client",
        description="the sensor session's Zenoh mode: client, through the router it connects to (rmw_zenohd "
        "or the simulator's); peer, straight to the endpoints (a peer behind a router with no listen endpoint of "
        "its own heard nothing from the other peers in a test here)",
    )
    connect: list[str] = Field(
        default_factory=lambda: ["tcp/127.0.0.1:7447"],
        description="Zenoh endpoints of the camera's side (rmw_zenohd listens on 7447)",
    )
    listen: list[str] = Field(default_factory=list, description="Zenoh endpoints this session listens on")
    connect_timeout_s: float = Field(
        10.0,
        ge=0.0,
        le=600.0,
        description="how long the sensor session keeps trying its connect endpoints before the agent gives up "
        "(a robot's Zenoh router may come up after the agent); 0: one try",
    )
    max_gap_s: PositiveFloat = Field(0.25, description="an image between poses further apart is dropped")
    max_hold_s: float = Field(
        0.05,
        ge=0.0,
        le=1.0,
        description="an image this much newer than the newest pose takes that pose; newer ones wait for the next",
    )
    max_pose_wait_s: float = Field(
        1.0,
        gt=0.0,
        le=10.0,
        description="an image waits for the pose after its stamp until an image this much newer arrives, then is "
        "dropped ('no pose in time')",
    )

    def under_vehicle(self, vehicle_id: int) -> SensorStreamSettings:
        """These settings with every topic under /drone<k>: the simulator's layout, one camera and one odometry
        per vehicle (what camera.source = "sim" hears)."""
        return self.model_copy(
            update={
                name: f"/drone{vehicle_id}/{getattr(self, name).lstrip('/')}"
                for name in ("depth_topic", "info_topic", "pose_topic")
            }
        )


class CameraSettings(_Section):
    """The depth camera (simulated by ray casting the world mesh, or a real one behind the same interface)."""

    source: Literal["sim", "zenoh", "ros2", "replay", "none"] = Field(
        "sim",
        description="sim: the simulator's cameras (`swarm cameras`, which `swarm run` starts), heard as "
        "zenoh does with camera.stream's topics under /drone<agent.id>; zenoh: a camera on ROS 2 heard through "
        "Zenoh (camera.stream); ros2: the same topics through rclpy (pip install 'swarm[ros2]'); replay: "
        "camera.replay_bag played back at its pace; an agent never loads a world, so all of these need "
        "mission.volume (`swarm sim` prints its world's); none: no mapping",
    )
    width: int = Field(160, ge=8, le=1280)
    height: int = Field(120, ge=6, le=960)
    hfov_deg: float = Field(90.0, gt=10.0, lt=170.0)
    min_range_m: PositiveFloat = 0.3
    max_range_m: PositiveFloat = 8.0
    rate_hz: float = Field(10.0, gt=0.0, le=60.0)
    noise: Literal["off", "stereo"] = "off"
    stereo_sigma_coeff: PositiveFloat = Field(0.002418, description="sigma(z) = coeff * z^2, metres")
    pitch_deg: float = Field(0.0, ge=-90.0, le=90.0, description="camera pitch, positive looks down")
    mount: CameraMount = CameraMount()
    record: Path | None = Field(
        None,
        description='camera.source = "zenoh": record every sensor message received '
        "to this ROS 2 MCAP bag (a directory that must not exist)",
    )
    replay_bag: Path | None = Field(
        None,
        description='camera.source = "replay": the bag played back as the '
        "camera (ROS 2 directory or ROS 1 .bag; topics picked by type)",
    )
    peer_mask_m: float = Field(
        0.5,
        ge=0.0,
        le=3.0,
        description="streamed frames: pixels whose rays meet a sphere of this radius round a "
        "peer's reported position (half a body height up) are not mapped, so drones leave no phantom obstacles; 0: off",
    )
    stream: SensorStreamSettings = SensorStreamSettings()

    @model_validator(mode="after")
    def _ranges(self) -> CameraSettings:
        if self.min_range_m >= self.max_range_m:
            raise ValueError(f"min_range_m {self.min_range_m} must be below max_range_m {self.max_range_m}")
        return self


WeightLaw = Literal["constant", "inverse_square", "dropoff"]


class MappingSettings(_Section):
    """The shared TSDF lattice (mission constants: every patch carries them) and patch sealing."""

    voxel_size_m: float = Field(0.1, ge=0.02, le=1.0)
    block_resolution: int = Field(8, ge=4, le=32, description="voxels per block edge")
    truncation_voxels: float = Field(4.0, ge=1.0, le=16.0)
    weight_law: WeightLaw = Field(
        "dropoff",
        description="how much one observation weighs: dropoff (1, falling linearly to 0 from one voxel behind the "
        "surface to the truncation distance, as in voxblox: guesses behind a surface no longer close doors), "
        "constant (1), inverse_square (1 / z^2)",
    )
    known_weight: PositiveFloat = Field(1.0, description="a voxel is known once its summed weight reaches this")
    patch_frames: int = Field(15, ge=1, le=255, description="seal the open patch every K frames")
    patch_distance_m: PositiveFloat = Field(2.0, description="... or after the drone moved this far")
    patch_stretch: int = Field(
        3,
        ge=1,
        le=16,
        description="an open patch that has little new to say (under novel_block_fraction of its blocks absent "
        "from the map) at those triggers goes on until this many times them: fewer, larger patches where a drone "
        "looks again at what it has mapped (1: seal at the triggers always)",
    )
    novel_block_fraction: float = Field(
        0.2, ge=0.0, le=1.0, description="share of an open patch's blocks new to the map that makes it worth sealing"
    )
    patch_changes_only: bool = Field(
        True,
        description="a sealed patch keeps only the voxels that change this drone's map: new ones, ones not yet known, "
        "and ones whose fusion moves them across the surface (swarm.patches.sealer); false: every observed voxel",
    )
    planning_resolution_m: PositiveFloat = Field(0.2, description="occupancy grid exported for planning")
    max_patch_bytes: int = Field(4 << 20, ge=1024, description="larger patches are rejected on receipt")
    max_patch_blocks: int | None = Field(
        None,
        ge=1,
        description="patches with more blocks are rejected on receipt, and the open patch is sealed at half this; "
        "unset: twice what one frame of this agent's camera (camera.width, height, hfov_deg, max_range_m) can touch "
        "(swarm.patches.sealer.patch_block_limit); set it for the whole mission when the drones' cameras differ",
    )


class SyncSettings(_Section):
    """Map sharing between agents (`swarm.sync`): push on seal in chunks, digests in heartbeats, pull from the
    nearest holder. Defaults follow Hardouin's proposal (PhD thesis, UPJV, 2022), shortened for indoor speeds."""

    chunk_bytes: int = Field(
        8192, ge=512, le=1 << 20, description="patches travel in chunks of at most this many payload bytes"
    )
    period_s: PositiveFloat = Field(0.25, description="how often missing patches are looked for and requested")
    grace_s: float = Field(
        1.0, ge=0.0, le=60.0, description="a patch first advertised this recently is left to its push"
    )
    request_timeout_s: PositiveFloat = Field(3.0, description="a pull request not fully answered by then fails")
    max_in_flight: int = Field(4, ge=1, le=64, description="pull requests in flight at once")
    batch_size: int = Field(4, ge=1, le=64, description="patch ids per pull request")
    backoff_initial_s: PositiveFloat = Field(0.5, description="first back-off from a holder that failed")
    backoff_max_s: PositiveFloat = Field(8.0, description="back-off cap (doubles on each failure)")
    assembly_timeout_s: PositiveFloat = Field(30.0, description="a patch still incomplete after this is dropped")
    max_assembly_bytes: int = Field(64 << 20, ge=1 << 20, description="bytes of incomplete patches kept at most")
    max_missing_tracked: int = Field(
        4096,
        ge=1,
        le=1 << 20,
        description="missing patch ids tracked at most (the oldest first): bounds the memory a peer's digest can claim",
    )
    linger_max_s: float = Field(
        60.0,
        ge=0.0,
        le=3600.0,
        description="after landing, stay on the bus until every peer has finished and holds what we hold, or this long",
    )
    linger_wait_departed_s: float = Field(
        20.0,
        ge=0.0,
        le=600.0,
        description="while lingering, a peer that left before it was in step is waited for this long (a lossy "
        "link's lease expiry is often a flap)",
    )
    push_drop_fraction: float = Field(
        0.0, ge=0.0, le=1.0, description="experiments only: drop this fraction of outgoing push chunks on purpose"
    )
    # Serving the store. A requester names itself (`from=`), so these hold per name and for all together.
    # Legitimate: a requester asks at most max_in_flight requests of batch_size patches per period_s (16 a
    # second by default), of patches of typically 10-300 kB.
    serve_requests_hz: PositiveFloat = Field(40.0, description="store queries a second per requester; burst: 1 s")
    serve_bytes_per_s: int = Field(
        8 << 20, ge=1 << 16, description="reply bytes a second per requester; burst: one second's worth"
    )
    serve_total_factor: float = Field(
        3.0, ge=1.0, le=256.0, description="all requesters together get this many requesters' worth"
    )
    signing_dir: Path | None = Field(
        None,
        description="patch signing (swarm.patches.signing): a directory with the authority's ca.pem and this "
        "drone's drone-<id>.sign.pem/.sign.key; every received patch must then be signed by its producer. "
        "Unset: bus.tls_dir when TLS is on, else no signing (any member can forge any patch)",
    )

    @model_validator(mode="after")
    def _backoff(self) -> SyncSettings:
        if self.backoff_max_s < self.backoff_initial_s:
            raise ValueError(f"backoff_max_s {self.backoff_max_s} must be at least backoff_initial_s")
        return self


Strategy = Literal["coordinated", "uncoordinated", "frontier-only", "scripted"]


class ExploreSettings(_Section):
    """Autonomous exploration (`swarm.explore`, `swarm.roles`): frontiers, goal assignment, planning.

    Mahdoui's rules (PhD thesis, UTC Compiègne, 2018) adapted to 3D and to drones ten times faster than the thesis's:
    the loop period r and the explorer timeout tau are scaled from the cruise speed and the camera range."""

    strategy: Strategy = Field(
        "coordinated",
        description="coordinated: the cluster leader assigns targets; uncoordinated: each drone picks its own best "
        "frontier (maps still shared); frontier-only: frontiers and targets are exchanged, patches are not; "
        "scripted: the harness's ground-truth routes (no exploration)",
    )
    assignment: Literal["utility", "tours", "tail-tours"] = Field(
        "utility",
        description="how a coordinated leader hands out candidates: utility, each member's best gain against "
        "distance (Mahdoui's rule, swarm.roles.assignment); tours, the candidates divided between members by "
        "position and each member sent to the first of its own tour (swarm.roles.tours); tail-tours, utility "
        "until no candidate is worth tail_gain_m3, tours from then on",
    )
    tail_gain_m3: float = Field(
        20.0,
        ge=0.0,
        description="with assignment = tail-tours, a round whose best candidate would see less unknown than this "
        "is the mission's tail: leftovers, handed out by tours",
    )
    loop_s: PositiveFloat = Field(3.0, description="r: assignment period (also runs when a drone reaches its target)")
    view_reuse_s: float = Field(
        1.0,
        ge=0.0,
        description="a decision within this long of the last map view (frontiers, planning grid) decides on it "
        "instead of computing a new one: a leader is woken by every member's arrival, and recomputing the view "
        "each time made it the slowest drone (hall, 5 drones: 105 views against 50-57); 0: always a new view",
    )
    explorer_timeout_s: PositiveFloat = Field(
        6.0, description="tau: an explorer with no target from its leader for this long picks its own"
    )
    utility_lambda: float = Field(0.2, ge=0.0, le=1.0, description="lambda of U = I exp(-lambda (d_i + (n_c-1)/d_tot))")
    sigma_m: PositiveFloat = Field(
        6.0,
        description="gain scheduling: gains near an assigned target drop (Eq. 3.5); Mahdoui's 3 m with a 4 m "
        "sensor, scaled to the 8 m camera (two viewpoints closer than its range see much of the same space)",
    )
    current_target_bonus: float = Field(
        3.0,
        ge=1.0,
        le=10.0,
        description="utility factor for a drone's current target (fewer U-turns between loops: "
        "with view gains, 1.5 let a drone be sent 12-17 m one way and back between two loops)",
    )
    clearance_m: PositiveFloat = Field(
        0.25,
        description="planned paths keep this far from mapped obstacle cells (drone radius + 5 cm: at 0.2 m a "
        "drone touched a wall end; at 0.35 m the 0.2 m grid cut 1.1 m doorways off)",
    )
    roomy_clearance_m: float = Field(
        0.45,
        ge=0.0,
        le=2.0,
        description="paths keep this far from mapped obstacles where the space allows, and "
        "come down to clearance_m only in narrow passages (at the minimum alone, a drone passed every wall end "
        "0.05 m from contact); at most clearance_m: off",
    )
    body_height_m: float = Field(
        0.45,
        ge=0.0,
        le=2.0,
        description="the airframe reaches this far above the position it reports; planned "
        "positions need clearance_m up to there (the simulator's drone: its sphere's top is 0.42 m up)",
    )
    min_altitude_m: PositiveFloat = Field(0.6, description="lowest flight height above the mission volume's floor")
    ceiling_margin_m: PositiveFloat = Field(0.3, description="highest flight: this far below the mission volume's top")
    gain_model: Literal["view", "box"] = Field(
        "view",
        description="what a candidate is worth: view, the unknown volume its viewpoint's camera would see "
        "(ray cast); box, the unknown volume in the gain_radius_m cube around its point (Mahdoui's window)",
    )
    gain_radius_m: PositiveFloat = Field(
        1.0,
        description="box gain: unknown cells within this half-width cube around a frontier point (also the "
        "min_gain_m3 test under either model)",
    )
    min_gain_m3: float = Field(
        0.8, ge=0.0, description="frontier clusters with less unknown volume around them than this are ignored"
    )
    min_view_gain_m3: float = Field(
        2.0,
        ge=0.0,
        description="view gain: a viewpoint that would see less unknown than this is not worth a trip "
        "(what such views leave unseen are floor corners and slivers; chasing them across the building was most of "
        "a mission's tail: office, 3 drones, 95 % at 63 s, the last targets of 0.5-2 m3 until 103 s)",
    )
    seen_fraction: float = Field(
        0.5,
        gt=0.0,
        le=1.0,
        description="a planning cell with no obstacle counts as seen free when this share of its voxels is known",
    )
    min_unknown_m3: float = Field(
        0.2, ge=0.0, description="unknown pockets smaller than this (specks inside known space) are not worth a trip"
    )
    cluster_size_m: PositiveFloat = Field(1.2, description="frontier cells are grouped into candidates this large")
    reach_m: PositiveFloat = Field(
        1.2, description="a frontier counts when a safe reachable viewpoint lies within this distance of it"
    )
    visited_radius_m: PositiveFloat = Field(
        0.8, description="a candidate this close to a viewpoint already visited is exhausted"
    )
    arrive_tolerance_m: PositiveFloat = Field(0.4, description="a target is reached within this distance")
    dwell_s: float = Field(0.8, ge=0.0, le=30.0, description="at a target, face the frontier this long")
    separation_m: PositiveFloat = Field(1.2, description="drones keep this far apart (heartbeat poses)")
    own_frontier_bonus: float = Field(
        1.0, ge=1.0, le=10.0, description="utility factor for a drone's own frontier points (Mahdoui 3.7; 1 = none)"
    )
    return_home: bool = Field(True, description="when the mission is done, fly back above the take-off point")
    idle_home_s: float = Field(
        6.0,
        ge=0.0,
        le=600.0,
        description="with return_home, a drone left without a target this long, through two decisions for it, "
        "heads home while the others finish (a new target stops it), so that it lands soon after its cluster is "
        "done (at once when a decision found nothing for it; after five times this when no decision comes)",
    )


class SwarmConfig(_Section):
    mission: MissionSettings = MissionSettings()
    agent: AgentSettings = AgentSettings()
    sim: SimSettings = SimSettings()
    bus: BusSettings = BusSettings()
    camera: CameraSettings = CameraSettings()
    mapping: MappingSettings = MappingSettings()
    sync: SyncSettings = SyncSettings()
    explore: ExploreSettings = ExploreSettings()

    def agent_bus(self) -> BusSettings:
        """The bus settings of drone `agent.id`: with TLS on and no certificate named, its own (drone-<id>)."""
        if self.bus.tls_dir is not None and self.bus.tls_name is None:
            return self.bus.model_copy(update={"tls_name": tls_drone_name(self.agent.id)})
        return self.bus

    def signing_dir(self) -> Path | None:
        """Where this process's patch signing material is: sync.signing_dir, else the TLS directory, else none."""
        return self.sync.signing_dir if self.sync.signing_dir is not None else self.bus.tls_dir

    @model_validator(mode="after")
    def _explorers_see(self) -> SwarmConfig:
        if self.explore.strategy != "scripted" and self.camera.source == "none":
            raise ValueError(
                f"explore.strategy '{self.explore.strategy}' needs a camera (camera.source = \"sim\"); "
                'without one only explore.strategy = "scripted" flies'
            )
        return self


def parse_override(text: str) -> tuple[str, Any]:
    """Parse one `section.field=value` override; the value is read as TOML, else taken as a string."""
    key, sep, raw = text.partition("=")
    key = key.strip()
    if not sep or not key or not all(key.split(".")):
        raise ConfigError(f"override '{text}' is not of the form section.field=value")
    try:
        value = tomllib.loads(f"v = {raw.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw.strip()
    return key, value


def _apply(tree: dict[str, Any], dotted: str, value: Any) -> None:
    *parents, leaf = dotted.split(".")
    node = tree
    for part in parents:
        child = node.setdefault(part, {})
        if not isinstance(child, dict):
            raise ConfigError(f"override '{dotted}': '{part}' is not a section")
        node = child
    node[leaf] = value


def read_toml(path: str | Path, what: str = "config file") -> dict[str, Any]:
    """The TOML file's tables; ConfigError (one line naming `what` and the path) if it cannot be read."""
    try:
        return tomllib.loads(Path(path).read_text())
    except FileNotFoundError:
        raise ConfigError(f"{what} {path} does not exist") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{what} {path} cannot be read: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{what} {path} is not valid TOML: {exc}") from None


def load_config(path: Path | None = None, overrides: dict[str, Any] | None = None) -> SwarmConfig:
    """Load a configuration from an optional TOML file plus dotted overrides; raise ConfigError on bad input."""
    tree: dict[str, Any] = read_toml(path) if path is not None else {}
    for key, value in (overrides or {}).items():
        _apply(tree, key, value)
    try:
        return SwarmConfig.model_validate(tree)
    except ValidationError as exc:
        raise ConfigError(validation_problem(exc, unknown="unknown setting", nowhere="config")) from None


def dump_config(config: SwarmConfig) -> dict[str, Any]:
    """A TOML-ready dict of the configuration (None values left out, paths as strings)."""
    return config.model_dump(mode="json", exclude_none=True)


def gcs_port(sim: SimSettings, drone_id: int) -> int:
    """Where vehicle `drone_id` sends MAVLink before anyone talks to it (the port layout above)."""
    return sim.gcs_base_port + min(drone_id, SITL_GCS_PORTS) - 1


def gcs_port_shared(drone_id: int) -> bool:
    """Whether vehicle `drone_id`'s GCS port is shared with other vehicles: its agent must dial the vehicle."""
    return drone_id >= SITL_GCS_PORTS


def sim_autopilot_url(sim: SimSettings, drone_id: int) -> str:
    """How drone `drone_id`'s agent reaches its simulated vehicle on sim.host: listening on its own GCS port, or
    for the vehicles that share one, dialling the vehicle's port."""
    if gcs_port_shared(drone_id):
        return f"udpout://{sim.host}:{vehicle_port(sim, drone_id)}"
    return f"udpin://{sim.host}:{gcs_port(sim, drone_id)}"


def vehicle_port(sim: SimSettings, drone_id: int) -> int:
    return sim.vehicle_base_port + drone_id - 1


def bus_port(bus: BusSettings, drone_id: int) -> int:
    """Loopback Zenoh port of a drone's agent in `swarm run`; id 0 is the observer."""
    return bus.base_port + drone_id
