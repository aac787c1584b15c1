"""`swarm bench mapping --drones N`'s verdict and the simulated cameras' render cost it reports (unit tier)."""

from __future__ import annotations

from pathlib import Path

import pytest

from swarm.mission.bench import SUSTAINED_SHARE, camera_render_ms, sustains

pytestmark = pytest.mark.unit


def test_every_agent_must_integrate_nearly_the_camera_rate() -> None:
    assert sustains([9.8, 9.76, 9.9], 10.0)
    assert not sustains([9.8, 9.4, 9.9], 10.0)  # one agent below 95 %
    assert sustains([SUSTAINED_SHARE * 10.0], 10.0)
    assert not sustains([], 10.0)


def test_the_render_cost_is_read_from_the_camera_drivers_last_line(tmp_path: Path) -> None:
    log = tmp_path / "cameras.log"
    log.write_text(
        "swarm cameras: 5 depth cameras at 10 Hz on tcp/127.0.0.1:7647 (rmw_zenoh keys, /drone1/depth ...)\n"
        "camera driver: drone 2: bad odometry\n"
        "swarm cameras: published 6120 images, render 3.4 ms each\n"
    )
    assert camera_render_ms(log) == 3.4
    log.write_text("swarm cameras: 5 depth cameras at 10 Hz\n")  # killed before its last line
    assert camera_render_ms(log) is None
    assert camera_render_ms(tmp_path / "none.log") is None
