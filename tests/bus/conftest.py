from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import uuid
from collections.abc import AsyncIterator, Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from swarm.bus.bridge import AsyncBus
from tests.bus.helpers import open_connecting_bus, open_listening_bus

REPO_ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def mission() -> str:
    """A mission name of its own, so concurrent test runs never share keys."""
    return f"t{os.getpid()}-{uuid.uuid4().hex[:8]}"


@pytest.fixture
async def bus_pair(mission: str) -> AsyncIterator[tuple[AsyncBus, AsyncBus]]:
    """Two sessions in this process: `a` listens on loopback, `b` connects to it."""
    a, endpoint = await open_listening_bus(mission)
    b: AsyncBus | None = None
    try:
        b = await open_connecting_bus(mission, endpoint)
        yield a, b
    finally:
        if b is not None:
            await b.close()
        await a.close()


class PeerProcess:
    """A running `tests.bus.peer_process`; its stdout JSON events collect in `events`."""

    def __init__(
        self,
        mission: str,
        agent_id: int,
        endpoint: str | list[str],
        listen: str | None = None,
        repair_routes: bool = False,
    ) -> None:
        self.agent_id = agent_id
        self.events: list[dict[str, Any]] = []
        self.stderr: list[str] = []
        self.proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "tests.bus.peer_process",
                "--mission",
                mission,
                "--id",
                str(agent_id),
                *(arg for e in ([endpoint] if isinstance(endpoint, str) else endpoint) for arg in ("--connect", e)),
                *(["--listen", listen] if listen else []),
                *(["--repair-routes"] if repair_routes else []),
            ],
            cwd=REPO_ROOT,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        self._pumps = [
            threading.Thread(target=self._pump, args=(stream, sink), daemon=True)
            for stream, sink in ((self.proc.stdout, self._on_stdout), (self.proc.stderr, self.stderr.append))
        ]
        for pump in self._pumps:
            pump.start()

    @staticmethod
    def _pump(stream: Any, sink: Callable[[str], None]) -> None:
        for line in stream:
            sink(line)

    def _on_stdout(self, line: str) -> None:
        try:
            self.events.append(json.loads(line))
        except ValueError:
            self.stderr.append(f"(stdout) {line}")

    def of(self, event: str) -> list[dict[str, Any]]:
        return [e for e in list(self.events) if e.get("event") == event]

    def describe(self) -> str:
        return f"peer {self.agent_id} (exit code {self.proc.poll()}), stderr:\n{''.join(self.stderr[-30:])}"

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGKILL)
        self.proc.wait(5)

    def stop(self) -> None:
        """SIGTERM (the peer closes its bus and exits), SIGKILL if it is still there after 5 s."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGCONT)  # in case a test left it stopped
            self.proc.terminate()
            try:
                self.proc.wait(5)
            except subprocess.TimeoutExpired:
                self.kill()
        self._release()

    def _release(self) -> None:
        for pump in self._pumps:
            pump.join(2)
        for stream in (self.proc.stdout, self.proc.stderr):
            if stream is not None:
                stream.close()


@pytest.fixture
def peer_process(mission: str) -> Iterator[Callable[..., PeerProcess]]:
    """Start peer processes of this test's mission (`start(id, endpoint or endpoints, listen=None,
    repair_routes=False)`); all are stopped (or killed) afterwards."""
    started: list[PeerProcess] = []

    def start(
        agent_id: int, endpoint: str | list[str], listen: str | None = None, repair_routes: bool = False
    ) -> PeerProcess:
        peer = PeerProcess(mission, agent_id, endpoint, listen, repair_routes)
        started.append(peer)
        return peer

    try:
        yield start
    finally:
        for peer in started:
            peer.stop()
