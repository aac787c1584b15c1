import pytest

from swarm.sim.worlds import World, load_world
from tests.sim.support import free_port_block


@pytest.fixture
def port_base() -> int:
    """The base of a block of free loopback UDP ports (vehicle ports at base, GCS ports at base + 20)."""
    return free_port_block()


@pytest.fixture(scope="session")
def box_world() -> World:
    return load_world("box")


@pytest.fixture(scope="session")
def office_world() -> World:
    return load_world("office")
