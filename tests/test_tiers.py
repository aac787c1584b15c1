"""The unit tier holds its tests to no I/O (tests/conftest.py): each kind of I/O it refuses, refused."""

from __future__ import annotations

import socket
import subprocess

import pytest
import zenoh

from tests.conftest import UnitTestDidIO


def test_a_unit_test_can_bind_no_socket_start_no_process_and_open_no_zenoh_session() -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as udp, pytest.raises(UnitTestDidIO, match="bind"):
        udp.bind(("127.0.0.1", 0))
    with socket.socket() as tcp, pytest.raises(UnitTestDidIO, match="connect"):
        tcp.connect(("127.0.0.1", 9))
    with pytest.raises(UnitTestDidIO, match="start a process"):
        subprocess.run(["true"], check=True)
    with pytest.raises(UnitTestDidIO, match="Zenoh"):
        zenoh.open(zenoh.Config())


@pytest.mark.bus
def test_a_test_of_a_heavier_tier_may() -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as udp:
        udp.bind(("127.0.0.1", 0))
        assert udp.getsockname()[1] > 0
