"""No agent opens the world file. The agent imports nothing of `swarm.sim` (tests/test_layers.py); this checks what
it does with the config `swarm run` gives it: a world path that does not exist, the mission volume, and a camera
heard through the simulator's sensor router. Its whole start-up before the bus (epoch, keys, mapping task, camera
source) runs with `load_world` made to fail."""

from __future__ import annotations

import asyncio
from pathlib import Path

import numpy as np
import pytest

from swarm.agent import main
from swarm.agent.main import Agent
from swarm.config import load_config
from swarm.mission.run import NO_WORLD_FOR_AGENTS, RunPlan, RunState, _agent_camera, _write_config
from swarm.sensing.zenoh_source import ZenohSensorSource
from swarm.sim import worlds


class ReachedTheBus(Exception):
    pass


def test_an_agent_configured_as_swarm_run_configures_it_starts_without_loading_the_world(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    config = load_config(overrides={"mission.world": "box"})
    volume = (np.zeros(3), np.array([4.0, 4.0, 3.0]))
    plan = RunPlan(config, worlds.load_world("box"), tmp_path, [], [], volume, sensor_port=7650)
    written = config.model_copy(update=_agent_camera(plan, RunState(), 1))
    agent_config = load_config(_write_config(tmp_path / "config" / "agent-1.toml", written))  # as the agent reads it
    assert agent_config.mission.world == str(tmp_path / "config" / NO_WORLD_FOR_AGENTS)
    assert not Path(agent_config.mission.world).exists()

    def no_world(spec: str) -> worlds.World:
        raise AssertionError(f"the agent loaded the world {spec}")

    started: list[str] = []

    async def bus(*args: object) -> None:
        raise ReachedTheBus

    monkeypatch.setattr(worlds, "load_world", no_world)
    monkeypatch.setattr(ZenohSensorSource, "start", lambda self: started.append(self.settings.depth_topic))
    monkeypatch.setattr(main.AsyncBus, "open", bus)
    monkeypatch.setattr(Agent, "_install_signal_handlers", lambda self, loop: None)  # not in the test's process
    with pytest.raises(ReachedTheBus):
        asyncio.run(Agent(agent_config).run())
    assert started == ["/drone1/camera/depth/image_rect_raw"]  # its camera started, from the streams alone
