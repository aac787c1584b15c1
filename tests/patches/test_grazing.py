"""Grazing pixels are not integrated: the incidence test on an analytic ceiling, and the 0.2 m slab that a far,
grazing view once made read as free space (a drone planned through it)."""

from __future__ import annotations

import numpy as np

from swarm.config import load_config
from swarm.patches.fused import FREE
from swarm.patches.grazing import drop_grazing, grazing_mask
from swarm.patches.mapper import Mapper
from swarm.sim.camera import DepthCamera
from swarm.sim.worlds import load_world, mission_volume

W, H, F = 160, 120, 80.0  # the default camera: 90 degrees across 160 pixels
K = np.array([[F, 0.0, W / 2], [0.0, F, H / 2], [0.0, 0.0, 1.0]])


def ceiling_depth(height: float) -> tuple[np.ndarray, np.ndarray]:
    """z-depth of a plane `height` above a level camera (camera y points down), and each pixel's incidence."""
    u, v = np.meshgrid((np.arange(W) + 0.5 - W / 2) / F, (np.arange(H) + 0.5 - H / 2) / F)
    up = v < 0
    depth = np.where(up, height / np.where(up, -v, 1.0), 0.0).astype(np.float32)
    incidence = np.degrees(np.arccos(np.where(up, -v, 0.0) / np.sqrt(u * u + v * v + 1.0)))
    return depth, incidence


def test_pixels_are_kept_up_to_the_incidence_limit_and_edges_and_borders_dropped() -> None:
    depth, incidence = ceiling_depth(1.0)
    keep = grazing_mask(depth, K, 75.0)
    inner = np.zeros_like(keep)
    inner[1:-1, 1:-1] = True
    rows_with_return = depth[:, W // 2] > 0
    clear = inner & (depth > 0) & np.roll(rows_with_return, -1)[:, None] & np.roll(rows_with_return, 1)[:, None]
    assert np.array_equal(keep[clear & (incidence < 74.0)], np.ones(np.count_nonzero(clear & (incidence < 74.0)), bool))
    assert not keep[incidence > 76.0].any()
    assert not keep[~inner].any() and not keep[depth == 0].any()
    assert not keep[int(np.flatnonzero(rows_with_return)[-1])].any()  # the last row of returns: a depth edge
    assert drop_grazing(depth, K, 90.0) is depth  # 90 degrees: every pixel, untouched
    dropped = drop_grazing(depth, K, 75.0)
    assert np.array_equal(dropped > 0, keep) and np.array_equal(dropped[keep], depth[keep])


WORLD = "gen:3:size=16x12,storeys=2"  # storey 2's floor: a 0.2 m slab, z 3.4-3.6, solid over y 0-4.5


def free_slab_cells(max_incidence_deg: float, camera: tuple[float, float, float]) -> int:
    """Planning cells (0.2 m) of the slab layer reading FREE after one frame from `camera`, looking along +x
    under the slab (the ceiling ahead is seen at grazing incidence), integrated with `max_incidence_deg`."""
    config = load_config(overrides={"mission.world": WORLD, "mapping.max_incidence_deg": max_incidence_deg})
    world = load_world(WORLD)
    lo, hi = mission_volume(world, None)
    sim_camera = DepthCamera(world, config.camera)
    mapper = Mapper(config.mapping, producer=1, epoch=1, bounds=(lo, hi))
    T = sim_camera.pose(camera, 0.0)
    mapper.integrate(sim_camera.render(T), sim_camera.intrinsics, T, 0.0, config.camera.max_range_m)
    mapper.seal()
    with mapper.current_map() as fused:
        origin, states = fused.occupancy_grid(0.2, min_known=config.explore.seen_fraction)
    cells = states[
        int((camera[0] + 1.0) / 0.2) : int(9.8 / 0.2), int(1.0 / 0.2) : int(3.2 / 0.2), int((3.5 - origin[2]) / 0.2)
    ]
    return int(np.count_nonzero(cells == FREE))


def test_a_slab_seen_at_grazing_incidence_is_not_read_as_free_space() -> None:
    for camera in ((1.9, 2.1, 2.7), (2.2, 2.1, 2.4)):
        assert free_slab_cells(90.0, camera) > 10  # the defect, with every pixel integrated
        assert free_slab_cells(78.0, camera) == 0
