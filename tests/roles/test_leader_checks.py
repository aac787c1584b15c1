"""The leader checks what it is told (docs/security.md): a member's reported gains, points and looks are weighed
against the leader's own map, the mission volume and the member's heartbeat track before they count.

Driven through the pure core as tests/roles/test_protocol.py does, with its stand-in map."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from swarm.bus.phase import Phase
from swarm.config import ExploreSettings, SwarmConfig, Vec3, load_config
from swarm.explore.frontiers import ExplorationGrid, ViewModel
from swarm.patches.fused import UNKNOWN
from swarm.roles.membership import TRACK_POINTS, TRACK_SPACING_M, PeerTable
from swarm.roles.messages import FrontierReport, TargetAssignment, as_points
from swarm.roles.protocol import OWN_GAIN_PER_MEMBER, ExplorationCore, ReportLimits, Situation
from tests.roles.test_protocol import Map, _f, _report

LOOP = ExploreSettings().loop_s
VOLUME: tuple[Vec3, Vec3] = ((0.0, 0.0, 0.0), (10.0, 10.0, 3.0))
LIMITS = ReportLimits(VOLUME, margin_m=0.1, max_gain_m3=300.0)
LEADER_AT, MEMBER_AT = (1.0, 1.0, 1.5), (5.0, 1.0, 1.5)
FAR = _f((8.0, 1.0, 1.5), (9.0, 1.0, 1.5))  # a frontier the member reports and nobody has looked at


def _core(drone: int = 1, limits: ReportLimits = LIMITS, **settings: Any) -> ExplorationCore:
    return ExplorationCore(ExploreSettings(**settings), drone, epoch=1, now=0.0, limits=limits)


def _lead(core: ExplorationCore, now: float, grid: Map | None = None, **fields: Any) -> list[TargetAssignment]:
    """One leader decision for the cluster [1, 2] (member 2 at MEMBER_AT); the assignments it published that
    name a target or say done (not a round with nothing for anyone)."""
    situation = Situation(
        here=LEADER_AT,
        leader=1,
        cluster=fields.pop("cluster", [1, 2]),
        positions=fields.pop("positions", {2: MEMBER_AT}),
        frontiers=fields.pop("frontiers", []),
        map=grid or Map(),
        tracks=fields.pop("tracks", {}),
    )
    published = core.decide(now, situation).publish
    return [m for m in published if isinstance(m, TargetAssignment) and (m.drones or m.done)]


def _track(*points: Vec3) -> np.ndarray:
    return np.asarray(points, dtype=float).reshape(-1, 3)


def test_a_lying_explorers_visited_points_far_from_its_track_do_not_remove_candidates() -> None:
    core = _core()
    lie = _report(2, 1, [FAR], visited=as_points([FAR.viewpoint]), looked_at=as_points([FAR.point]))
    core.on_report(0.0, 2, lie, leader=1)
    sent = _lead(core, 0.1, tracks={2: _track(MEMBER_AT, (5.5, 1.0, 1.5))})  # it never flew near (8, 1)
    assert sent[-1].target_of(2) == (FAR.viewpoint, FAR.point)
    assert core.rejected["visited_off_track"] == 1


def test_a_look_near_the_members_track_still_exhausts_its_candidate() -> None:
    """The control of the test above: an honest look, where the member's heartbeats put it, counts."""
    core = _core()
    honest = _report(2, 1, [FAR], visited=as_points([FAR.viewpoint]), looked_at=as_points([FAR.point]))
    core.on_report(0.0, 2, honest, leader=1)
    arrived_at = (8.3, 1.2, 1.5)  # within arrive_tolerance_m of the viewpoint
    sent = _lead(core, 0.1, tracks={2: _track(MEMBER_AT, arrived_at)})
    assert sent == [] and core.rejected["visited_off_track"] == 0


def test_untrusted_visited_points_do_not_end_the_mission() -> None:
    core = _core()
    for step in range(6):
        lie = _report(2, step + 1, [], visited=as_points([FAR.viewpoint]), looked_at=as_points([FAR.point]))
        core.on_report(step * LOOP, 2, lie, leader=1)
        sent = _lead(core, step * LOOP + 0.1, frontiers=[FAR], tracks={2: _track(MEMBER_AT)})
        assert sent and not sent[-1].done, step
    assert not core.done
    assert core.rejected["visited_off_track"] == 6  # once per report the leader used


