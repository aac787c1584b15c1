"""`swarm view RUN_DIR`: a finished run's recordings (`*.rrd`) in the Rerun viewer, native or in a browser.

The viewer is the `rerun` program bundled in the rerun-sdk wheel (package `rerun_cli`), run directly (through
`python -m rerun` a stopped wrapper leaves the viewer behind), in the foreground, given every .rrd file of the
run: files with the same recording id (the run's, `swarm.mission.recording.run_recording_id`) open as one
recording. Every server it starts (its gRPC proxy; with --web the HTTP server too) binds to loopback only;
reach the web viewer from another machine through an SSH tunnel.

`LiveViewer` is the viewer `swarm run --view` streams to while the swarm flies: one it starts (native, or the
web viewer) or one already running, named by its gRPC proxy URL. The processes that record (observer, camera
driver, harness) send their streams there as well as to their files (`swarm.mission.recording.open_stream`).

Every viewer started here runs with `CI=1` in its environment: Rerun's viewer then sends no usage data
(its analytics are off on CI machines); Swarm sends nothing off the machine.
"""

from __future__ import annotations

import importlib.util
import os
import socket
import subprocess
import time
from pathlib import Path
from urllib.parse import quote

from swarm.config import VIEW_MODES
from swarm.errors import SwarmError
from swarm.mission.ports import ensure_free, find_free_base

BIND = "127.0.0.1"
GRPC_PORT = 9876  # Rerun's own default for its gRPC proxy; the next free one is taken
DISPLAY_VARIABLES = ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET")


def run_recordings(run_dir: Path) -> list[Path]:
    """The run's .rrd files (its own and any under it, e.g. per-agent ones), sorted, then its blueprint (.rbl,
    the viewer's layout); SwarmError (one line) when the directory does not exist or holds no recording."""
    if not run_dir.is_dir():
        raise SwarmError(f"{run_dir}: no such run directory")
    paths = sorted(p for p in run_dir.rglob("*.rrd") if p.is_file())
    if not paths:
        raise SwarmError(f"{run_dir}: no recording (*.rrd) in it; was it run with --no-rrd?")
    return paths + sorted(p for p in run_dir.glob("*.rbl") if p.is_file())  # the layout, if the run wrote one


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


def screenshot_run(run_dir: Path, out: Path, wait_s: float = 45.0) -> Path:
    """A PNG of the web viewer showing the run's recordings (`swarm.mission.screenshot`): the viewer is served
    on free loopback ports while headless Chromium looks at it."""
    from swarm.mission.screenshot import screenshot, viewer_page

    paths = run_recordings(run_dir)
    web_port = find_free_base(BIND, 1, "tcp", 9090, step=1)
    grpc_port = find_free_base(BIND, 1, "tcp", GRPC_PORT, step=1)
    server = _start_quietly(viewer_argv(rerun_binary(), paths, web_port=web_port, grpc_port=grpc_port), False)
    try:
        _wait_listening(web_port, server)
        return screenshot(viewer_page(web_port, proxy_url(grpc_port)), out, wait_s)
    finally:
        server.terminate()
        server.wait()


def _start_quietly(argv: list[str], open_browser: bool | None = None) -> subprocess.Popen[bytes]:
    """A viewer started in the background, its output kept out of ours (`viewer_env` for `open_browser`)."""
    try:
        return subprocess.Popen(
            argv,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            env=viewer_env(open_browser),
        )
    except OSError as exc:
        raise SwarmError(f"cannot start the Rerun viewer: {exc}") from None


def _wait_listening(port: int, server: subprocess.Popen[bytes], timeout_s: float = 20.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if server.poll() is not None:
            raise SwarmError(f"the Rerun viewer exited ({server.returncode}) before serving")
        with socket.socket() as sock:
            if sock.connect_ex((BIND, port)) == 0:
                return
        time.sleep(0.2)
    raise SwarmError(f"the Rerun viewer did not serve on port {port} within {timeout_s:.0f} s")


def proxy_url(port: int) -> str:
    return f"rerun+http://{BIND}:{port}/proxy"


def viewer_env(open_browser: bool | None = None) -> dict[str, str]:
    """The viewer's environment: no usage data sent (module docstring). The web viewer opens the system's browser
    on its page: only when `open_browser` (default: when there is a display); else BROWSER is `true`, which it
    runs instead (headless, a browser started for nothing writes its profile into the home directory)."""
    env = {**os.environ, "CI": "1"}
    if not (has_display() if open_browser is None else open_browser):
        env["BROWSER"] = "true"
    return env


class LiveViewer:
    """The viewer a run streams to: `mode` "native" or "web" starts one (on loopback, at a free gRPC port; the
    web viewer's HTTP server at `web_port`), a rerun+http URL names one already running. `url` is where the
    recording streams go. The viewer outlives the mission: `wait` until it is closed (native) or Ctrl-C (web)."""

    def __init__(self, mode: str, web_port: int = 9090) -> None:
        self.mode = mode
        self.web_port = web_port
        self.process: subprocess.Popen[bytes] | None = None
        if mode not in VIEW_MODES:
            self.url = mode
            return
        if mode == "native" and not has_display():
            raise SwarmError("no display for --view (DISPLAY and WAYLAND_DISPLAY are unset): use --view web")
        if mode == "web":
            ensure_free(BIND, web_port, "tcp", "the web viewer")
        self.grpc_port = find_free_base(BIND, 1, "tcp", GRPC_PORT, step=1)
        self.url = proxy_url(self.grpc_port)

    def argv(self) -> list[str]:
        argv = [str(rerun_binary()), "--bind", BIND, "--port", str(self.grpc_port), "--expect-data-soon"]
        if self.mode == "web":
            argv += ["--serve-web", "--web-viewer-port", str(self.web_port)]
        return argv

    def start(self) -> LiveViewer:
        """Start the viewer (its own log stays out of the mission's output) and wait until it listens."""
        if self.mode in VIEW_MODES:
            self.process = _start_quietly(self.argv())
            _wait_listening(self.grpc_port, self.process)
            print(f"swarm run: {self.describe()}", flush=True)
        return self

    def describe(self) -> str:
        if self.mode == "web":
            return f"web viewer at http://{BIND}:{self.web_port}/?url={quote(self.url, safe='')} (streaming live)"
        if self.mode == "native":
            return f"viewer window open, streaming live ({self.url})"
        return f"streaming live to the viewer at {self.url}"

    def wait(self) -> int:
        """After the mission: until the window is closed (native) or Ctrl-C (web); at once for a URL."""
        if self.process is None:
            return 0
        if self.mode == "web":
            print(f"swarm run: the recording stays served at http://{BIND}:{self.web_port} (Ctrl-C to stop)")
        return _wait(self.process)

    def close(self) -> None:
        if self.process is not None and self.process.poll() is None:
            self.process.terminate()
            self.process.wait()


def _call(argv: list[str]) -> int:
    try:
        process = subprocess.Popen(argv, stdin=subprocess.DEVNULL, env=viewer_env())
    except OSError as exc:
        raise SwarmError(f"cannot start the Rerun viewer: {exc}") from None
    return _wait(process)


def _wait(process: subprocess.Popen[bytes]) -> int:
    try:
        return process.wait()
    except KeyboardInterrupt:
        process.terminate()
        process.wait()
        return 0
