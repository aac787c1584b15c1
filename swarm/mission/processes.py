"""Child processes of `swarm run`: started with their own log files, always stopped, never left behind.

Each child gets PR_SET_PDEATHSIG, so the kernel sends it SIGTERM if the orchestrator dies without cleaning up
(even by SIGKILL). `stop()` asks politely (SIGTERM, which makes an airborne agent land), then kills.

A child may be asked to run at a niceness below the harness's (a higher scheduling priority, `nice`): it is set
between fork and exec, so every thread the program starts inherits it. Lowering niceness needs root or
CAP_SYS_NICE; without them the child runs as the harness does, and `Child.nice` (read back from the kernel
after the start) says which one it got.
"""

from __future__ import annotations

import ctypes
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

_PR_SET_PDEATHSIG = 1


def _die_with_parent() -> None:
    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
    except OSError:
        pass


def swarm_command(*args: str) -> list[str]:
    """The command line of a swarm subcommand, run by this interpreter."""
    return [sys.executable, "-m", "swarm", *args]


@dataclass
class Child:
    name: str
    popen: subprocess.Popen[bytes]
    log_path: Path
    _log: IO[bytes] = field(repr=False)
    nice: int = 0  # the niceness the kernel gave it (the one asked for, or the harness's when not permitted)

    @property
    def pid(self) -> int:
        return self.popen.pid

    def poll(self) -> int | None:
        return self.popen.poll()

    def last_log_line(self) -> str:
        try:
            lines = self.log_path.read_text(errors="replace").strip().splitlines()
        except OSError:
            return ""
        return lines[-1] if lines else ""

    def signal(self, signum: int) -> None:
        if self.popen.poll() is None:
            try:
                self.popen.send_signal(signum)
            except ProcessLookupError:
                pass

    def stop(self, grace_s: float) -> int:
        """SIGTERM, wait up to grace_s, then SIGKILL; returns the exit code."""
        self.signal(signal.SIGTERM)
        try:
            code = self.popen.wait(timeout=grace_s)
        except subprocess.TimeoutExpired:
            self.popen.kill()
            code = self.popen.wait()
        self._log.close()
        return code


def _prepare_child(nice: int | None) -> Callable[[], None]:
    def prepare() -> None:
        _die_with_parent()
        if nice is not None:
            try:
                os.setpriority(os.PRIO_PROCESS, 0, nice)
            except OSError:
                pass  # not permitted: the child keeps the harness's niceness, and Child.nice says so

    return prepare


def start_child(
    name: str, argv: list[str], log_path: Path, env: dict[str, str] | None = None, nice: int | None = None
) -> Child:
    """Start `argv` with its output in `log_path`; at niceness `nice` when given and permitted."""
    log_path.parent.mkdir(parents=True, exist_ok=True)
    log = open(log_path, "wb")
    child_env = {**os.environ, "PYTHONUNBUFFERED": "1", "OMP_NUM_THREADS": "1", **(env or {})}
    popen = subprocess.Popen(
        argv,
        stdout=log,
        stderr=subprocess.STDOUT,
        stdin=subprocess.DEVNULL,
        env=child_env,
        preexec_fn=_prepare_child(nice),
    )
    try:
        got = os.getpriority(os.PRIO_PROCESS, popen.pid)  # exec has happened: Popen returns after it
    except OSError:
        got = os.getpriority(os.PRIO_PROCESS, 0)  # already gone (it failed at once): what it would have had
    return Child(name, popen, log_path, log, got)


def stop_all(children: list[Child], grace_s: float) -> dict[str, int]:
    """Stop children in parallel: SIGTERM to all, one shared grace period, then SIGKILL the rest."""
    for child in children:
        child.signal(signal.SIGTERM)
    deadline = time.monotonic() + grace_s
    codes = {}
    for child in children:
        codes[child.name] = child.stop(max(0.1, deadline - time.monotonic()))
    return codes
