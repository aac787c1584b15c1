"""The simulator's files: its status (`sim.json`, written every loop, the mission's ground truth) and the
control file `swarm run` writes to inject faults (`SimControl`)."""

from __future__ import annotations

from swarm.files import FileModel


class VehicleStatus(FileModel):
    id: int
    vehicle_port: int
    gcs_port: int
    home: list[float]
    position: list[float]
    velocity: list[float]
    armed: bool
    mode: str  # FlightMode name
    landed_state: str  # "on_ground", "in_air", "taking_off", "landing"...
    distance_m: float
    battery: float  # remaining fraction, 0..1 (swarm/sim/battery.py)
    global_position: bool  # False without GPS until a global origin is set
    local_origin: list[float]  # the world point of the vehicle's local (EKF) origin
    collisions: int
    closest_world_m: float | None  # None until the vehicle came within NEAR_GAP_M of the world in flight
    closest_world_at: list[float] | None
    closest_drone_m: float | None
    gcs_seen: bool
    last_gcs_message_age_s: float | None

    @property
    def landed_and_disarmed(self) -> bool:
        return self.landed_state == "on_ground" and not self.armed


class CollisionRecord(FileModel):
    t: float
    kind: str  # "world" or "drone"
    vehicles: list[int]
    position: list[float]


class Stall(FileModel):
    """A simulator loop iteration that ran `s` seconds late, at simulated time `t`."""

    t: float
    s: float


class SimStatus(FileModel):
    ready: bool
    done: bool
    t: float
    world: str
    collisions: int
    collision_events: list[CollisionRecord]
    stalls: list[Stall]
    vehicles: list[VehicleStatus]


class SimControl(FileModel):
    """Faults `swarm run` injects into a running simulator: the vehicles whose telemetry is cut."""

    telemetry_off: list[int]
