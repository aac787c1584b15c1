"""`Flight.is_clear` asked of a world mesh, for tests that fly or plan without a map."""

from __future__ import annotations

import numpy as np


def clear_in(world, margin=0.5):  # type: ignore[no-untyped-def]
    """`Flight.is_clear` from the world mesh: every point of a-b (every 5 cm) at least 0.6 m up and its airframe
    `margin` from every surface."""

    def is_clear(a, b) -> bool:  # type: ignore[no-untyped-def]
        a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
        t = np.linspace(0.0, 1.0, max(2, int(np.linalg.norm(b - a) / 0.05) + 1))[:, None]
        points = a + t * (b - a)
        return bool((points[:, 2] >= 0.6).all() and (world.distance(points + [0.0, 0.0, 0.22]) > margin).all())

    return is_clear
