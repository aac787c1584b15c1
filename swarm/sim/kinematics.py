"""Point-mass kinematics of a multicopter: PX4's cascade of a position loop and a velocity loop, with speed and
acceleration limits.

The position loop makes a velocity command (gain * position error, plus any velocity feed-forward), the velocity
loop an acceleration (gain * velocity error), as PX4's PositionControl does with MPC_XY_P / MPC_Z_P and
MPC_XY_VEL_P_ACC / MPC_Z_VEL_P_ACC (src/modules/mc_pos_control/PositionControl). Two proportional loops make a
second-order response: with PX4's defaults the horizontal one is underdamped (damping 0.5 * sqrt(1.8 / 0.95) =
0.69), so a position step overshoots by a few centimetres per metre, and the vertical one is critically damped
(0.5 * sqrt(4.0 / 1.0) = 1.0), so a vehicle never overshoots its altitude. PX4's velocity integrator and
derivative terms are left out. The acceleration is capped by MPC_ACC_HOR in every direction (PX4 caps it by the
tilt limit MPC_TILTMAX_AIR in offboard, which allows more: the cap here is the kinder one for the tests' walls).

World frame (x east, y north, z up). Yaw is kept in NED convention (radians, 0 = north, clockwise), as MAVLink
carries it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

GRAVITY = 9.81


@dataclass
class Limits:
    max_xy: float  # m/s, horizontal speed
    max_up: float  # m/s
    max_down: float  # m/s
    max_accel: float  # m/s^2, norm of the acceleration
    gain_xy: float  # 1/s, horizontal velocity command per metre of position error (MPC_XY_P)
    gain_z: float  # 1/s, vertical (MPC_Z_P)
    velocity_gain_xy: float  # 1/s, horizontal acceleration per m/s of velocity error (MPC_XY_VEL_P_ACC)
    velocity_gain_z: float  # 1/s, vertical (MPC_Z_VEL_P_ACC)
    max_yaw_rate: float = math.radians(90.0)  # rad/s


@dataclass
class Body:
    position: np.ndarray  # world frame, m
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    acceleration: np.ndarray = field(default_factory=lambda: np.zeros(3))
    yaw: float = 0.0  # NED, rad
    yaw_rate: float = 0.0  # rad/s


def velocity_command(
    position: np.ndarray, target_position: np.ndarray, target_velocity: np.ndarray, limits: Limits
) -> np.ndarray:
    """gain * position error on axes with a position target, plus the velocity target (or feed-forward),
    limited to the horizontal and vertical speed limits. NaN axes of a target are not controlled."""
    cmd = np.array([limits.gain_xy, limits.gain_xy, limits.gain_z]) * (target_position - position)
    cmd[np.isnan(cmd)] = 0.0
    feed_forward = target_velocity.copy()
    feed_forward[np.isnan(feed_forward)] = 0.0
    cmd += feed_forward
    horizontal = math.hypot(cmd[0], cmd[1])
    if horizontal > limits.max_xy:
        cmd[:2] *= limits.max_xy / horizontal
    cmd[2] = min(max(cmd[2], -limits.max_down), limits.max_up)
    return cmd


def track(body: Body, command: np.ndarray, limits: Limits, dt: float, ground_z: float) -> None:
    """The velocity loop: accelerate toward `command` (velocity gain * error, never past the command within one
    step, within the acceleration limit), integrate, clamp at the ground."""
    error = command - body.velocity
    dv = error * np.minimum(
        np.array([limits.velocity_gain_xy, limits.velocity_gain_xy, limits.velocity_gain_z]) * dt, 1.0
    )
    norm = math.sqrt(dv.dot(dv))
    if norm > limits.max_accel * dt:
        dv *= limits.max_accel * dt / norm
    _integrate(body, dv, dt, ground_z)


def fall(body: Body, dt: float, ground_z: float, max_accel: float) -> None:
    """Disarmed: free fall until the ground; horizontal motion decays within max_accel."""
    if body.position[2] <= ground_z and body.velocity[2] <= 0.0:
        body.velocity[:] = 0.0
        body.acceleration[:] = 0.0
        return
    dv = np.zeros(3)
    horizontal = math.hypot(body.velocity[0], body.velocity[1])
    if horizontal > 0.0:
        dv[:2] = -body.velocity[:2] * min(1.0, max_accel * dt / horizontal)
    dv[2] = -GRAVITY * dt
    _integrate(body, dv, dt, ground_z)


def _integrate(body: Body, dv: np.ndarray, dt: float, ground_z: float) -> None:
    body.velocity += dv
    body.acceleration = dv / dt
    body.position += body.velocity * dt
    if body.position[2] < ground_z:
        body.position[2] = ground_z
        body.velocity[2] = max(body.velocity[2], 0.0)


def turn(body: Body, yaw_target: float | None, yaw_rate_target: float | None, limits: Limits, dt: float) -> None:
    """Yaw toward a target angle (shortest way) or at a target rate, within the yaw-rate limit."""
    if yaw_target is not None and math.isfinite(yaw_target):
        error = wrap_pi(yaw_target - body.yaw)
        rate = max(-limits.max_yaw_rate, min(limits.max_yaw_rate, error / dt))
    elif yaw_rate_target is not None and math.isfinite(yaw_rate_target):
        rate = max(-limits.max_yaw_rate, min(limits.max_yaw_rate, yaw_rate_target))
    else:
        rate = 0.0
    body.yaw = wrap_pi(body.yaw + rate * dt)
    body.yaw_rate = rate


def tilt(body: Body) -> tuple[float, float]:
    """(roll, pitch) in rad that a multicopter needs for the body's horizontal acceleration (FRD body frame)."""
    a_north, a_east = body.acceleration[1], body.acceleration[0]
    forward = a_north * math.cos(body.yaw) + a_east * math.sin(body.yaw)
    right = -a_north * math.sin(body.yaw) + a_east * math.cos(body.yaw)
    return math.atan2(right, GRAVITY), -math.atan2(forward, GRAVITY)


def wrap_pi(angle: float) -> float:
    return (angle + math.pi) % (2.0 * math.pi) - math.pi
