"""The whole-map baseline (what sending the whole fused map every exploration loop would cost) is measured every
few loops; the loops in between count at sizes interpolated between the measurements."""

from __future__ import annotations

import threading

import pytest

from swarm.agent.mapping import BASELINE_SAMPLE_LOOPS, baseline_interval, interpolated_bytes

pytestmark = pytest.mark.unit


def test_loops_between_measurements_count_on_the_line_between_them() -> None:
    assert interpolated_bytes(0, 500, 5) == 100 + 200 + 300 + 400 + 500
    assert interpolated_bytes(1000, 1000, 4) == 4000  # a map that stopped growing counts its size every loop
    assert interpolated_bytes(200, 700, 1) == 700  # measured every loop: the measurement itself


def test_no_loop_is_no_bytes() -> None:
    assert interpolated_bytes(300, 900, 0) == 0


def test_a_growing_map_sampled_every_five_loops_is_close_to_measuring_every_loop() -> None:
    sizes = [int(1000 * k**1.5) for k in range(1, 31)]  # a map growing faster than linearly, one size per loop
    every_loop = sum(sizes)
    sampled, previous = 0, 0
    for end in range(5, 31, 5):
        sampled += interpolated_bytes(previous, sizes[end - 1], 5)
        previous = sizes[end - 1]
    assert abs(sampled - every_loop) / every_loop < 0.05


def test_the_map_is_measured_after_1_2_4_8_16_loops_then_every_sample_interval() -> None:
    counted, at = 0, []
    while counted < 100:
        counted += baseline_interval(counted)
        at.append(counted)
    assert at[:7] == [1, 2, 4, 8, 16, 32, 32 + BASELINE_SAMPLE_LOOPS] and BASELINE_SAMPLE_LOOPS == 20


def test_a_map_that_grows_fast_then_slowly_sampled_that_way_is_understated_and_close() -> None:
    sizes = [int(50_000 * (1 - 0.9 ** (k + 1))) for k in range(120)]  # one size per loop: quick, then levelling
    every_loop = sum(sizes)
    sampled, previous, counted = 0, 0, 0
    while counted < len(sizes):
        step = min(baseline_interval(counted), len(sizes) - counted)
        counted += step
        sampled += interpolated_bytes(previous, sizes[counted - 1], step)
        previous = sizes[counted - 1]
    assert sampled <= every_loop and (every_loop - sampled) / every_loop < 0.05


def test_the_decision_thread_runs_nicer_than_the_mapping_thread() -> None:
    """When the cores are short, frames go first: a slow decision must not cost camera frames."""
    import os
    from concurrent.futures import ThreadPoolExecutor

    from swarm.agent.mapping import DECISION_NICENESS, _yield_to_frames

    def own_niceness() -> int:
        return os.getpriority(os.PRIO_PROCESS, threading.get_native_id())

    with ThreadPoolExecutor(1) as plain, ThreadPoolExecutor(1, initializer=_yield_to_frames) as decider:
        mapping, decision = plain.submit(own_niceness).result(), decider.submit(own_niceness).result()
    assert decision == min(mapping + DECISION_NICENESS, 19) > mapping
    assert own_niceness() == mapping  # the process and its other threads keep theirs
