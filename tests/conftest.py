import os
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.helpers import SwarmPorts, free_swarm_ports


@pytest.fixture
def swarm_ports() -> SwarmPorts:
    return free_swarm_ports()


@pytest.fixture(scope="session", autouse=True)
def mavsdk_temp_dirs(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """MAVSDK makes a temporary directory per vehicle it meets and never removes it: the flight tests' (MAVSDK in
    this process, and the processes it starts) go to pytest's temporary tree, which pytest prunes, not /tmp."""
    tmp = tmp_path_factory.mktemp("mavsdk")
    before = os.environ.get("TMPDIR")
    os.environ["TMPDIR"] = str(tmp)
    yield tmp
    if before is None:
        os.environ.pop("TMPDIR", None)
    else:
        os.environ["TMPDIR"] = before
