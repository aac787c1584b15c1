import fcntl
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


@pytest.hookimpl(tryfirst=True)  # before xdist's own hook, which reads the groups
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        if not any(item.get_closest_marker(tier) for tier in HEAVY_TIERS):
            item.add_marker(pytest.mark.unit)
        if any(item.get_closest_marker(tier) for tier in ONE_AT_A_TIME_TIERS):
            item.add_marker(pytest.mark.xdist_group(ONE_AT_A_TIME_GROUP))


# ----- sharing the machine --------------------------------------------------------------------------------------
# `./bootstrap.sh test` runs the heavier tiers on two workers (pytest-xdist, `--dist loadgroup`): a box mission
# uses about 0.7 of the two cores, so two tests fit beside each other, missions included (each has its own ports,
# directories and, in namespaces, its own tagged names). Everything in network namespaces goes to one group, run
# one at a time on one worker: bridges, veths and nftables tables are the kernel's, and a netns test counts what it
# leaves behind. A test marked `alone` (it loads both cores, or measures how fast the machine answers) runs with
# nothing beside it: every heavier test holds a shared lock on one file of the run, an `alone` test holds it
# exclusively. Without xdist nothing is locked.
ONE_AT_A_TIME_TIERS = ("netns",)
ONE_AT_A_TIME_GROUP = "one_at_a_time"


@pytest.fixture(autouse=True)
def _share_the_machine(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    if os.environ.get("PYTEST_XDIST_WORKER") is None or request.node.get_closest_marker("unit") is not None:
        yield
        return
    lock = tmp_path_factory.getbasetemp().parent / "machine.lock"  # the run's directory, shared by its workers
    with open(lock, "a") as held:
        fcntl.flock(held, fcntl.LOCK_EX if request.node.get_closest_marker("alone") else fcntl.LOCK_SH)
        try:
            yield
        finally:
            fcntl.flock(held, fcntl.LOCK_UN)


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
