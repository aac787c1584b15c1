"""The carrot a path is flown by (`swarm.agent.flight.carried_lead`): pure geometry; the flights are in
`test_fly_path.py`."""

from __future__ import annotations

import numpy as np
import pytest

from swarm.agent.flight import (
    CORNER_CUT_M,
    GENTLE_TURN_DEG,
    LOOKAHEAD_M,
    LOOKAHEAD_NEAR_M,
    LOOKAHEAD_OPEN_M,
    LOOKAHEAD_TAPER_M,
    REST_S,
    SLOW_M_S,
    Flight,
    carried_lead,
    carrot_may_advance,
    gentle_turns,
    lookahead_before,
    still_since,
)
from swarm.config import Vec3, load_config
from tests.agent.fake_autopilot import FakeAutopilot


def test_a_new_carrot_keeps_the_old_ones_lead_in_the_new_direction() -> None:
    here = (0.0, 0.0, 1.5)
    assert carried_lead(here, None, (5.0, 0.0, 1.5)) == 0.0
    assert carried_lead(here, (0.8, 0.0, 1.5), (5.0, 0.0, 1.5)) == pytest.approx(0.8)  # straight on
    assert carried_lead(here, (0.8, 0.0, 1.5), (5.0, 5.0, 1.5)) == pytest.approx(0.8 / np.sqrt(2))  # 45 degrees
    assert carried_lead(here, (0.8, 0.0, 1.5), (-5.0, 0.0, 1.5)) == 0.0  # a U-turn starts at the drone
    assert carried_lead(here, (0.8, 0.0, 1.5), (0.3, 0.0, 1.5)) == pytest.approx(0.3)  # within the segment
    assert carried_lead(here, (2.0, 0.0, 1.5), (5.0, 0.0, 1.5)) == pytest.approx(LOOKAHEAD_OPEN_M)  # the look-ahead
    assert carried_lead(here, (2.0, 0.0, 1.5), (1.2, 0.0, 1.5)) == pytest.approx(LOOKAHEAD_M)  # nearer its end


def test_the_carrot_waits_for_a_drone_that_is_off_its_segment_after_a_corner() -> None:
    start, target = np.array([10.7, 6.9, 1.5]), np.array([11.7, 6.9, 1.5])  # the level way through a door
    carrot = np.array([10.8, 6.9, 1.5])
    moving, at_rest = 0.0, REST_S  # seconds at rest
    above_the_corner = np.array([10.6, 6.9, 1.75])  # 0.25 m above the segment, still coming down
    assert not carrot_may_advance(above_the_corner, moving, carrot, start, target)
    on_the_segment = np.array([10.75, 6.9, 1.56])
    assert carrot_may_advance(on_the_segment, moving, carrot, start, target)
    # at rest off the segment: it will get no closer, so the segment goes on rather than stalling
    assert carrot_may_advance(above_the_corner, at_rest, carrot, start, target)
    # ... but not at the moment it turns back (it passes through rest), nor before it has rested REST_S
    assert not carrot_may_advance(above_the_corner, 0.1, carrot, start, target)
    far_behind = np.array([9.7, 6.9, 1.5])  # on the line, but the carrot is a look-ahead away
    assert not carrot_may_advance(far_behind, at_rest, carrot, start, target)


def test_a_drone_is_at_rest_from_when_it_slowed_down_until_it_moves_again() -> None:
    slow, fast = np.array([0.0, SLOW_M_S / 2, 0.0]), np.array([0.0, 0.0, -2 * SLOW_M_S])
    assert still_since(None, fast, 10.0) is None
    assert still_since(None, slow, 10.0) == 10.0  # came to rest now
    assert still_since(10.0, slow, 10.4) == 10.0  # ... and has stayed so
    assert still_since(10.0, fast, 10.5) is None  # moving again (climbing counts)


def test_the_carrot_runs_on_for_a_drone_short_of_a_waypoint_on_the_straight_way_on() -> None:
    start, target = np.array([2.0, 0.0, 1.5]), np.array([4.0, 0.0, 1.5])
    short_of_it = np.array([1.75, 0.02, 1.5])  # within the waypoint tolerance, not yet at the waypoint
    assert carrot_may_advance(short_of_it, 0.0, start, start, target)
    short_of_a_right_angle = np.array([2.0, -0.25, 1.5])  # coming along y to turn along x
    assert not carrot_may_advance(short_of_a_right_angle, 0.0, start, start, target)


