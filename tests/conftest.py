import fcntl
import os
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
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


# ----- sharing the machine --------------------------------------------------------------------------------------
# `./bootstrap.sh test` runs the heavier tiers on two workers (pytest-xdist, `-n 2`): a box mission uses about 0.7
# of the two cores, so two tests fit beside each other, missions included (each has its own ports and
# directories). Two kinds of test may not, and wait on a lock file of the run (flock, which the kernel releases
# when a worker dies):
# - a test that changes the machine's network (marked netns or containers: namespaces, bridges, veths, nftables
#   tables, Podman's networks, all the kernel's, and those tests count what is left behind) holds `network.lock`:
#   one such test at a time;
# - a test marked `alone` (it loads both cores, or measures how fast the machine answers) holds `machine.lock`
#   exclusively; every other heavier test holds it shared, so nothing runs beside an `alone` test.
# (xdist's own `--dist loadgroup` would place the network tests on one worker, but with pytest 9 it groups nothing:
# it renames `item._nodeid`, which pytest 9 no longer reads.) Without xdist nothing is locked.
ONE_AT_A_TIME_MARKS = ("netns", "containers")


@pytest.fixture(autouse=True)
def _share_the_machine(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    if os.environ.get("PYTEST_XDIST_WORKER") is None or request.node.get_closest_marker("unit") is not None:
        yield
        return
    run_dir = tmp_path_factory.getbasetemp().parent  # shared by the run's workers
    network = any(request.node.get_closest_marker(mark) for mark in ONE_AT_A_TIME_MARKS)
    alone = request.node.get_closest_marker("alone") is not None
    with ExitStack() as held:  # the network lock first: a test waiting for it holds nothing an `alone` test needs
        if network:
            held.enter_context(_flock(run_dir / "network.lock", fcntl.LOCK_EX))
        held.enter_context(_flock(run_dir / "machine.lock", fcntl.LOCK_EX if alone else fcntl.LOCK_SH))
        yield


@contextmanager
def _flock(path: Path, mode: int) -> Iterator[None]:
    with open(path, "a") as lock:
        fcntl.flock(lock, mode)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


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
