"""The exploration oracle on the `box` world: its views really see 95 % of the reachable space (rendered by the
simulated camera, fused into a real map and measured as the report measures it), more drones never take longer,
and a poorer camera never takes less time."""

from __future__ import annotations

import numpy as np
import pytest

from swarm.config import SwarmConfig, load_config
from swarm.mission.oracle import Oracle
from swarm.patches.fused import UNKNOWN
from swarm.patches.mapper import Mapper
from swarm.sim.camera import DepthCamera
from swarm.sim.coverage import explored_fraction, mission_reachable_space
from swarm.sim.worlds import load_world, mission_volume


def _config(**overrides: object) -> SwarmConfig:
    return load_config(overrides={"mission.world": "box", **overrides})


@pytest.fixture(scope="module")
def box_oracle() -> Oracle:
    return Oracle(load_world("box"), _config())


def test_the_chosen_views_rendered_and_fused_cover_95_percent_of_the_reachable_space(box_oracle: Oracle) -> None:
    config, world = box_oracle.config, box_oracle.world
    plan = box_oracle.plan(1)
    assert plan.time_to_95_s is not None and plan.coverage >= 0.95
    camera = DepthCamera(world, config.camera)
    mapper = Mapper(config.mapping, producer=1, epoch=1, bounds=mission_volume(world, None))
    for t, view in enumerate(plan.views):
        mapper.integrate(
            camera.render(camera.pose(view.position, view.yaw_deg)),
            camera.intrinsics,
            camera.pose(view.position, view.yaw_deg),
            float(t),
            config.camera.max_range_m,
        )
    mapper.seal()
    space = mission_reachable_space(world, config)
    with mapper.current_map() as fused:
        measured = explored_fraction(space, lambda points: fused.state_at(points) != UNKNOWN)
    assert measured >= 0.95


def test_every_view_is_reachable_and_keeps_the_airframe_clear(box_oracle: Oracle) -> None:
    config = box_oracle.config
    positions = np.array([v.position for v in box_oracle.plan(1).views])
    for lift in (0.0, config.explore.body_height_m):
        gaps = box_oracle.world.distance(positions + [0.0, 0.0, lift])
        assert np.all(gaps >= config.explore.clearance_m)
    lo, _ = mission_volume(box_oracle.world, None)
    assert np.all(positions[:, 2] >= lo[2] + config.explore.min_altitude_m)


def test_more_drones_never_take_longer(box_oracle: Oracle) -> None:
    times = [box_oracle.plan(n).time_to_95_s for n in (1, 2, 3, 4)]
    assert all(t is not None for t in times)
    assert times == sorted(times, reverse=True)
    assert times[2] < times[0]  # and three drones do share the work


@pytest.mark.parametrize("poorer", [{"camera.hfov_deg": 60.0}, {"camera.max_range_m": 3.0}])
def test_a_narrower_or_shorter_sighted_camera_never_takes_less_time(box_oracle: Oracle, poorer: dict) -> None:
    worse = Oracle(load_world("box"), _config(**poorer))
    for n in (1, 3):
        assert worse.plan(n).time_to_95_s >= box_oracle.plan(n).time_to_95_s


def test_a_target_no_view_can_reach_gives_no_time_and_says_why() -> None:
    blind = Oracle(load_world("box"), _config(**{"camera.max_range_m": 0.5}))
    plan = blind.plan(1)
    assert plan.time_to_95_s is None
    assert plan.coverage < 0.95 and plan.notes
