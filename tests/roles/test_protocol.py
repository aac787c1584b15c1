"""The exploration protocol's pure core, driven without a bus, a map or a clock: reports and assignments in,
decisions at given times, the flight's outcomes; asserting what it publishes, targets, and when it is done.

The map is a stand-in with the two queries the core makes (it is the unit under test's input, not the thing
tested). Each early-termination pattern seen on unseen buildings has a case here."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from swarm.config import ExploreSettings, Vec3
from swarm.explore.frontiers import Frontier
from swarm.roles.messages import FrontierReport, TargetAssignment, as_points
from swarm.roles.protocol import (
    ARRIVAL_WAKE_GAP_S,
    MAP_CHANGE_M3,
    POCKET_TRUST_LOOPS,
    UNREACHABLE_GIVE_UP,
    UNREACHABLE_RETRY_S,
    Effects,
    ExplorationCore,
    Situation,
    Target,
)

LOOP = ExploreSettings().loop_s


class Map:
    """The map queries: the box gain everywhere (settable), the view gain per viewpoint (settable; unset, more
    than any report says), and whether a frontier is still near a point."""

    def __init__(self, gain: float = 5.0) -> None:
        self.gain = gain
        self.explored: list[Vec3] = []
        self.views: dict[Vec3, float] = {}

    def gain_at(self, points: np.ndarray) -> np.ndarray:
        return np.full(len(np.asarray(points).reshape(-1, 3)), self.gain)

    def view_gain(self, viewpoints: np.ndarray, points: np.ndarray) -> np.ndarray:
        rows = np.asarray(viewpoints, dtype=float).reshape(-1, 3)
        return np.array([self.views.get(tuple(float(v) for v in row), 1e6) for row in rows])

    def is_frontier_near(self, point: Vec3, radius: float) -> bool:
        return not any(np.linalg.norm(np.subtract(point, e)) <= radius for e in self.explored)

    def travel_distances(self, starts: np.ndarray, goals: np.ndarray) -> np.ndarray:
        return np.linalg.norm(np.reshape(starts, (-1, 1, 3)) - np.reshape(goals, (1, -1, 3)), axis=2)

    def travel_between(self, points: np.ndarray) -> np.ndarray:
        return self.travel_distances(points, points)


def _core(drone: int = 1, **settings: Any) -> ExplorationCore:
    return ExplorationCore(ExploreSettings(**settings), drone, epoch=1, now=0.0)


def _situation(
    frontiers: list[Frontier],
    here: Vec3 = (1.0, 1.0, 1.5),
    leader: int = 1,
    cluster: list[int] | None = None,
    positions: dict[int, Vec3] | None = None,
    grid: Map | None = None,
    in_pocket: bool = False,
) -> Situation:
    return Situation(
        here=here,
        leader=leader,
        cluster=cluster or [leader],
        positions=positions or {},
        frontiers=frontiers,
        map=grid or Map(),
        in_pocket=in_pocket,
    )


def _f(viewpoint: Vec3, point: Vec3, gain: float = 10.0) -> Frontier:
    return Frontier(point=point, viewpoint=viewpoint, gain=gain, cells=4)


def _report(drone: int, seq: int, frontiers: list[Frontier] = (), **fields: Any) -> FrontierReport:
    return FrontierReport(
        id=drone,
        epoch=1,
        seq=seq,
        position=fields.pop("position", (5.0, 1.0, 1.5)),
        viewpoints=as_points([f.viewpoint for f in frontiers]),
        points=as_points([f.point for f in frontiers]),
        gains=np.asarray([f.gain for f in frontiers], dtype=np.float32),
        **fields,
    )


TAKE_OFF = (1.0, 1.0, 1.5)
EAST = _f(TAKE_OFF, (2.0, 1.0, 1.5))
WEST = _f(TAKE_OFF, (0.0, 1.0, 1.5))
ABOVE = _f(TAKE_OFF, (1.0, 1.05, 2.4))


def test_a_spot_looked_from_one_way_is_still_a_target_the_other_way() -> None:
    """A drone that took off in a small room has every viewpoint there: exhaustion by position alone ended
    one-drone missions at 13-17 % explored after the first look."""
    core = _core()
    effects = core.decide(0.0, _situation([EAST, WEST]))
    assert core.target is not None and effects.retarget
    looked = core.target
    core.looked_at(looked)
    core.look_finished(looked)
    core.decide(1.0, _situation([EAST, WEST]))
    assert core.target is not None and core.target.point != looked.point  # the other way, same spot
    assert not core.done
    assert core._candidates([EAST, WEST, ABOVE]) == [
        c for c in core._candidates([EAST, WEST, ABOVE]) if c.point != looked.point
    ]


def test_a_point_straight_above_its_viewpoint_is_exhausted_by_any_look_from_there() -> None:
    core = _core()
    core.looked_at(Target(TAKE_OFF, EAST.point, "self"))
    assert [c.point for c in core._candidates([ABOVE, WEST])] == [WEST.point]


def test_a_lone_drone_is_done_only_when_its_map_stays_empty_for_a_loop() -> None:
    core = _core()
    core.decide(0.0, _situation([]))
    assert not core.done  # a map update in flight can empty the frontier set for a moment
    core.decide(LOOP / 2, _situation([]))
    assert not core.done
    effects = core.decide(LOOP + 0.1, _situation([]))
    assert core.done and "no reachable frontier" in core.done_reason
    assert any(isinstance(m, TargetAssignment) and m.done for m in effects.publish)
    assert "exploration_done" in [e for e, _ in effects.events]


def test_a_drone_shut_in_by_its_map_is_never_done() -> None:
    """From a pocket (its own cell blocked in its map) nothing is reachable, and that says nothing."""
    core = _core()
    for t in range(10):
        core.decide(t * LOOP, _situation([], in_pocket=True))
    assert not core.done


def test_the_leader_is_done_only_after_every_member_reported_since_its_map_ran_empty() -> None:
    core = _core(drone=1)
    cluster, positions = [1, 2], {2: (5.0, 1.0, 1.5)}
    core.on_report(0.0, 2, _report(2, 1), leader=1)
    core.decide(1.0, _situation([], cluster=cluster, positions=positions))
    core.decide(1.0 + 2 * LOOP, _situation([], cluster=cluster, positions=positions))
    assert not core.done  # member 2's last word is older than the empty map
    core.on_report(1.0 + 2 * LOOP, 2, _report(2, 2, in_pocket=True), leader=1)
    core.decide(1.0 + 2.5 * LOOP, _situation([], cluster=cluster, positions=positions))
    assert not core.done  # member 2 is shut in: its empty list says nothing yet
    core.on_report(1.0 + 2.6 * LOOP, 2, _report(2, 3), leader=1)
    core.decide(1.0 + 2.7 * LOOP, _situation([], cluster=cluster, positions=positions))
    assert core.done


def test_a_member_claiming_a_pocket_forever_holds_the_cluster_only_for_a_while() -> None:
    """A liar (or a drone stuck for good) that reports in_pocket on every report would keep its leader from ever
    being done: pockets are waited for POCKET_TRUST_LOOPS loops after the candidates ran out, then no longer (and
    that is counted). Honest reports in between, as a liar's own agent sends them, do not restart the wait."""
    core = _core(drone=1)
    cluster, positions = [1, 2], {2: (5.0, 1.0, 1.5)}
    t, seq = 0.0, 0
    while t < (POCKET_TRUST_LOOPS - 1) * LOOP:
        seq += 1
        if seq % 4 == 0:
            core.on_report(t - 0.05, 2, _report(2, seq + 1000), leader=1)  # its agent's honest report
        core.on_report(t, 2, _report(2, seq, in_pocket=True), leader=1)
        core.decide(t + 0.1, _situation([], cluster=cluster, positions=positions))
        t += LOOP
    assert not core.done and core.rejected["pocket_distrusted"] == 0
    while t < (POCKET_TRUST_LOOPS + 3) * LOOP and not core.done:
        seq += 1
        core.on_report(t, 2, _report(2, seq, in_pocket=True), leader=1)
        core.decide(t + 0.1, _situation([], cluster=cluster, positions=positions))
        t += LOOP
    assert core.done and core.rejected["pocket_distrusted"] == 1


