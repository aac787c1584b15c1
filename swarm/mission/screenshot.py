"""A picture of the web viewer showing a run, taken by headless Chromium (`swarm view RUN_DIR --screenshot PNG`).

For a machine without a display or a GPU (CI, a server): the viewer's web app renders with WebGL on Chromium's
software rasteriser (SwiftShader), and Chromium is driven over the DevTools protocol on a pipe (its
`--remote-debugging-pipe`: JSON messages ended by NUL on file descriptors 3 and 4, no socket and no extra
library). Every host name but loopback is made unresolvable (`--host-resolver-rules`), so the page cannot reach
the network: the viewer's page asks for web fonts, which it then draws without. Chromium's profile, cache and
temporary files go into a directory of its own that is removed afterwards (`--user-data-dir`, and HOME, TMPDIR and
the XDG directories pointed there): nothing is left in the home directory or /tmp.

Chromium comes from Debian's `chromium` package; without it the command says so in one line.
"""

from __future__ import annotations

import base64
import fcntl
import json
import os
import shutil
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any
from urllib.parse import quote

from swarm.errors import SwarmError

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome")
WINDOW = (1600, 1000)
LOOPBACK_ONLY = "MAP * ~NOTFOUND, EXCLUDE 127.0.0.1, EXCLUDE localhost"
# Chromium writes its crash database under the home directory whatever --user-data-dir says, and its profile
# lock's socket directory under TMPDIR (a socket path: a TMPDIR of over about 60 characters fails)
SCRATCH_VARIABLES = ("HOME", "TMPDIR", "XDG_CONFIG_HOME", "XDG_CACHE_HOME")


def chromium_binary() -> str:
    for name in CHROMIUM_NAMES:
        path = shutil.which(name)
        if path is not None:
            return path
    raise SwarmError("no Chromium to take the screenshot with (Debian: apt-get install chromium)")


def viewer_page(web_port: int, grpc_url: str) -> str:
    """The web viewer's address, connected to the recording's gRPC proxy, rendering with WebGL."""
    return f"http://127.0.0.1:{web_port}/?url={quote(grpc_url, safe='')}&renderer=webgl"


class DevTools:
    """Chromium's DevTools protocol over the pipe of `--remote-debugging-pipe`."""

    def __init__(self, to_chrome: int, from_chrome: int) -> None:
        self._out = os.fdopen(to_chrome, "wb", buffering=0)
        self._in = os.fdopen(from_chrome, "rb", buffering=0)
        self._buffer = b""
        self._id = 0

    def call(self, method: str, session: str | None = None, **params: Any) -> dict[str, Any]:
        """Send one command and return its result; events that arrive meanwhile are dropped."""
        self._id += 1
        message: dict[str, Any] = {"id": self._id, "method": method, "params": params}
        if session is not None:
            message["sessionId"] = session
        self._out.write(json.dumps(message).encode() + b"\0")
        while True:
            reply = self._read()
            if reply.get("id") == self._id:
                if "error" in reply:
                    raise SwarmError(f"Chromium refused {method}: {reply['error'].get('message')}")
                result: dict[str, Any] = reply.get("result", {})
                return result

    def _read(self) -> dict[str, Any]:
        while b"\0" not in self._buffer:
            chunk = self._in.read(1 << 16)
            if not chunk:
                raise SwarmError("Chromium closed its DevTools pipe")
            self._buffer += chunk
        text, self._buffer = self._buffer.split(b"\0", 1)
        message: dict[str, Any] = json.loads(text)
        return message

    def close(self) -> None:
        self._out.close()
        self._in.close()


def screenshot(page: str, out: Path, wait_s: float) -> Path:
    """Open `page` in headless Chromium, let it run for `wait_s` (the viewer compiles, connects and loads the
    recording), and write what it shows to `out` (PNG)."""
    with tempfile.TemporaryDirectory(prefix="swarm-chromium-") as scratch:
        return _screenshot(page, out, wait_s, Path(scratch))


def _screenshot(page: str, out: Path, wait_s: float, scratch: Path) -> Path:
    to_chrome_r, to_chrome_w = os.pipe()
    from_chrome_r, from_chrome_w = os.pipe()
    argv = [
        chromium_binary(),
        "--headless=new",
        "--no-sandbox",  # as root; the page is our own viewer on loopback
        "--use-angle=swiftshader",
        "--enable-unsafe-swiftshader",
        f"--host-resolver-rules={LOOPBACK_ONLY}",
        f"--window-size={WINDOW[0]},{WINDOW[1]}",
        "--remote-debugging-pipe",
        f"--user-data-dir={scratch / 'profile'}",
        "--no-first-run",
        "about:blank",
    ]

    def child_fds() -> None:
        # the protocol's fixed descriptors, Chromium reads 3 and writes 4; copied above both first, so neither
        # end can be overwritten by the other's dup2 (Popen keeps 3 and 4 open: pass_fds)
        read_end = fcntl.fcntl(to_chrome_r, fcntl.F_DUPFD, 10)
        write_end = fcntl.fcntl(from_chrome_w, fcntl.F_DUPFD, 10)
        os.dup2(read_end, 3)
        os.dup2(write_end, 4)

    try:
        chrome = subprocess.Popen(
            argv,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            pass_fds=(3, 4),
            preexec_fn=child_fds,
            env={**os.environ, **{name: str(scratch) for name in SCRATCH_VARIABLES}},
        )
    finally:
        os.close(to_chrome_r)
        os.close(from_chrome_w)
    tools = DevTools(to_chrome_w, from_chrome_r)
    try:
        target = tools.call("Target.createTarget", url="about:blank")["targetId"]
        session = tools.call("Target.attachToTarget", targetId=target, flatten=True)["sessionId"]
        tools.call("Page.enable", session)
        tools.call("Page.navigate", session, url=page)
        time.sleep(wait_s)
        shot = tools.call("Page.captureScreenshot", session, format="png")
        out.write_bytes(base64.b64decode(shot["data"]))
        return out
    finally:
        tools.close()
        chrome.terminate()
        try:
            chrome.wait(timeout=10)
        except subprocess.TimeoutExpired:
            chrome.kill()
            chrome.wait()
