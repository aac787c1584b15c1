"""The separation manoeuvre on one segment as a pure step function: what a drone does about a nearby drone.

`swarm.agent.flight` flies a segment and, every setpoint period, tells the manoeuvre what it sees (a `Cue`);
`step` says what to do next. The geometry (who is a rival, where the refuge is) stays in `flight`.

    follow --clear--> follow           the way is clear: the carrot advances along the segment
    follow --give_way--> yield         a lower id within the separation distance: step aside until it has passed
    follow --hold_for--> hold          right of way, but a higher id (or a silent or parked drone) is in the way
    follow --held_too_long--> replan   the hold timer, kept through a yield, ran out on the first hold after it
    hold --hold_for--> hold            still in the way, the hold timer running
    hold --held_too_long--> replan     held longer than MAX_YIELD_S: it is not moving off
    hold --clear--> follow             the way is clear again: the hold timer resets (only here)
    hold --give_way--> yield
    yield --way_on_clear--> follow     the peer passed and the straight way on from the refuge is clear
    yield --way_on_blocked--> rejoin   the peer passed: fly the step aside back to where the segment was left
    yield --yield_timed_out--> replan  it had not passed after MAX_YIELD_S
    rejoin --back--> follow            at the segment again, within REJOIN_TOLERANCE_M (the flight back is a
                                       segment of its own, with its own manoeuvre)
    rejoin --not_back--> replan        the flight back was interrupted or gave up
    follow, hold, yield --interrupted--> replan   the mission asked for another path

In replan the segment is given up: `fly_path` returns False and the mission plans again.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

from swarm.agent.lifecycle import IllegalTransition

MAX_YIELD_S = 8.0  # yielding or holding longer than this gives up the path (the mission replans)


class Manoeuvre(StrEnum):
    FOLLOW = "follow"
    HOLD = "hold"
    YIELD = "yield"
    REJOIN = "rejoin"
    REPLAN = "replan"


class Cue(StrEnum):
    CLEAR = "clear"  # no drone to give way to or hold for
    GIVE_WAY = "give_way"  # a live lower id within the separation distance
    HOLD_FOR = "hold_for"  # one we hold for (`Flight._rival`)
    HELD_TOO_LONG = "held_too_long"  # derived by `step` from HOLD_FOR and the hold timer
    WAY_ON_CLEAR = "way_on_clear"
    WAY_ON_BLOCKED = "way_on_blocked"
    YIELD_TIMED_OUT = "yield_timed_out"
    BACK = "back"
    NOT_BACK = "not_back"
    INTERRUPTED = "interrupted"


TRANSITIONS: dict[tuple[Manoeuvre, Cue], Manoeuvre] = {
    (Manoeuvre.FOLLOW, Cue.CLEAR): Manoeuvre.FOLLOW,
    (Manoeuvre.FOLLOW, Cue.GIVE_WAY): Manoeuvre.YIELD,
    (Manoeuvre.FOLLOW, Cue.HOLD_FOR): Manoeuvre.HOLD,
    (Manoeuvre.FOLLOW, Cue.HELD_TOO_LONG): Manoeuvre.REPLAN,
    (Manoeuvre.FOLLOW, Cue.INTERRUPTED): Manoeuvre.REPLAN,
    (Manoeuvre.HOLD, Cue.HOLD_FOR): Manoeuvre.HOLD,
    (Manoeuvre.HOLD, Cue.HELD_TOO_LONG): Manoeuvre.REPLAN,
    (Manoeuvre.HOLD, Cue.CLEAR): Manoeuvre.FOLLOW,
    (Manoeuvre.HOLD, Cue.GIVE_WAY): Manoeuvre.YIELD,
    (Manoeuvre.HOLD, Cue.INTERRUPTED): Manoeuvre.REPLAN,
    (Manoeuvre.YIELD, Cue.WAY_ON_CLEAR): Manoeuvre.FOLLOW,
    (Manoeuvre.YIELD, Cue.WAY_ON_BLOCKED): Manoeuvre.REJOIN,
    (Manoeuvre.YIELD, Cue.YIELD_TIMED_OUT): Manoeuvre.REPLAN,
    (Manoeuvre.YIELD, Cue.INTERRUPTED): Manoeuvre.REPLAN,
    (Manoeuvre.REJOIN, Cue.BACK): Manoeuvre.FOLLOW,
    (Manoeuvre.REJOIN, Cue.NOT_BACK): Manoeuvre.REPLAN,
}


@dataclass(frozen=True)
class Separation:
    """The manoeuvre on a segment, and since when the drone holds (None: not holding since the way was last
    clear; a yield in between does not reset it)."""

    manoeuvre: Manoeuvre = Manoeuvre.FOLLOW
    held_since: float | None = None


def step(state: Separation, cue: Cue, now: float, max_hold_s: float = MAX_YIELD_S) -> Separation:
    """The manoeuvre after `cue` at time `now`; raises IllegalTransition for a cue that cannot come in this
    manoeuvre (a bug in the caller)."""
    held_since = state.held_since
    if cue == Cue.HOLD_FOR:
        held_since = now if held_since is None else held_since
        if now - held_since > max_hold_s:
            cue = Cue.HELD_TOO_LONG
    elif cue == Cue.CLEAR:
        held_since = None
    following = TRANSITIONS.get((state.manoeuvre, cue))
    if following is None:
        raise IllegalTransition(f"separation {state.manoeuvre} --{cue}-->")
    return Separation(following, held_since)
