"""Children of `swarm run` at the niceness asked for (`mission.sim_nice`, `mission.agent_nice`), read back from
the kernel, threads included."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

from swarm.mission.processes import start_child

pytestmark = pytest.mark.sim

THREAD_NICENESS = (
    "import os, threading\nthreading.Thread(target=lambda: print(os.getpriority(os.PRIO_PROCESS, 0))).start()\n"
)


def test_a_child_and_the_threads_it_starts_run_at_the_niceness_asked_and_the_child_says_which_it_got(
    tmp_path: Path,
) -> None:
    # raising niceness is always permitted, so this holds with or without root
    asked = min(19, os.getpriority(os.PRIO_PROCESS, 0) + 3)
    child = start_child("probe", [sys.executable, "-c", THREAD_NICENESS], tmp_path / "probe.log", nice=asked)
    assert child.nice == asked
    assert child.popen.wait(timeout=10) == 0
    child.stop(1.0)  # closes its log
    assert int((tmp_path / "probe.log").read_text()) == asked


def test_a_child_asked_for_nothing_keeps_the_harness_niceness(tmp_path: Path) -> None:
    child = start_child("probe", [sys.executable, "-c", "pass"], tmp_path / "probe.log")
    assert child.nice == os.getpriority(os.PRIO_PROCESS, 0)
    assert child.popen.wait(timeout=10) == 0
    child.stop(1.0)  # closes its log
