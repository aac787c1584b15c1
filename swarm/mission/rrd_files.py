"""The names of a run's Rerun recordings, without importing Rerun (0.5 s and 100 MB): the harness and the report
page need the names, only the processes that write a recording need the SDK (`swarm.mission.recording`)."""

from __future__ import annotations

from pathlib import Path

RECORDING_NAME = "run.rrd"  # the observer's and the harness's recording of the run
DEPTH_RECORDING_NAME = "cameras.rrd"  # each drone's depth image (mission.view_depth), from the camera driver
BLUEPRINT_NAME = "run.rbl"  # the viewer's layout for the run (swarm.mission.recording.run_blueprint)


def run_recording_id(out: Path, started_wall: float) -> str:
    """The recording id every process of one run uses: the run directory's name and the mission clock's zero
    (ms), so two runs never share one and the processes of one always do."""
    return f"{out.name}-{round(started_wall * 1000)}"