def test_the_leader_is_not_done_while_its_members_hold_patches_its_map_lacks() -> None:
    """A member's patches still on their way can hold the frontier the leader's map does not show yet (seen: a
    leader declared done with the upper room unexplored; the patches that made it reachable came after)."""
    core = _core(drone=1)
    cluster, positions = [1, 2], {2: (5.0, 1.0, 1.5)}

    def decide(t: float, to_come: int) -> None:
        core.on_report(t - 0.05, 2, _report(2, int(t * 10)), leader=1)
        situation = _situation([], cluster=cluster, positions=positions)
        situation.patches_to_come = to_come
        core.decide(t, situation)

    for step in range(4):
        decide(step * LOOP + 0.1, to_come=3)
    assert not core.done
    decide(4 * LOOP + 0.1, to_come=0)  # they came, and the map still has nothing to explore
    assert core.done and core.rejected["patches_never_came"] == 0


def test_patches_a_member_lists_but_never_serves_hold_the_cluster_only_for_a_while() -> None:
    core = _core(drone=1)
    cluster, positions = [1, 2], {2: (5.0, 1.0, 1.5)}
    t = 0.1
    while not core.done and t < (POCKET_TRUST_LOOPS + 3) * LOOP:
        core.on_report(t - 0.05, 2, _report(2, int(t * 10)), leader=1)
        situation = _situation([], cluster=cluster, positions=positions)
        situation.patches_to_come = 1
        core.decide(t, situation)
        t += LOOP
    assert core.done and t > (POCKET_TRUST_LOOPS - 1) * LOOP
    assert core.rejected["patches_never_came"] == 1


