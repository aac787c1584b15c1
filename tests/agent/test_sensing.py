"""The agent's camera sources: it never loads a world (tests/test_layers.py: it imports nothing of swarm.sim), so
every source needs the mission volume; a camera that cannot start stops the agent before it opens anything, with
one line; a background task that dies in flight is logged."""

from __future__ import annotations

import asyncio
import sys
from typing import Any

import numpy as np
import pytest

from swarm.agent import main
from swarm.agent.main import Agent
from swarm.config import ConfigError, SwarmConfig, load_config
from swarm.errors import SwarmError
from swarm.sensing.messages import SensorInputError
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


class UnstartableSource:
    """A stream source whose start fails as `error`."""

    def __init__(self, error: Exception) -> None:
        self.error = error
        self.closed = False

    def start(self) -> None:
        raise self.error

    def wait_frame(self, timeout_s: float) -> None:
        raise AssertionError("a source that did not start is never read")

    def counters(self) -> dict[str, int]:
        return {}

    def close(self) -> None:
        self.closed = True


def _camera_config(source: str) -> SwarmConfig:
    return load_config(
        overrides={"camera.source": source, "mission.world": "/nonexistent/world.ply", "mission.volume": VOLUME}
    )


@pytest.mark.parametrize(
    ("error", "line"),
    [
        (SensorInputError("camera.replay_bag: bag b has no depth image topic"), "camera.replay_bag: bag b has no"),
        (RuntimeError("rmw_fastrtps_cpp\nnot found"), 'camera.source = "zenoh" cannot start: RuntimeError: rmw_'),
    ],
)
def test_a_camera_that_cannot_start_is_one_line_and_the_source_is_closed(error: Exception, line: str) -> None:
    config = _camera_config("zenoh")

    async def start() -> UnstartableSource:
        mapping = Agent(config)._make_mapping(asyncio.get_running_loop())
        assert mapping is not None
        source = mapping.source = UnstartableSource(error)
        with pytest.raises(SwarmError) as raised:
            await mapping.start()
        assert str(raised.value).startswith(line) and "\n" not in str(raised.value)
        return source

    assert asyncio.run(start()).closed


def test_without_the_ros2_extra_the_agent_refuses_to_start_before_opening_the_bus(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setitem(sys.modules, "rclpy", None)  # as if the wheels were not installed

    async def no_bus(*args: Any) -> None:
        raise AssertionError("the bus is opened only once the camera works")

    monkeypatch.setattr(main.AsyncBus, "open", no_bus)
    monkeypatch.setattr(Agent, "_install_signal_handlers", lambda self, loop: None)  # not in the test's process
    with pytest.raises(SwarmError, match=r"camera.source = \"ros2\" needs rclpy: pip install 'swarm\[ros2\]'"):
        asyncio.run(Agent(_camera_config("ros2")).run())


def test_a_background_task_that_dies_in_flight_is_logged_with_its_error() -> None:
    events: list[dict[str, Any]] = []
    agent = Agent(_camera_config("zenoh"))
    agent.log = lambda event, **fields: events.append({"event": event, **fields})  # type: ignore[assignment]

    async def dies() -> None:
        raise SensorInputError("decoder broke")

    async def fly() -> None:
        tasks = [agent._background(dies(), "mapping"), agent._background(asyncio.sleep(60), "heartbeat")]
        await asyncio.sleep(0.01)
        tasks[1].cancel()  # what the agent does to every background task at exit: not a failure
        await asyncio.gather(*tasks, return_exceptions=True)

    asyncio.run(fly())
    assert events == [{"event": "task_failed", "task": "mapping", "error": "SensorInputError: decoder broke"}]
