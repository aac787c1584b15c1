"""The telemetry watchdog counts only the silence the agent was awake to hear: a stall of its own process (SIGSTOP,
CPU starvation, a blocked loop) is no evidence of a lost link, while a link that stops while the agent listens is
judged lost after the telemetry timeout, as before."""

from __future__ import annotations

import asyncio
import time
from types import SimpleNamespace

import pytest

from swarm.agent.flight import Flight, TelemetryLost
from swarm.agent.watchdog import LATE_AFTER_S, LOOP_PERIOD_S, DeafTime, LoopMonitor
from swarm.config import load_config


def test_deaf_time_after_the_last_sample_is_taken_off_the_silence() -> None:
    deaf = DeafTime()
    deaf.add(10.0, 12.5)  # the loop did not run from 10 to 12.5 s
    monitor = LoopMonitor(clock=lambda: 0.0)
    monitor.deaf = deaf
    assert monitor.heard_silence(13.0, 9.5) == pytest.approx(1.0)  # 3.5 s old, 2.5 s of it unheard
    assert monitor.heard_silence(13.0, 11.0) == pytest.approx(0.5)  # only the part after the sample counts
    assert monitor.heard_silence(13.0, 12.8) == pytest.approx(0.2)
    assert monitor.heard_silence(16.0, 9.5) == pytest.approx(4.0)  # listening again: the silence grows


def test_wake_ups_a_little_late_count_as_listening() -> None:
    monitor = LoopMonitor(clock=lambda: 0.0)
    monitor.note(due=1.0, woke=1.0 + LATE_AFTER_S * 0.9)
    assert monitor.heard_silence(3.0, 0.5) == pytest.approx(2.5)
    monitor.note(due=3.0, woke=4.0)
    assert monitor.heard_silence(4.5, 0.5) == pytest.approx(3.0)
    assert monitor.worst_late_s == pytest.approx(1.0)


async def test_a_blocked_loop_is_deaf_even_before_the_monitor_wakes_to_record_it() -> None:
    monitor = LoopMonitor()
    task = asyncio.create_task(monitor.run())
    try:
        await asyncio.sleep(3 * LOOP_PERIOD_S)
        sample = time.monotonic()
        time.sleep(0.8)  # the loop does not run, as if the process were stopped or starved
        # asked at once on waking, before the monitor's own wake-up: the overdue time is deaf already
        assert monitor.heard_silence(time.monotonic(), sample) < 0.3
        await asyncio.sleep(3 * LOOP_PERIOD_S)
        recorded = monitor.heard_silence(time.monotonic(), sample)
        assert recorded < 0.5, "the stall was counted as silence"
        assert monitor.worst_late_s > 0.5
        await asyncio.sleep(0.5)
        assert monitor.heard_silence(time.monotonic(), sample) > recorded + 0.4, "listening time was not counted"
    finally:
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)


def _airborne_flight(last_sample: float) -> Flight:
    """Only what `_check` reads: an airborne drone whose last position sample came at `last_sample`."""
    telemetry = SimpleNamespace(updated=last_sample)
    ap = SimpleNamespace(
        telemetry=telemetry, telemetry_age_s=time.monotonic() - last_sample, taken_over_by=lambda: None
    )
    flight = Flight(ap, load_config().agent, lambda *a, **k: None)  # type: ignore[arg-type]
    flight.airborne = True
    return flight


def test_telemetry_silent_while_the_agent_listened_is_lost() -> None:
    flight = _airborne_flight(time.monotonic() - 2.0)  # 2 s old, timeout 1.5 s, the loop ran all along
    with pytest.raises(TelemetryLost, match="no position telemetry for 2.0 s"):
        flight._check(asyncio.Event())


def test_telemetry_that_went_unheard_while_the_agent_was_stalled_is_not_lost() -> None:
    now = time.monotonic()
    flight = _airborne_flight(now - 2.0)
    flight.loop_monitor.note(due=now - 1.9, woke=now - 0.2)  # stalled for 1.7 s of those 2
    events: list[tuple[str, dict]] = []
    flight.log = lambda event, **fields: events.append((event, fields))  # type: ignore[method-assign]
    flight._check(asyncio.Event())
    assert [e for e, _ in events] == ["telemetry_gap_unheard"]
    assert events[0][1]["heard"] < 0.5