def test_a_reported_gain_of_3e38_does_not_outrank_an_honest_one() -> None:
    """The liar's candidate and the leader's own lie 2 m apart: gain scheduling leaves only the better one for
    this round, so which one is assigned says how they ranked."""
    core = _core()
    honest = _f((7.0, 3.0, 1.5), (8.0, 3.0, 1.5), gain=20.0)
    lie = _f((7.0, 1.0, 1.5), (8.0, 1.0, 1.5), gain=3e38)
    grid = Map()
    grid.views[lie.viewpoint] = 1.0  # the leader's map: little unknown to see from there
    core.on_report(0.0, 2, _report(2, 1, [lie]), leader=1)
    sent = _lead(core, 0.1, grid, frontiers=[honest])
    drones = {k: sent[-1].target_of(k) for k in sent[-1].drones}
    assert list(drones.values()) == [(honest.viewpoint, honest.point)]
    assert core.rejected["gain_clamped"] == 1


def test_without_shared_maps_a_reported_gain_is_clamped_to_what_a_view_can_hold() -> None:
    core = _core(strategy="frontier-only")
    core.on_report(0.0, 2, _report(2, 1, [_f(FAR.viewpoint, FAR.point, gain=3e38)]), leader=1)
    effects = core.decide(0.1, Situation(LEADER_AT, 1, [1, 2], {2: MEMBER_AT}, [], Map()))
    (gains,) = [fields["gains"] for event, fields in effects.events if event == "assignment"]
    assert gains == {2: LIMITS.max_gain_m3}
    assert core.rejected["gain_clamped"] == 1


def test_a_non_finite_gain_that_got_past_the_wire_drops_its_candidate() -> None:
    core = _core()
    good = _report(2, 1, [FAR])
    forged = FrontierReport.model_construct(**{**dict(good), "gains": np.array([np.nan], dtype=np.float32)})
    core.on_report(0.0, 2, forged, leader=1)
    assert _lead(core, 0.1) == [] and core.rejected["gain_invalid"] == 1


def test_a_target_outside_the_mission_volume_is_never_assigned() -> None:
    core = _core()
    outside = _f((12.0, 1.0, 1.5), (13.0, 1.0, 1.5), gain=200.0)
    above = _f((6.0, 1.0, 4.0), (6.5, 1.0, 4.0), gain=200.0)
    core.on_report(0.0, 2, _report(2, 1, [outside, above, FAR]), leader=1)
    sent = _lead(core, 0.1)
    targets = [sent[-1].target_of(k) for k in sent[-1].drones]
    assert targets == [(FAR.viewpoint, FAR.point)]
    assert core.rejected["candidate_outside_volume"] == 2


def test_a_point_looked_at_just_past_the_volumes_wall_is_still_a_candidate() -> None:
    """A frontier looked at from its own cell has its point LOOK_AHEAD_M ahead of the viewpoint, which near a
    wall of the volume lies outside it: the honest candidate stays."""
    core = _core()
    by_the_wall = _f((9.75, 5.0, 1.5), (10.75, 5.0, 1.5))
    core.on_report(0.0, 2, _report(2, 1, [by_the_wall]), leader=1)
    sent = _lead(core, 0.1)
    assert [sent[-1].target_of(k) for k in sent[-1].drones] == [(by_the_wall.viewpoint, by_the_wall.point)]
    assert core.rejected["candidate_outside_volume"] == 0


def test_visited_points_outside_the_volume_are_counted_and_ignored() -> None:
    core = _core()
    report = _report(2, 1, [FAR], visited=as_points([(50.0, 1.0, 1.5)]), looked_at=as_points([(51.0, 1.0, 1.5)]))
    core.on_report(0.0, 2, report, leader=1)
    _lead(core, 0.1, tracks={2: _track((50.0, 1.0, 1.5))})
    assert core.rejected["visited_outside_volume"] == 1 and core.rejected["visited_off_track"] == 0


def test_an_explorer_does_not_fly_an_assignment_outside_the_mission_volume() -> None:
    core = _core(drone=2)
    core.decide(0.0, Situation(MEMBER_AT, 1, [1, 2], {1: LEADER_AT}, [], Map()))
    away = TargetAssignment(
        leader=1,
        epoch=1,
        round=1,
        members=[1, 2],
        drones=[2],
        viewpoints=as_points([(500.0, 1.0, 1.5)]),
        points=as_points([(501.0, 1.0, 1.5)]),
    )
    core.on_assignment(0.5, 1, away, leader=1)
    assert core.target is None and core.rejected["assignment_outside_volume"] == 1
    inside = away.model_copy(update={"viewpoints": as_points([FAR.viewpoint]), "points": as_points([FAR.point])})
    core.on_assignment(0.6, 1, inside, leader=1)
    assert core.target is not None and core.target.viewpoint == FAR.viewpoint


class _CountingMap(Map):
    def __init__(self) -> None:
        super().__init__()
        self.cast = 0

    def view_gain(self, viewpoints: np.ndarray, points: np.ndarray) -> np.ndarray:
        self.cast += len(viewpoints)
        return np.full(len(viewpoints), 3.0)


