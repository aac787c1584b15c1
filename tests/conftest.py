import pytest

from tests.helpers import SwarmPorts, free_swarm_ports


@pytest.fixture
def swarm_ports() -> SwarmPorts:
    return free_swarm_ports()
