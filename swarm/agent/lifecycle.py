"""The agent's lifecycle as data: which flight phase may follow which, and the process stages around the flight.

Flight phases (`swarm.bus.phase.Phase`, what the heartbeat says) change only in `Flight._set_phase`, through
`transition`. `ALLOWED` is exactly what `swarm.agent.flight` does:

- connecting -> ready (autopilot connected and healthy) | failed (it did not connect or get healthy)
- ready -> takeoff | landed (a stop request before take-off: nothing to land) | failed (a flight error on the
  ground)
- takeoff -> flying (take-off altitude reached, or a restarted agent resumed a drone already in the air)
  | landing (a stop request or a flight error once airborne) | failsafe (telemetry lost) | failed (arming or the
  take-off command failed: still on the ground)
- flying -> hovering (the mission is over and `hover_s` > 0) | returning (the battery ran low) | landing
  | failsafe
- hovering -> returning (the battery ran low) | landing | failsafe
- returning -> landing (home, or no way there: it lands where it is) | failsafe
- landing -> landed | failed (the landing could not be commanded or seen through)
- landed, failsafe, failed: final (a failsafe landing that telemetry confirms later stays failsafe)

Landing and failsafe are the safe way down and must never be held up by bookkeeping: an illegal transition is a
bug in the flight code, so `transition` raises, and `Flight._set_phase` logs it loudly (`illegal_transition`)
and takes the phase anyway, so the heartbeat says what the drone does. The unit tests hold the table to the code.

The way home at the end of the mission is flown in phase flying (the exploration flies the drone back above its
take-off point, `Exploration._return`; a route ends where it ends): the cluster is done by then. A low battery
ends the mission early: the way home is flown in phase returning, which takes the drone out of its cluster
(`swarm.bus.phase.RETIRED_PHASES`), so the others' leader gives its targets to them, and a returning lowest id
hands the leadership on; then the drone lands. Lingering and exit come after the flight, while
the heartbeat keeps the final phase (a lingering agent's says landed); they are process `Stage`s of
`swarm.agent.main.Agent`.
"""

from __future__ import annotations

from enum import StrEnum

from swarm.bus.phase import Phase


class IllegalTransition(ValueError):
    """A change of phase or stage the lifecycle does not allow."""


ALLOWED: dict[Phase, frozenset[Phase]] = {
    Phase.CONNECTING: frozenset({Phase.READY, Phase.FAILED}),
    Phase.READY: frozenset({Phase.TAKEOFF, Phase.LANDED, Phase.FAILED}),
    Phase.TAKEOFF: frozenset({Phase.FLYING, Phase.LANDING, Phase.FAILSAFE, Phase.FAILED}),
    Phase.FLYING: frozenset({Phase.HOVERING, Phase.RETURNING, Phase.LANDING, Phase.FAILSAFE}),
    Phase.HOVERING: frozenset({Phase.RETURNING, Phase.LANDING, Phase.FAILSAFE}),
    Phase.RETURNING: frozenset({Phase.LANDING, Phase.FAILSAFE}),
    Phase.LANDING: frozenset({Phase.LANDED, Phase.FAILED}),
    Phase.LANDED: frozenset(),
    Phase.FAILSAFE: frozenset(),
    Phase.FAILED: frozenset(),
}
FINAL_PHASES = frozenset(p for p, following in ALLOWED.items() if not following)  # what Flight.run returns


def transition(current: Phase, wanted: Phase) -> Phase:
    """The phase after `current` when the flight asks for `wanted` (staying is no change); raises
    IllegalTransition when the lifecycle does not allow it."""
    if wanted == current:
        return current
    if wanted not in ALLOWED.get(current, frozenset()):
        raise IllegalTransition(f"phase {current} -> {wanted}")
    return wanted


class Stage(StrEnum):
    """Where the agent process is: flying (`Flight.run`, the phases above), then lingering on the bus after a
    normal landing until the swarm holds one map (not after a stop request, nor without map sharing), then
    exiting (last heartbeat, summary, bus closed)."""

    FLIGHT = "flight"
    LINGERING = "lingering"
    EXITING = "exiting"


STAGES_ALLOWED: dict[Stage, frozenset[Stage]] = {
    Stage.FLIGHT: frozenset({Stage.LINGERING, Stage.EXITING}),
    Stage.LINGERING: frozenset({Stage.EXITING}),
    Stage.EXITING: frozenset(),
}


def next_stage(current: Stage, wanted: Stage) -> Stage:
    """The stage after `current`; raises IllegalTransition when the process cannot go there from it."""
    if wanted not in STAGES_ALLOWED[current]:
        raise IllegalTransition(f"stage {current} -> {wanted}")
    return wanted
