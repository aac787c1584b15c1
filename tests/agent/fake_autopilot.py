"""An autopilot for unit tests of `Flight`: answers at once, and the drone is wherever its setpoint puts it."""

from __future__ import annotations

import time
from collections.abc import Callable

from swarm.agent.autopilot import FlightError, TelemetryCache
from swarm.config import Vec3


class FakeAutopilot:
    """What `Flight` uses of an autopilot, answering at once: a drone on the ground (or, `in_air`, hovering)."""

    def __init__(self, *, in_air: bool = False, refuse: frozenset[str] = frozenset(), climbs: bool = True) -> None:
        self.telemetry = TelemetryCache(
            position=(0.0, 0.0, 1.5 if in_air else 0.0),
            flight_mode="HOLD",
            armed=in_air,
            landed_state="IN_AIR" if in_air else "ON_GROUND",
            updated=time.monotonic(),
            samples=1,
            battery=1.0,
            battery_min=1.0,
        )
        self.home_world = None
        self.refuse = refuse
        self.climbs = climbs
        self.silent = False
        self.commands: list[str] = []
        self.taken_over_mode: str | None = None
        self.visited: list[Vec3] = []  # every setpoint, in order
        self.on_command: dict[str, Callable[[], None]] = {}
        self.on_status_text: Callable[[str, str], None] | None = None
        # the failsafe parameters, holding on an agent's death (PX4's defaults would Return: agent.px4_params)
        self.params: dict[str, float] = {
            "COM_OBL_RC_ACT": 5,
            "NAV_RCL_ACT": 1,
            "NAV_DLL_ACT": 0,
            "COM_RCL_EXCEPT": 0,
            "COM_RC_IN_MODE": 3,
            "COM_LOW_BAT_ACT": 0,
            "RTL_RETURN_ALT": 60.0,
            "COM_OF_LOSS_T": 1.0,
        }

    def taken_over_by(self) -> str | None:
        """The mode someone else switched to (`take_over`), once; None while the agent has the vehicle."""
        mode, self.taken_over_mode = self.taken_over_mode, None
        return mode

    def take_over(self, mode: str) -> None:
        """As a pilot's mode switch: the vehicle now flies `mode` (LAND comes down, disarmed, at once)."""
        self.taken_over_mode = mode
        self.telemetry.flight_mode = mode
        if mode == "LAND":
            self.telemetry.landed_state, self.telemetry.armed = "ON_GROUND", False

    def _command(self, name: str) -> None:
        self.commands.append(name)
        if name in self.refuse:
            raise FlightError(f"{name} refused")
        self.on_command.get(name, lambda: None)()

    def go_silent(self) -> None:
        self.silent = True
        self.telemetry.updated = time.monotonic() - 10.0

    @property
    def telemetry_age_s(self) -> float:
        return time.monotonic() - self.telemetry.updated if self.silent else 0.0

    @property
    def height_above_home(self) -> float:
        return self.telemetry.position[2]

    async def connect(self, timeout_s: float) -> None:
        self._command("connect")

    async def wait_healthy(self, timeout_s: float) -> None:
        self._command("wait_healthy")

    async def read_params(self, ints: tuple[str, ...], floats: tuple[str, ...]) -> dict[str, float]:
        self._command("read_params")
        return {name: self.params[name] for name in (*ints, *floats)}

    async def set_param_int(self, name: str, value: int) -> None:
        self._command("set_param_int")
        self.params[name] = value

    async def arm_and_takeoff(self, altitude_m: float) -> None:
        self._command("arm_and_takeoff")
        self.telemetry.armed, self.telemetry.landed_state = True, "IN_AIR"
        if self.climbs:
            self.telemetry.position = (0.0, 0.0, altitude_m)

    async def set_setpoint(self, target_world: Vec3, yaw_enu_deg: float) -> None:
        self._command("set_setpoint")
        self.telemetry.position = target_world  # it is there at once
        self.visited.append(target_world)

    async def hold(self, timeout_s: float | None = None) -> None:
        self._command("hold")

    async def land(self, timeout_s: float | None = None) -> None:
        self._command("land")
        self.telemetry.position = (0.0, 0.0, 0.0)
        self.telemetry.flight_mode, self.telemetry.armed, self.telemetry.landed_state = "LAND", False, "ON_GROUND"
