"""The tilting test flight the sensor tests share: along the office's lobby, 4 m in 6 s, pitching +-12 deg,
rolling +-8 deg and turning half round."""

from __future__ import annotations

import math

import numpy as np


def flight(t: float) -> tuple[np.ndarray, float, float, float]:
    """(position, roll, pitch, NED yaw) at `t` seconds into the flight."""
    s = min(max(t, 0.0) / 6.0, 1.0)
    return (
        np.array([3.0 + 4.0 * s, 10.0, 1.5]),
        math.radians(8) * math.cos(2.1 * t),
        math.radians(12) * math.sin(3.0 * t),
        math.radians(90 + 180 * s),
    )
