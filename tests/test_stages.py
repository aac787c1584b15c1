"""`StageClock`: what each stage of an agent costs, from every thread, in a bounded memory."""

from __future__ import annotations

import threading

import pytest

from swarm.stages import NO_CLOCK, RECENT, StageClock


def test_each_stage_counts_its_calls_total_median_and_worst() -> None:
    clock = StageClock()
    for seconds in (0.001, 0.002, 0.010):
        clock.record("integrate", seconds)
    clock.record("planning", 0.5)
    summary = clock.summary()
    assert list(summary) == ["integrate", "planning"]
    assert summary["integrate"] == {"calls": 3, "total_ms": 13.0, "p50_ms": 2.0, "max_ms": 10.0}
    assert summary["planning"]["calls"] == 1


def test_a_block_that_raises_is_timed_too() -> None:
    clock = StageClock()
    with pytest.raises(ValueError), clock.measure("planning"):
        raise ValueError("no path")
    with clock.measure("planning"):
        pass
    assert clock.summary()["planning"]["calls"] == 2


def test_the_median_is_over_the_recent_calls_and_the_worst_over_all() -> None:
    clock = StageClock()
    clock.record("fuse_patch", 1.0)  # an early slow call
    for _ in range(RECENT):
        clock.record("fuse_patch", 0.001)
    stage = clock.summary()["fuse_patch"]
    assert stage["p50_ms"] == 1.0 and stage["max_ms"] == 1000.0 and stage["calls"] == RECENT + 1


def test_threads_record_without_losing_calls() -> None:
    clock = StageClock()

    def work() -> None:
        for _ in range(1000):
            clock.record("integrate", 0.001)

    threads = [threading.Thread(target=work) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert clock.summary()["integrate"]["calls"] == 4000


def test_the_disabled_clock_records_nothing() -> None:
    with NO_CLOCK.measure("integrate"):
        pass
    NO_CLOCK.record("integrate", 1.0)
    assert NO_CLOCK.summary() == {}