def test_a_members_arrivals_wake_the_leader_at_most_once_a_gap() -> None:
    core = _core(drone=1)
    wakes = [core.on_report(i * 0.02, 2, _report(2, i + 1, arrived=True), leader=1).wake for i in range(100)]
    assert sum(wakes) == 2 and wakes[0]  # 2 s of reports at 50 Hz: at t = 0 and t = ARRIVAL_WAKE_GAP_S
    assert core.rejected["arrival_wake_limited"] == 98
    assert core.on_report(2.0 + ARRIVAL_WAKE_GAP_S, 2, _report(2, 200, arrived=True), leader=1).wake
    assert core.on_report(2.0 + ARRIVAL_WAKE_GAP_S, 3, _report(3, 1, arrived=True), leader=1).wake  # its own gap
    assert not core.on_report(9.0, 2, _report(2, 201, arrived=True), leader=2).wake  # not our member


def test_a_members_report_keeps_the_leader_from_being_done() -> None:
    core = _core(drone=1)
    cluster, positions = [1, 2], {2: (5.0, 1.0, 1.5)}
    far = _f((8.0, 1.0, 1.5), (9.0, 1.0, 1.5))
    for step in range(4):
        core.on_report(step * LOOP, 2, _report(2, step + 1, [far]), leader=1)
        effects = core.decide(step * LOOP + 0.1, _situation([], cluster=cluster, positions=positions))
    assert not core.done
    sent = [m for m in effects.publish if isinstance(m, TargetAssignment)][-1]
    assert sent.target_of(2) == (far.viewpoint, far.point)


def test_an_unreachable_target_is_kept_from_this_drone_a_while_then_until_the_map_changes() -> None:
    core = _core()
    grid = Map(gain=2.0)
    behind_a_door = _f((5.0, 1.0, 1.5), (5.5, 1.0, 1.5))
    now = 0.0
    for failure in range(1, UNREACHABLE_GIVE_UP + 1):
        core.decide(now, _situation([behind_a_door], grid=grid))
        assert core.target is not None and core.target.viewpoint == behind_a_door.viewpoint, failure
        effects = core.cannot_reach(now, core.target, grid)
        assert core.target is None and effects.wake
        core.decide(now + 1.0, _situation([behind_a_door], grid=grid))
        assert core.target is None  # not given to this drone again for a while
        now += UNREACHABLE_RETRY_S + 1.0
    # three failures: kept from it whatever the time (so it is given up, and the lone drone would be done a loop
    # after the map first ran empty) unless the map near it changes before
    assert [g.viewpoint for g in core.given_up] == [behind_a_door.viewpoint] and not core.done
    grid.gain += 2 * MAP_CHANGE_M3  # the map near it changed: the door may be open now
    effects = core.decide(now, _situation([behind_a_door], grid=grid))
    assert core.target is not None and core.target.viewpoint == behind_a_door.viewpoint
    assert "unreachable_retry" in [e for e, _ in effects.events]


