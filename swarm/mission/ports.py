"""Check up front that the ports a swarm needs are free, so a clash is one clear line, not a silent failure.

MAVSDK binds UDP with SO_REUSEADDR and would share (and silently lose) a port another process holds, so for
UDP a plain bind without that option is the only reliable test.
"""

from __future__ import annotations

import socket

from swarm.errors import PortInUseError

SENSOR_PORT_OFFSET = 200  # a simulated swarm's sensor router listens on bus.base_port + this


def ensure_free(host: str, port: int, kind: str, what: str) -> None:
    sock_type = socket.SOCK_DGRAM if kind == "udp" else socket.SOCK_STREAM
    with socket.socket(socket.AF_INET, sock_type) as sock:
        if kind == "tcp":
            # Zenoh listens with SO_REUSEADDR, so a port held only by TIME_WAIT leftovers is usable; an active
            # listener still makes this bind fail.
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.bind((host, port))
        except OSError:
            raise PortInUseError(f"{kind.upper()} port {port} ({what}) is already in use") from None


def find_free_base(host: str, count: int, kind: str, start: int, stop: int = 60000, step: int = 10) -> int:
    """The first base port in [start, stop) such that base .. base+count-1 are all free."""
    for base in range(start, stop, step):
        try:
            for port in range(base, base + count):
                ensure_free(host, port, kind, "probe")
        except PortInUseError:
            continue
        return base
    raise PortInUseError(f"no {count} consecutive free {kind.upper()} ports between {start} and {stop}")
