import numpy as np
import pytest

from swarm.agent.sensing import DepthFrame, DepthSource, SimulatedDepthSource, make_depth_source
from swarm.config import CameraSettings, load_config
from swarm.sim.worlds import World, load_world


@pytest.fixture(scope="module")
def box_world() -> World:
    return load_world("box")


def test_simulated_frames_are_consistent(box_world: World) -> None:
    settings = CameraSettings(width=64, height=48, hfov_deg=80.0)
    source: DepthSource = SimulatedDepthSource(box_world, settings, seed=0)
    frames = [source.capture(i, 0.1 * i, (2.0, 2.0 + 0.5 * i, 1.5), 30.0 * i) for i in range(4)]
    for i, frame in enumerate(frames):
        assert isinstance(frame, DepthFrame)
        assert frame.index == i and frame.t == pytest.approx(0.1 * i)
        assert frame.depth.shape == (48, 64) and frame.depth.dtype == np.float32
        assert np.allclose(frame.K, frames[0].K) and frame.K[0, 2] == 32.0 and frame.K[1, 2] == 24.0
        assert np.allclose(frame.T_world_cam[:3, 3], (2.0, 2.0 + 0.5 * i, 1.5))
        yaw = np.radians(30.0 * i)
        assert np.allclose(frame.T_world_cam[:3, 2], [np.cos(yaw), np.sin(yaw), 0.0])
        # depth, K and pose agree: every valid pixel back-projects onto the world's surface
        points = frame.world_points()
        assert len(points) > 0.9 * frame.depth.size
        assert np.all(box_world.distance(points) < 2e-3)


def test_make_depth_source_uses_the_mission_world() -> None:
    config = load_config(overrides={"mission.world": "box", "camera.width": 32, "camera.height": 24})
    frame = make_depth_source(config).capture(7, 12.5, (2.0, 4.0, 1.0), 0.0)
    assert frame.index == 7 and frame.t == 12.5 and frame.depth.shape == (24, 32)
    assert frame.depth[12, 16] == pytest.approx(4.0 - 2.0, abs=1e-3)  # the wall stub at x = 4 faces the camera


def test_a_zenoh_camera_without_a_mission_volume_is_one_clear_error_and_with_one_no_world_is_loaded(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import asyncio

    from swarm.agent.main import Agent
    from swarm.config import ConfigError
    from swarm.sensing.zenoh_source import ZenohSensorSource

    def no_world(spec: str) -> World:
        raise AssertionError(f"the agent loaded the world {spec}")

    monkeypatch.setattr("swarm.agent.main.load_world", no_world)
    config = load_config(overrides={"camera.source": "zenoh", "mission.world": "/nonexistent/world.ply"})
    loop = asyncio.new_event_loop()
    try:
        with pytest.raises(ConfigError, match="needs mission.volume"):
            Agent(config)._make_mapping(loop)
        with_volume = load_config(overrides={
            "camera.source": "zenoh", "mission.world": "/nonexistent/world.ply",
            "mission.volume": {"min": [0.0, 0.0, 0.0], "max": [4.0, 4.0, 3.0]}})
        mapping = Agent(with_volume)._make_mapping(loop)
        assert mapping is not None and isinstance(mapping.source, ZenohSensorSource)
        assert np.allclose(mapping.bounds[1], (4.0, 4.0, 3.0))
        mapping._worker.shutdown()
    finally:
        loop.close()
