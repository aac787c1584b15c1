import os
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.helpers import SwarmPorts, free_swarm_ports


@pytest.fixture
def swarm_ports() -> SwarmPorts:
    return free_swarm_ports()


@pytest.fixture(scope="session", autouse=True)
def matplotlib_font_cache() -> None:
    """Matplotlib builds its font cache on first use by running fc-list: build it before unit tests refuse processes
    (on a fresh machine the first plotting unit test would otherwise fail)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.font_manager  # noqa: F401  (builds or loads the cache at import)


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


# ----- test tiers ------------------------------------------------------------------------------------------------
# Every test has one tier (pyproject.toml registers them). A test marked with none of the heavier tiers is `unit`,
# and a unit test is held to it: it may not bind, connect or send on a socket, start a process or open a Zenoh
# session (the guard below turns each into a failure that names the tier to mark it with). `pytest -m unit` is
# the seconds-long tier to run while iterating; `./bootstrap.sh test` runs it first and stops on its failure.
HEAVY_TIERS = ("fuzz", "bus", "sim", "mission", "netns", "ros2")


class UnitTestDidIO(AssertionError):
    pass


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        if not any(item.get_closest_marker(tier) for tier in HEAVY_TIERS):
            item.add_marker(pytest.mark.unit)


@pytest.fixture(autouse=True)
def _unit_tests_do_no_io(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> None:
    if request.node.get_closest_marker("unit") is None:
        return
    import socket
    import subprocess

    import zenoh

    def refuse(what: str):  # type: ignore[no-untyped-def]
        def refused(*args, **kwargs):  # type: ignore[no-untyped-def]
            raise UnitTestDidIO(f"a unit test may not {what}: mark it with its tier ({', '.join(HEAVY_TIERS)})")

        return refused

    for method in ("bind", "connect", "connect_ex", "sendto"):
        monkeypatch.setattr(socket.socket, method, refuse(f"{method} a socket"))
    monkeypatch.setattr(subprocess.Popen, "__init__", refuse("start a process"))
    monkeypatch.setattr(zenoh, "open", refuse("open a Zenoh session"))
