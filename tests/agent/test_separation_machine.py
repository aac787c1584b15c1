"""The separation manoeuvre's step function: every transition of its table, the hold timer, and what is refused.
(The manoeuvre flown against another drone in the simulator: tests/agent/test_separation.py.)"""

from __future__ import annotations

from itertools import product

import pytest

from swarm.agent.lifecycle import IllegalTransition
from swarm.agent.separation import MAX_YIELD_S, TRANSITIONS, Cue, Manoeuvre, Separation, step

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
