"""Helpers for the simulator tests: free loopback ports, a simulator in a thread, a pymavlink ground station."""

from __future__ import annotations

import math
import random
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

from swarm.config import SwarmConfig, load_config
from swarm.mission.ports import find_free_base
from swarm.sim.server import SimServer
from swarm.sim.worlds import World
from tests.helpers import worker_ports

PORT_BLOCK = 40  # vehicle ports at base .. base+19, GCS ports at base+20 .. base+39


def free_port_block(size: int = PORT_BLOCK) -> int:
    """A base port such that base .. base+size-1 are free UDP ports (never the 14540/14580 defaults), below the
    ephemeral range, in this test worker's share of them (`tests.helpers.worker_ports`)."""
    lo, hi = worker_ports()
    start = random.randrange(lo, hi - 2 * size, size)
    return find_free_base("127.0.0.1", size, "udp", start, stop=hi - size, step=size)


def sim_config(base_port: int, **overrides: Any) -> SwarmConfig:
    values = {
        "sim.vehicle_base_port": base_port,
        "sim.gcs_base_port": base_port + PORT_BLOCK // 2,
        "mission.world": "box",
        "mission.drones": 1,
        # the simulated vehicle starts with PX4's defaults, where an agent death is a Return: an agent flown
        # in-process against it writes the safe values first, as every agent of swarm run does
        "agent.px4_params": "set",
    }
    values.update(overrides)
    return load_config(overrides=values)


def wait_until(predicate: Callable[[], bool], timeout: float, what: str, poll: float = 0.01) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(poll)


@contextmanager
def running_sim(config: SwarmConfig, world: World) -> Iterator[SimServer]:
    """A simulator serving real UDP ports from a thread; always stopped, joined and closed."""
    server = SimServer(config, world)
    server.open()
    stop = threading.Event()
    errors: list[BaseException] = []

    def loop() -> None:
        try:
            server.run(stop)
        except BaseException as exc:  # surfaced in the test thread below
            errors.append(exc)

    thread = threading.Thread(target=loop, name="sim", daemon=True)
    thread.start()
    try:
        yield server
    finally:
        stop.set()
        thread.join(timeout=10)
        server.close()
    assert not thread.is_alive(), "simulator thread did not stop"
    if errors:
        raise errors[0]


class Gcs:
    """A pymavlink ground station (sysid 245, compid 190 as MAVSDK) listening on a vehicle's GCS port."""

    def __init__(self, port: int) -> None:
        self.conn = mavutil.mavlink_connection(
            f"udpin:127.0.0.1:{port}", source_system=245, source_component=190, dialect="common"
        )
        self.target = 1

    def close(self) -> None:
        self.conn.close()

    def recv_until(
        self, predicate: Callable[[Any], bool], timeout: float, what: str, types: str | list[str] | None = None
    ) -> Any:
        """The first message (of `types`) that satisfies predicate, within timeout."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            msg = self.conn.recv_match(type=types, blocking=True, timeout=0.1)
            if msg is not None and msg.get_type() != "BAD_DATA" and predicate(msg):
                return msg
        raise AssertionError(f"timed out after {timeout} s waiting for {what}")

    def heartbeat(self, timeout: float = 5.0) -> Any:
        msg = self.recv_until(lambda m: True, timeout, "HEARTBEAT", "HEARTBEAT")
        self.target = msg.get_srcSystem()
        return msg

    def command(self, command: int, *params: float, timeout: float = 3.0) -> Any:
        """Send COMMAND_LONG and return its COMMAND_ACK."""
        p = list(params) + [0.0] * (7 - len(params))
        self.conn.mav.command_long_send(self.target, 1, command, 0, *p)
        return self.recv_until(lambda m: m.command == command, timeout, f"ACK of command {command}", "COMMAND_ACK")

    def command_int(
        self,
        command: int,
        frame: int,
        params: tuple[float, float, float, float],
        x: int,
        y: int,
        z: float,
        timeout: float = 3.0,
    ) -> Any:
        self.conn.mav.command_int_send(self.target, 1, frame, command, 0, 0, *params, x, y, z)
        return self.recv_until(lambda m: m.command == command, timeout, f"ACK of command {command}", "COMMAND_ACK")

    def latest(self, msg_type: str) -> Any:
        return self.conn.messages.get(msg_type)


NAN = math.nan
ACCEPTED = mavlink.MAV_RESULT_ACCEPTED


@contextmanager
def gcs(port: int) -> Iterator[Gcs]:
    client = Gcs(port)
    try:
        yield client
    finally:
        client.close()
