"""The web viewer shows a run: `swarm view RUN_DIR --screenshot` serves the run's recording with Rerun's web viewer
and headless Chromium (software WebGL) takes a picture of it, here of a recording of real sealed patches. Needs
Chromium (./bootstrap.sh installs Debian's)."""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

import matplotlib.image
import numpy as np
import pytest

from swarm.config import load_config
from swarm.mission.recording import MAP_RGB, MissionRecording, add_report
from swarm.mission.rrd_files import RECORDING_NAME
from swarm.mission.viewer import screenshot_run
from swarm.patches import Lattice
from swarm.patches.fused import FusedMap
from swarm.patches.wire import decode_patch
from swarm.sim.worlds import load_world
from tests.file_models import mission_report
from tests.mission.spin_patches import spin_patches
from tests.mission.test_recording import _state

pytestmark = [pytest.mark.sim, pytest.mark.timeout(120)]


def _map_share(png: Path) -> float:
    """The share of the 3D view (the left two thirds of the layout) drawn in the map's blue."""
    pixels = (matplotlib.image.imread(png)[..., :3] * 255).astype(np.int32)
    view = pixels[:, : pixels.shape[1] * 2 // 3]
    r, g, b = view[..., 0], view[..., 1], view[..., 2]
    assert MAP_RGB[2] > MAP_RGB[0] + 60  # the test's colour rule is the map's
    return float(np.mean((b > r + 60) & (b > g + 20)))


def _chromium_leftovers(*folders: Path) -> list[Path]:
    return [p for folder in folders if folder.exists() for p in folder.iterdir() if "chromium" in p.name.lower()]


def test_the_web_viewer_shows_the_map_of_a_recorded_run(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # Chromium's profile, cache and lock directory would land in HOME and TMPDIR: both are the test's own here
    # (a short TMPDIR: Chromium's lock is a socket, whose path is limited to 108 bytes)
    home, temp = tmp_path / "home", Path(tempfile.mkdtemp(prefix="swarm-test-", dir="/tmp"))
    home.mkdir()
    monkeypatch.setenv("HOME", str(home))
    monkeypatch.setenv("TMPDIR", str(temp))
    monkeypatch.setattr(tempfile, "tempdir", None)  # read TMPDIR again
    try:
        _check_the_viewer(tmp_path)
        left = _chromium_leftovers(temp, home, home / ".config", home / ".cache")
        assert not left, f"Chromium left {left}"
    finally:
        shutil.rmtree(temp, ignore_errors=True)


def _check_the_viewer(tmp_path: Path) -> None:
    config = load_config(overrides={"mission.world": "box"})
    world = load_world("box")
    fused = FusedMap(Lattice.from_settings(config.mapping), world.bounds, config.mapping.known_weight)
    for data in spin_patches(config):
        fused.add(decode_patch(data, fused.lattice, config.mapping.max_patch_bytes))
    run = tmp_path / "run"
    run.mkdir()
    recording = MissionRecording(run / RECORDING_NAME, "run-1")
    recording.world(world.vertices, world.triangles)
    start = world.default_start
    for i in range(5):
        recording.state(1.0 + i, _state(1, (start[0] + 0.2 * i, start[1], 1.2)))
    recording.map(5.0, *fused.mesh(), version=1, exact=True)
    recording.close()
    add_report(run, "run-1", mission_report(duration_s=6.0), {})  # the layout (run.rbl) comes with it
    png = screenshot_run(run, tmp_path / "viewer.png", wait_s=20.0)
    assert png.read_bytes().startswith(b"\x89PNG")
    share = _map_share(png)
    assert share > 0.1, f"{share:.3f} of the 3D view shows the map: the viewer did not draw the recording"
