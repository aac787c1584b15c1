"""The agent's camera sources: it never loads a world (tests/test_layers.py: it imports nothing of swarm.sim), so
every source needs the mission volume."""

from __future__ import annotations

import asyncio

import numpy as np
import pytest

from swarm.agent.main import Agent
from swarm.config import ConfigError, load_config
from swarm.sensing.zenoh_source import ZenohSensorSource

VOLUME = {"min": [0.0, 0.0, 0.0], "max": [4.0, 4.0, 3.0]}


@pytest.mark.parametrize("source", ["sim", "zenoh", "replay"])
def test_a_camera_without_a_mission_volume_is_one_clear_error(source: str) -> None:
    config = load_config(overrides={"camera.source": source, "mission.world": "/nonexistent/world.ply"})
    loop = asyncio.new_event_loop()
    try:
        with pytest.raises(ConfigError, match="needs mission.volume"):
            Agent(config)._make_mapping(loop)
    finally:
        loop.close()


@pytest.mark.parametrize(("source", "prefix"), [("sim", "/drone3/"), ("zenoh", "/")])
def test_the_simulators_camera_is_heard_under_the_vehicles_namespace_and_a_zenoh_one_as_configured(
    source: str, prefix: str
) -> None:
    config = load_config(
        overrides={
            "camera.source": source,
            "agent.id": 3,
            "mission.world": "/nonexistent/world.ply",
            "mission.volume": VOLUME,
        }
    )
    loop = asyncio.new_event_loop()
    try:
        mapping = Agent(config)._make_mapping(loop)
        assert mapping is not None and isinstance(mapping.source, ZenohSensorSource)
        assert mapping.source.settings.depth_topic == f"{prefix}camera/depth/image_rect_raw"
        assert np.allclose(mapping.bounds[1], (4.0, 4.0, 3.0))
        mapping._worker.shutdown()
    finally:
        loop.close()
