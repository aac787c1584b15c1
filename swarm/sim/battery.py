"""The simulated vehicle's battery: a remaining fraction that drains while the motors run.

Model: while armed the battery delivers a hover draw, 1 / (60 * sim.battery_minutes) of its charge per second
(a full battery hovers for `sim.battery_minutes`), times 1 + SPEED_DRAW * v^2 for a speed of v m/s (the extra
power of fast flight; at the 1.5 m/s cruise 11 % more, at the 3 m/s speed limit 45 %). Disarmed it draws
nothing. There is no recharge: a vehicle's battery lasts the simulator's run. The voltage is a 4S LiPo's with
PX4's default cell voltages (BAT1_V_EMPTY 3.6 V, BAT1_V_CHARGED 4.05 V), linear in the remaining fraction.
"""

from __future__ import annotations

SPEED_DRAW = 0.05  # extra draw per (m/s)^2, as a fraction of the hover draw
CELLS = 4
CELL_EMPTY_V, CELL_FULL_V = 3.6, 4.05  # PX4's BAT1_V_EMPTY and BAT1_V_CHARGED defaults (src/lib/battery/module.yaml)


class Battery:
    def __init__(self, minutes: float, start: float = 1.0) -> None:
        self.hover_per_s = 1.0 / (60.0 * minutes)
        self.remaining = min(max(start, 0.0), 1.0)

    def drain(self, dt: float, speed: float, armed: bool) -> None:
        """`dt` seconds at `speed` m/s, motors running when `armed`."""
        if armed:
            self.remaining = max(0.0, self.remaining - self.hover_per_s * (1.0 + SPEED_DRAW * speed * speed) * dt)

    @property
    def voltage_v(self) -> float:
        return CELLS * (CELL_EMPTY_V + (CELL_FULL_V - CELL_EMPTY_V) * self.remaining)
