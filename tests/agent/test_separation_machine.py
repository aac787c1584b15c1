"""The separation manoeuvre's step function: every transition of its table, the hold timer, and what is refused.
(The manoeuvre flown against another drone in the simulator: tests/agent/test_separation.py.)"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from itertools import product

import pytest

import swarm.agent.flight as flight_module
from swarm.agent.flight import Flight, Neighbour
from swarm.agent.lifecycle import IllegalTransition
from swarm.agent.separation import MAX_YIELD_S, TRANSITIONS, Cue, Manoeuvre, Separation, step
from swarm.config import Vec3, load_config
from tests.agent.fake_autopilot import FakeAutopilot

pytestmark = pytest.mark.unit

M = Manoeuvre
LONG_AGO = -2 * MAX_YIELD_S  # a hold timer started this long before t = 0 has run out
# Every transition of the table: the manoeuvre, the hold timer, the cue at t = 0, and what follows.
TESTED: dict[tuple[Manoeuvre, Cue], tuple[float | None, Cue, Manoeuvre]] = {
    (M.FOLLOW, Cue.CLEAR): (None, Cue.CLEAR, M.FOLLOW),
    (M.FOLLOW, Cue.GIVE_WAY): (None, Cue.GIVE_WAY, M.YIELD),
    (M.FOLLOW, Cue.HOLD_FOR): (None, Cue.HOLD_FOR, M.HOLD),
    # back on the segment after a yield, with the hold timer from before it: the next hold is too long
    (M.FOLLOW, Cue.HELD_TOO_LONG): (LONG_AGO, Cue.HOLD_FOR, M.REPLAN),
    (M.FOLLOW, Cue.INTERRUPTED): (None, Cue.INTERRUPTED, M.REPLAN),
    (M.HOLD, Cue.HOLD_FOR): (-1.0, Cue.HOLD_FOR, M.HOLD),
    (M.HOLD, Cue.HELD_TOO_LONG): (LONG_AGO, Cue.HOLD_FOR, M.REPLAN),
    (M.HOLD, Cue.CLEAR): (-1.0, Cue.CLEAR, M.FOLLOW),
    (M.HOLD, Cue.GIVE_WAY): (-1.0, Cue.GIVE_WAY, M.YIELD),
    (M.HOLD, Cue.INTERRUPTED): (-1.0, Cue.INTERRUPTED, M.REPLAN),
    (M.YIELD, Cue.WAY_ON_CLEAR): (None, Cue.WAY_ON_CLEAR, M.FOLLOW),
    (M.YIELD, Cue.WAY_ON_BLOCKED): (None, Cue.WAY_ON_BLOCKED, M.REJOIN),
    (M.YIELD, Cue.YIELD_TIMED_OUT): (None, Cue.YIELD_TIMED_OUT, M.REPLAN),
    (M.YIELD, Cue.INTERRUPTED): (None, Cue.INTERRUPTED, M.REPLAN),
    (M.REJOIN, Cue.BACK): (None, Cue.BACK, M.FOLLOW),
    (M.REJOIN, Cue.NOT_BACK): (None, Cue.NOT_BACK, M.REPLAN),
}


@pytest.mark.parametrize("transition", list(TESTED), ids=lambda t: f"{t[0]}-{t[1]}")
def test_the_manoeuvre_takes_the_transition(transition: tuple[Manoeuvre, Cue]) -> None:
    manoeuvre, _ = transition
    held_since, cue, following = TESTED[transition]
    assert TRANSITIONS[transition] == following
    assert step(Separation(manoeuvre, held_since), cue, 0.0).manoeuvre == following


def test_every_transition_of_the_table_is_tested_and_no_other() -> None:
    assert set(TRANSITIONS) == set(TESTED)


def test_only_replan_is_final() -> None:
    assert {m for m in Manoeuvre if not any(start == m for start, _ in TRANSITIONS)} == {M.REPLAN}


@pytest.mark.parametrize(
    "manoeuvre, cue", [(m, c) for m, c in product(Manoeuvre, Cue) if (m, c) not in TRANSITIONS], ids=lambda v: str(v)
)
def test_a_cue_that_cannot_come_in_the_manoeuvre_is_refused(manoeuvre: Manoeuvre, cue: Cue) -> None:
    with pytest.raises(IllegalTransition):
        step(Separation(manoeuvre), cue, 0.0)


def test_a_hold_gives_the_segment_up_only_after_max_yield_s() -> None:
    state = step(Separation(), Cue.HOLD_FOR, 100.0)
    assert state == Separation(M.HOLD, 100.0)
    state = step(state, Cue.HOLD_FOR, 100.0 + MAX_YIELD_S)
    assert state == Separation(M.HOLD, 100.0)  # at the limit: still holding
    assert step(state, Cue.HOLD_FOR, 100.0 + MAX_YIELD_S + 0.1).manoeuvre == M.REPLAN


def test_the_hold_timer_resets_only_when_the_way_is_clear() -> None:
    held = step(Separation(), Cue.HOLD_FOR, 0.0)
    assert step(held, Cue.CLEAR, 1.0) == Separation(M.FOLLOW, None)
    yielding = step(held, Cue.GIVE_WAY, 1.0)
    assert yielding == Separation(M.YIELD, 0.0)
    rejoining = step(yielding, Cue.WAY_ON_BLOCKED, 5.0)
    back = step(rejoining, Cue.BACK, 7.0)
    assert back == Separation(M.FOLLOW, 0.0)  # the timer started before the yield still runs
    assert step(back, Cue.HOLD_FOR, MAX_YIELD_S + 1.0).manoeuvre == M.REPLAN
    assert step(step(back, Cue.CLEAR, 8.0), Cue.HOLD_FOR, MAX_YIELD_S + 1.0).manoeuvre == M.HOLD


# -- flown by Flight (a fake autopilot that is wherever its setpoint puts it) ----------------------------------

Transition = tuple[Manoeuvre, Cue, Manoeuvre]
START, GOAL = (0.0, 0.0, 1.5), (1.0, 0.0, 1.5)


def _fly_segment(
    ap: FakeAutopilot,
    own_id: int,
    neighbours: Callable[[], list[Neighbour]],
    monkeypatch: pytest.MonkeyPatch,
    is_clear: Callable[[Vec3, Vec3], bool] = lambda a, b: True,
    max_hold_s: float = MAX_YIELD_S,
) -> tuple[bool, set[Transition], list[str]]:
    """Fly from START to GOAL among `neighbours`; whether it arrived, the manoeuvre's transitions and the log
    events."""
    taken: set[Transition] = set()

    def recorded(state: Separation, cue: Cue, now: float) -> Separation:
        following = step(state, cue, now, max_hold_s)
        taken.add((state.manoeuvre, cue, following.manoeuvre))
        return following

    monkeypatch.setattr(flight_module, "step", recorded)
    events: list[str] = []
    settings = load_config().agent.model_copy(update={"id": own_id})
    log = lambda event, **fields: events.append(event)  # noqa: E731
    flight = Flight(ap, settings, log, separation_m=1.2, neighbours=neighbours, is_clear=is_clear)  # type: ignore[arg-type]
    flight.airborne = True
    arrived = asyncio.run(flight.fly_path([GOAL], asyncio.Event()))
    return arrived, taken, events


def _off_the_segment(p: Vec3) -> bool:
    return abs(p[1]) > 0.05 or abs(p[2] - START[2]) > 0.05


def _passes_once_given_way(ap: FakeAutopilot, peer: Neighbour) -> Callable[[], list[Neighbour]]:
    """`peer`, until the drone has stepped off its segment: then it has passed, and is gone."""
    return lambda: [] if any(_off_the_segment(p) for p in ap.visited) else [peer]


LOWER = Neighbour(1, (0.8, 0.0, 1.5), (-0.5, 0.0, 0.0), heading_to=(-3.0, 0.0, 1.5))  # coming head on


def test_flown_a_drone_in_the_way_is_held_for_until_the_hold_times_out(monkeypatch: pytest.MonkeyPatch) -> None:
    ap = FakeAutopilot(in_air=True)
    higher = Neighbour(2, (0.8, 0.0, 1.5), (0.0, 0.0, 0.0), heading_to=(0.8, 5.0, 1.5))
    arrived, taken, events = _fly_segment(ap, 1, lambda: [higher], monkeypatch, max_hold_s=0.3)
    assert not arrived and "blocked_by" in events
    assert taken == {
        (M.FOLLOW, Cue.HOLD_FOR, M.HOLD),
        (M.HOLD, Cue.HOLD_FOR, M.HOLD),
        (M.HOLD, Cue.HOLD_FOR, M.REPLAN),  # HOLD_FOR after max_hold_s: held too long
    }
    assert all(p[0] < 0.05 for p in ap.visited)  # held where it was


def test_flown_a_drone_gives_way_then_goes_on_from_the_refuge_when_the_way_on_is_clear(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    ap = FakeAutopilot(in_air=True)
    arrived, taken, events = _fly_segment(ap, 2, _passes_once_given_way(ap, LOWER), monkeypatch)
    assert arrived and "give_way" in events
    assert {(M.FOLLOW, Cue.GIVE_WAY, M.YIELD), (M.YIELD, Cue.WAY_ON_CLEAR, M.FOLLOW)} <= taken
    assert not any(M.REJOIN in (a, b) for a, _, b in taken)
    assert ap.visited[-1] == pytest.approx(GOAL)


def test_flown_a_drone_gives_way_then_flies_back_to_its_segment_when_the_way_on_is_blocked(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    ap = FakeAutopilot(in_air=True)
    blocked_on = lambda a, b: not (_off_the_segment(a) and b == GOAL)  # noqa: E731
    arrived, taken, events = _fly_segment(ap, 2, _passes_once_given_way(ap, LOWER), monkeypatch, blocked_on)
    assert arrived and "give_way" in events
    assert {(M.YIELD, Cue.WAY_ON_BLOCKED, M.REJOIN), (M.REJOIN, Cue.BACK, M.FOLLOW)} <= taken
    refuge = next(i for i, p in enumerate(ap.visited) if _off_the_segment(p))
    back = next(i for i in range(refuge, len(ap.visited)) if not _off_the_segment(ap.visited[i]))
    assert ap.visited[back][0] < GOAL[0] and ap.visited[-1] == pytest.approx(GOAL)  # back on it, then along it