def test_what_one_drone_cannot_reach_goes_to_another_and_is_given_up_only_when_nobody_can() -> None:
    core = _core(drone=1)
    cluster, positions = [1, 2], {2: (5.0, 1.0, 1.5)}
    grid = Map()
    door = _f((2.0, 1.0, 1.5), (2.5, 1.0, 1.5))
    core.decide(0.0, _situation([door], cluster=cluster, positions=positions, grid=grid))
    mine = core.target
    assert mine is not None and mine.viewpoint == door.viewpoint  # the leader is nearer
    core.cannot_reach(0.5, mine, grid)
    core.on_report(0.6, 2, _report(2, 1), leader=1)
    effects = core.decide(1.0, _situation([door], cluster=cluster, positions=positions, grid=grid))
    sent = [m for m in effects.publish if isinstance(m, TargetAssignment)][-1]
    assert sent.target_of(2) == (door.viewpoint, door.point) and core.target is None
    core.on_report(2.0, 2, _report(2, 2, unreachable=as_points([door.viewpoint])), leader=1)
    core.decide(2.1, _situation([door], cluster=cluster, positions=positions, grid=grid))
    assert [g.viewpoint for g in core.given_up] == [door.viewpoint]
    assert "every member" in core.given_up[0].reason
    core.on_report(2.0 + LOOP, 2, _report(2, 3, unreachable=as_points([door.viewpoint])), leader=1)
    core.decide(2.2 + LOOP, _situation([door], cluster=cluster, positions=positions, grid=grid))
    assert core.done and core.summary()["frontiers_given_up"][0]["viewpoint"] == list(door.viewpoint)


def test_an_explorer_reports_and_takes_its_leaders_assignment() -> None:
    core = _core(drone=2)
    effects = core.decide(0.0, _situation([EAST], leader=1, cluster=[1, 2]))
    report = effects.publish[0]
    assert isinstance(report, FrontierReport) and len(report.viewpoints) == 1 and core.target is None
    assignment = TargetAssignment(
        leader=1,
        epoch=1,
        round=1,
        members=[1, 2],
        drones=[2],
        viewpoints=as_points([WEST.viewpoint]),
        points=as_points([WEST.point]),
    )
    effects = core.on_assignment(0.5, 1, assignment, leader=1)
    assert core.target is not None and core.target.source == "leader" and effects.retarget
    core.looked_at(core.target)
    effects = core.decide(1.0, _situation([EAST, WEST], leader=1, cluster=[1, 2]))
    report = effects.publish[0]
    assert report.arrived and report.looked_at.tolist() == [list(WEST.point)]


def test_an_explorer_whose_leader_is_quiet_picks_its_own_after_tau() -> None:
    core = _core(drone=2)
    tau = core.settings.explorer_timeout_s
    core.decide(0.0, _situation([EAST], leader=1, cluster=[1, 2]))
    core.decide(tau - 0.5, _situation([EAST], leader=1, cluster=[1, 2]))
    assert core.target is None
    core.decide(tau + 0.5, _situation([EAST], leader=1, cluster=[1, 2]))
    assert core.target is not None and core.target.source == "self"


def test_a_leader_change_mid_assignment_follows_the_new_leader_only() -> None:
    core = _core(drone=3)
    core.decide(0.0, _situation([EAST], leader=1, cluster=[1, 3]))
    old = TargetAssignment(
        leader=1,
        epoch=1,
        round=4,
        members=[1, 3],
        drones=[3],
        viewpoints=as_points([WEST.viewpoint]),
        points=as_points([WEST.point]),
    )
    core.decide(1.0, _situation([EAST], leader=2, cluster=[2, 3]))  # leader 1 is gone: 2 leads now
    core.on_assignment(1.5, 1, old, leader=2)
    assert core.target is None  # the old leader's word no longer counts
    tau = core.settings.explorer_timeout_s
    core.decide(1.0 + tau - 0.5, _situation([EAST], leader=2, cluster=[2, 3]))
    assert core.target is None  # tau runs from the first report to the new leader
    done = TargetAssignment(leader=2, epoch=1, round=1, members=[2, 3], done=True)
    core.on_assignment(2.0, 2, done, leader=2)
    assert core.done and "leader 2" in core.done_reason