def test_a_member_reporting_hundreds_of_candidates_costs_the_leader_a_bounded_number_of_ray_casts() -> None:
    core = _core()
    many = [_f((1.0 + 0.015 * i, 9.0, 1.5), (1.0 + 0.015 * i, 9.5, 1.5), gain=3e38) for i in range(500)]
    grid = _CountingMap()
    core.on_report(0.0, 2, _report(2, 1, many), leader=1)
    effects = core.decide(0.1, Situation(LEADER_AT, 1, [1, 2], {2: MEMBER_AT}, [], grid))
    assert grid.cast == OWN_GAIN_PER_MEMBER
    (gains,) = [fields["gains"] for event, fields in effects.events if event == "assignment"]
    assert gains and max(gains.values()) <= 3.0  # the rest are worth no more than the least of those cast


def test_the_view_gain_bound_holds_what_a_view_into_nothing_but_unknown_sees() -> None:
    config = load_config(overrides={"mission.volume": {"min": [-20, -20, -20], "max": [20, 20, 20]}})
    limits = ReportLimits.from_config(config)
    states = np.full((100, 100, 100), UNKNOWN, dtype=np.uint8)  # 20 m a side at 0.2 m
    grid = ExplorationGrid.from_states(
        (-10.0, -10.0, -10.0), 0.2, states, config.explore, -10.0, 10.0, view=ViewModel.from_camera(config.camera)
    )
    seen = float(grid.view_gain(np.zeros((1, 3)), np.array([[1.0, 0.0, 0.0]]))[0])
    assert seen <= limits.max_gain_m3 < 1.15 * seen


def test_the_box_gain_bound_is_the_gain_cube() -> None:
    config = SwarmConfig.model_validate({"explore": {"gain_model": "box"}})
    limits = ReportLimits.from_config(config)
    states = np.full((30, 30, 30), UNKNOWN, dtype=np.uint8)
    grid = ExplorationGrid.from_states((0.0, 0.0, 0.0), 0.2, states, config.explore, 0.0, 6.0)
    assert float(grid.gain_at(np.array([[3.0, 3.0, 3.0]]))[0]) == pytest.approx(limits.max_gain_m3)
    small = load_config(overrides={"mission.volume": {"min": [0, 0, 0], "max": [1, 1, 1]}, "explore.gain_model": "box"})
    assert ReportLimits.from_config(small).max_gain_m3 == pytest.approx(1.0)  # never more than the volume


def test_a_peers_track_keeps_breadcrumbs_and_leaves_out_a_teleport_until_it_could_have_flown_there() -> None:
    now = [0.0]
    table = PeerTable(1, clock=lambda: now[0])
    for step in range(10):  # 0.1 m apart: a breadcrumb every TRACK_SPACING_M
        now[0] = step * 0.2
        table.heard(2, (step * 0.1, 0.0, 1.5), Phase.FLYING, 1)
    track = table.peers[2].track_array()
    assert 3 <= len(track) <= 5 and np.all(np.diff(track[:, 0]) >= TRACK_SPACING_M - 1e-9)
    table.heard(2, (80.0, 0.0, 1.5), Phase.FLYING, 1)  # 80 m in no time
    assert table.track_jumps == 1 and table.peers[2].track_array()[-1][0] < 1.0
    now[0] += 80.0 / 12.0  # as long as a drone would need
    table.heard(2, (80.0, 0.0, 1.5), Phase.FLYING, 1)
    assert table.track_jumps == 1 and tuple(table.peers[2].track_array()[-1]) == (80.0, 0.0, 1.5)


def test_a_connecting_peers_origin_is_not_on_its_track() -> None:
    """Before its first telemetry an agent's heartbeats say (0, 0, 0): the first real position is no jump."""
    table = PeerTable(1, clock=lambda: 0.0)
    table.heard(2, (0.0, 0.0, 0.0), Phase.CONNECTING, 1)
    table.heard(2, (30.0, 4.0, 0.1), Phase.READY, 1)
    assert table.track_jumps == 0 and table.peers[2].track_array().tolist() == [[30.0, 4.0, 0.1]]


def test_a_peers_track_is_bounded() -> None:
    table = PeerTable(1, clock=lambda: 0.0)
    for step in range(TRACK_POINTS + 10):
        table.heard(2, (float(step % 2) * 0.5, 0.0, 1.5), Phase.FLYING, 1)
    assert len(table.peers[2].track) == TRACK_POINTS


def test_an_agent_without_a_volume_checks_no_volume() -> None:
    """The defaults check nothing: a core of a test, or an agent whose mission has no volume to check against."""
    assert ReportLimits().inside(np.array([[1e6, -1e6, 0.0]])).all()
    assert not LIMITS.inside(np.array([[10.2, 5.0, 1.5]])).any() and LIMITS.inside(np.array([[10.05, 5, 1.5]])).all()
