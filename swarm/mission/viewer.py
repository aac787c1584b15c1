"""`swarm view RUN_DIR`: a finished run's recordings (`*.rrd`) in the Rerun viewer, native or in a browser.

The viewer is the `rerun` program bundled in the rerun-sdk wheel (package `rerun_cli`), run directly (through
`python -m rerun` a stopped wrapper leaves the viewer behind), in the foreground, given every .rrd file of the
run: files with the same recording id (the run's, `swarm.mission.recording.run_recording_id`) open as one
recording. Every server it starts (its gRPC proxy; with --web the HTTP server too) binds to loopback only;
reach the web viewer from another machine through an SSH tunnel.
"""

from __future__ import annotations

import importlib.util
import os
import subprocess
from pathlib import Path

from swarm.errors import SwarmError

BIND = "127.0.0.1"
DISPLAY_VARIABLES = ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET")


def run_recordings(run_dir: Path) -> list[Path]:
    """The run's .rrd files (its own and any under it, e.g. per-agent ones), sorted; SwarmError (one line) when
    the directory does not exist or holds none."""
    if not run_dir.is_dir():
        raise SwarmError(f"{run_dir}: no such run directory")
    paths = sorted(p for p in run_dir.rglob("*.rrd") if p.is_file())
    if not paths:
        raise SwarmError(f"{run_dir}: no recording (*.rrd) in it; was it run with --no-rrd?")
    return paths


def rerun_binary() -> Path:
    """The viewer program of the installed rerun-sdk wheel."""
    spec = importlib.util.find_spec("rerun_cli")
    path = Path(spec.origin).parent / "rerun" if spec is not None and spec.origin else Path("rerun_cli/rerun")
    if not path.is_file():
        raise SwarmError(f"no Rerun viewer at {path} (reinstall rerun-sdk)")
    return path


def viewer_argv(
    binary: Path, paths: list[Path], web_port: int | None = None, grpc_port: int | None = None
) -> list[str]:
    """The viewer's command line for `paths`: native, or with `web_port` the web viewer served on loopback at
    that port (HTTP). `grpc_port`: the port of its gRPC proxy (default Rerun's, 9876)."""
    argv = [str(binary), "--bind", BIND]
    if grpc_port is not None:
        argv += ["--port", str(grpc_port)]
    if web_port is not None:
        argv += ["--web-viewer", "--web-viewer-port", str(web_port)]
    return argv + [str(p) for p in paths]


def has_display(environ: dict[str, str] | os._Environ[str] = os.environ) -> bool:
    return any(environ.get(name) for name in DISPLAY_VARIABLES)


def view_run(run_dir: Path) -> int:
    """The native viewer on the run's recordings, until its window is closed; returns its exit code."""
    paths = run_recordings(run_dir)
    if not has_display():
        raise SwarmError("no display (DISPLAY and WAYLAND_DISPLAY are unset): use swarm view --web RUN_DIR")
    return _call(viewer_argv(rerun_binary(), paths))


def serve_run(run_dir: Path, port: int) -> int:
    """The web viewer on the run's recordings at http://127.0.0.1:PORT, until Ctrl-C."""
    argv = viewer_argv(rerun_binary(), run_recordings(run_dir), web_port=port)
    print(f"web viewer at http://{BIND}:{port} (Ctrl-C to stop)", flush=True)
    return _call(argv)


def _call(argv: list[str]) -> int:
    try:
        process = subprocess.Popen(argv, stdin=subprocess.DEVNULL)
    except OSError as exc:
        raise SwarmError(f"cannot start the Rerun viewer: {exc}") from None
    try:
        return process.wait()
    except KeyboardInterrupt:
        process.terminate()
        process.wait()
        return 0