def test_messages_whose_sender_is_not_their_author_are_ignored() -> None:
    core = _core(drone=1)
    assert not core.on_report(0.0, 3, _report(2, 1, arrived=True), leader=1).wake
    assert core.reports == {}
    forged = TargetAssignment(leader=2, epoch=1, round=1, members=[1, 2], done=True)
    core.on_assignment(0.0, 3, forged, leader=2)
    assert not core.done


def test_the_same_spot_assigned_again_keeps_the_target_object() -> None:
    """The flight knows its target by identity: a new object at every loop never counted as reached."""
    core = _core(drone=2)
    effects = Effects()
    assert core.set_target(effects, Target((1.0, 1.0, 1.5), (1.5, 1.0, 1.5), "self"))
    flying_to = core.target
    again = Effects()
    assert core.set_target(again, Target((1.3, 1.2, 1.5), (1.9, 1.2, 1.5), "leader")) is False  # 0.36 m away
    assert core.target is flying_to and flying_to.point == (1.9, 1.2, 1.5) and flying_to.source == "leader"
    assert not again.retarget and again.events == []
    assert (core.targets_self_selected, core.targets_assigned) == (1, 0)
    other = Effects()
    assert core.set_target(other, Target((4.0, 1.0, 1.5), (4.5, 1.0, 1.5), "leader"))
    assert core.target is not flying_to and other.retarget and core.targets_assigned == 1


def test_a_target_whose_frontier_is_gone_is_dropped_and_a_new_one_asked_for() -> None:
    core = _core()
    grid = Map()
    core.decide(0.0, _situation([EAST], grid=grid))
    assert core.target is not None
    grid.explored.append(EAST.point)
    effects = core.decide(1.0, _situation([WEST], grid=grid))
    assert "target_explored" in [e for e, _ in effects.events]
    assert core.target is not None and core.target.point == WEST.point


def test_reports_with_looks_of_the_wrong_length_do_not_validate() -> None:
    with pytest.raises(ValueError, match="looked_at"):
        _report(2, 1, visited=as_points([TAKE_OFF, TAKE_OFF]), looked_at=as_points([EAST.point]))


def _round(drones: list[int], members: list[int], round_: int = 1) -> TargetAssignment:
    return TargetAssignment(
        leader=1,
        epoch=1,
        round=round_,
        members=members,
        drones=drones,
        viewpoints=as_points([WEST.viewpoint] * len(drones)),
        points=as_points([WEST.point] * len(drones)),
    )


def test_a_round_with_nothing_for_a_member_says_so_and_one_with_a_target_or_for_others_does_not() -> None:
    """An idle drone waits for its next target; one its leader found nothing for heads home at once
    (`left_out_at`): waiting `idle_home_s` for it put 6-7 s on the return of the drone that landed last."""
    core = _core(drone=2)
    core.on_assignment(1.0, 1, _round([2], [1, 2]), leader=1)
    assert core.left_out_at is None
    core.on_assignment(2.0, 1, _round([1], [1, 3]), leader=1)  # a round for another cluster's members
    assert core.left_out_at is None
    core.on_assignment(3.0, 1, _round([1], [1, 2], round_=2), leader=1)
    assert core.left_out_at == 3.0


def test_rounds_for_a_drone_are_its_leaders_rounds_heard_and_its_own_as_leader() -> None:
    """What an idle drone counts before it heads home on time alone (`should_head_home`): decisions that were
    made for it, not the seconds a slow leader took."""
    member = _core(drone=2)
    member.on_assignment(1.0, 1, _round([2], [1, 2]), leader=1)
    member.on_assignment(2.0, 3, _round([1], [1, 2]), leader=1)  # sent by 3, naming 1: not a round of its leader
    member.on_assignment(3.0, 1, _round([1], [1, 2], round_=2), leader=4)  # 1 is no longer its leader
    assert member.rounds_since(0.0) == 1 and member.rounds_since(1.5) == 0
    member.on_assignment(4.0, 1, _round([1], [1, 3], round_=3), leader=1)  # a round it is not in still came
    assert member.rounds_since(1.5) == 1
    leader = _core(drone=1)
    leader.decide(5.0, _situation([EAST]))
    leader.decide(6.0, _situation([EAST]))
    assert leader.rounds_since(5.0) == 2 and leader.rounds_since(5.5) == 1 and leader.rounds_since(6.5) == 0