def test_the_carrot_cuts_a_corner_only_where_the_map_shows_the_cut_in_open_space() -> None:
    start, target = np.array([2.0, 0.0, 1.5]), np.array([2.0, 2.0, 1.5])  # east, then north at (2, 0)
    short_of_the_corner = np.array([1.6, 0.0, 1.5])  # 0.4 m before it, flying east at speed
    assert not carrot_may_advance(short_of_the_corner, 0.0, start, start, target)
    assert carrot_may_advance(short_of_the_corner, 0.0, start, start, target, cut_is_clear=True)
    # ... and never more than the look-ahead ahead of the drone
    far_short = np.array([0.5, 0.0, 1.5])
    assert not carrot_may_advance(far_short, 0.0, start, start, target, cut_is_clear=True, lookahead=1.5)


def _flight(is_clear: object, is_roomy: object = None) -> Flight:
    return Flight(FakeAutopilot(), load_config().agent, lambda *a, **kw: None, is_clear=is_clear, is_roomy=is_roomy)  # type: ignore[arg-type]


def test_near_its_corner_a_drone_may_cut_it_where_the_map_shows_the_way_clear() -> None:
    corner, carrot = np.array([2.0, 0.0, 1.5]), np.array([2.0, 0.6, 1.5])  # east, then north at (2, 0)
    near = corner - [CORNER_CUT_M - 0.05, 0.0, 0.0]
    farther = corner - [CORNER_CUT_M + 0.05, 0.0, 0.0]
    asked: list[tuple[Vec3, Vec3]] = []

    def clear(a: Vec3, b: Vec3) -> bool:
        asked.append((a, b))
        return True

    flight = _flight(clear)
    assert flight._may_cut_to(near, carrot, corner)
    assert asked == [(tuple(near), tuple(carrot))]  # the straight way from the drone to the carrot's next place
    assert not flight._may_cut_to(farther, carrot, corner)  # farther off: only where the map shows it roomy
    assert _flight(clear, is_roomy=lambda a, b: True)._may_cut_to(farther, carrot, corner)
    assert not _flight(lambda a, b: False)._may_cut_to(near, carrot, corner)  # the way is not clear
    assert not _flight(None)._may_cut_to(near, carrot, corner)  # no map: never
    # a gentle turn is cut from farther off too, where the way is clear, never without a map
    assert flight._may_cut_to(farther, carrot, corner, gentle=True)
    assert not _flight(lambda a, b: False)._may_cut_to(farther, carrot, corner, gentle=True)
    assert not _flight(None)._may_cut_to(farther, carrot, corner, gentle=True)


def test_the_look_ahead_is_long_in_the_open_and_short_near_a_segments_end() -> None:
    assert lookahead_before(10.0) == pytest.approx(LOOKAHEAD_OPEN_M)
    assert lookahead_before(LOOKAHEAD_NEAR_M) == pytest.approx(LOOKAHEAD_M)
    assert lookahead_before(0.0) == pytest.approx(LOOKAHEAD_M)
    ramp = [lookahead_before(d) for d in np.linspace(0.0, 5.0, 51)]
    assert all(b >= a for a, b in zip(ramp, ramp[1:]))  # never longer nearer the end


def test_gentle_turns_are_those_of_at_most_gentle_turn_deg_and_the_lead_runs_on_through_them() -> None:
    def bend(at: Vec3, length: float, degrees: float) -> Vec3:
        a = np.radians(degrees)
        return (at[0] + length * np.cos(a), at[1] + length * np.sin(a), at[2])

    start: Vec3 = (0.0, 0.0, 1.5)
    w0 = bend(start, 1.0, 0.0)
    w1 = bend(w0, 0.8, GENTLE_TURN_DEG - 1.0)  # gentle
    w2 = bend(w1, 0.7, 2 * GENTLE_TURN_DEG)  # GENTLE_TURN_DEG + 1 from the last leg: sharp
    w3 = bend(w2, 0.6, 2 * GENTLE_TURN_DEG + 10.0)  # gentle: 10 degrees more
    gentle, run_on = gentle_turns(start, [w0, w1, w2, w3])
    assert gentle == [False, True, False, True]  # the first segment's way in is not on the path
    assert run_on[0] == pytest.approx(0.8)  # on through w0's gentle turn, to w1, where the turn is sharp
    assert run_on[1] == 0.0
    assert run_on[2] == pytest.approx(0.6)
    assert run_on[3] == 0.0  # the path ends there
    straight = [(float(x), 0.0, 1.5) for x in range(1, 12)]
    _, long_run = gentle_turns(start, straight)
    assert long_run[0] == pytest.approx(LOOKAHEAD_NEAR_M + LOOKAHEAD_TAPER_M)  # as far as the lead looks
    assert gentle_turns(start, [start, w1])[0] == [False, True]  # from a leg of no length: no turn to make