def test_a_leader_that_finds_nothing_for_itself_or_for_anyone_says_so() -> None:
    leader = _core(drone=1)
    leader.decide(1.0, _situation([EAST]))
    assert leader.target is not None and leader.left_out_at is None
    # the only candidate goes to a member beside it; nothing is left for the leader, far away
    other = _core(drone=1)
    near_east = {2: (1.0, 1.0, 1.5)}
    other.decide(2.0, _situation([EAST], cluster=[1, 2], positions=near_east, here=(-9.0, 1.0, 1.5)))
    assert other.target is None and other.left_out_at == 2.0
    other.decide(3.0, _situation([], cluster=[1, 2], positions=near_east))  # no candidate at all
    assert other.left_out_at == 3.0


def test_a_leader_with_nothing_for_anyone_tells_its_members_so_until_it_is_done() -> None:
    """Without this round an idle member heard nothing until `done` (3-6 s later) or its own `idle_home_s`."""
    leader = _core(drone=1)
    members = [1, 2]
    effects = leader.decide(1.0, _situation([], cluster=members, positions={2: (5.0, 1.0, 1.5)}))
    [empty] = [m for m in effects.publish if isinstance(m, TargetAssignment)]
    assert empty.members == members and empty.drones == [] and not empty.done
    member = _core(drone=2)
    member.on_assignment(1.1, 1, empty, leader=1)
    assert member.left_out_at == 1.1 and not member.done
    leader.on_report(1.5, 2, _report(2, 1), leader=1)  # a fresh report, a loop later: done
    effects = leader.decide(1.0 + LOOP + 0.1, _situation([], cluster=members, positions={2: (5.0, 1.0, 1.5)}))
    assert leader.done
    assert [m.done for m in effects.publish if isinstance(m, TargetAssignment)] == [True]


@pytest.mark.parametrize(
    ("assignment", "big_gain", "rule", "target_x"),
    [
        ("utility", 60.0, "utility", 9.0),
        ("tours", 60.0, "tours", 0.0),
        ("tail-tours", 60.0, "utility", 9.0),  # a large candidate is left: not the tail yet
        ("tail-tours", 15.0, "tours", 0.0),  # every candidate under tail_gain_m3 (20): leftovers, by tours
    ],
)
def test_the_leader_hands_out_candidates_by_the_configured_rule(
    assignment: str, big_gain: float, rule: str, target_x: float
) -> None:
    """Two small candidates beside the leader and one larger 8 m on: utility takes the larger, a tour the nearest."""
    core = _core(drone=1, assignment=assignment)
    near = [_f((0.0, 1.0, 1.5), (0.0, 0.5, 1.5), gain=3.0), _f((-2.0, 1.0, 1.5), (-2.0, 0.5, 1.5), gain=3.0)]
    far = _f((9.0, 1.0, 1.5), (9.5, 1.0, 1.5), gain=big_gain)
    grid = Map()
    grid.views = {f.viewpoint: f.gain for f in (*near, far)}
    effects = core.decide(0.0, _situation([*near, far], here=(1.0, 1.0, 1.5), grid=grid))
    [logged] = [fields for event, fields in effects.events if event == "assignment"]
    assert logged["rule"] == rule
    assert core.target is not None and core.target.viewpoint[0] == target_x


@pytest.mark.parametrize(("home", "target_x"), [(None, -2.8), ((-10.0, 1.0, 1.5), 3.0)])
def test_with_tours_a_member_that_reports_its_home_gets_a_tour_that_ends_there(
    home: Vec3 | None, target_x: float
) -> None:
    core = _core(drone=1, assignment="tours")
    west, east = _f((-2.8, 1.0, 1.5), (-2.8, 0.5, 1.5)), _f((3.0, 1.0, 1.5), (3.0, 0.5, 1.5))
    core.on_report(0.0, 2, _report(2, 1, [west, east], position=(0.0, 1.0, 1.5), home=home), leader=1)
    situation = _situation([], here=(50.0, 1.0, 1.5), cluster=[1, 2], positions={2: (0.0, 1.0, 1.5)})
    effects = core.decide(0.1, situation)
    sent = [m for m in effects.publish if isinstance(m, TargetAssignment)][-1]
    assert sent.target_of(2) is not None and sent.target_of(2)[0][0] == pytest.approx(target_x)
