"""The exploration report's extras: time to coverage, overlap, per-drone coverage, the leader timeline and
trajectories from heartbeats, the figures and report.md. No processes: the pure pieces, fed synthetic data."""

from __future__ import annotations

import base64
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from swarm.agent.summary import AgentSummary
from swarm.bus.messages import AgentState
from swarm.bus.phase import Phase
from swarm.config import load_config
from swarm.mission import observer as observer_module
from swarm.mission.coverage import SwarmCoverage, overlap_fraction, unexplored_regions
from swarm.mission.files import AgentRow, Defences, MissionReport, ObserverStatus, UnexploredRegion
from swarm.mission.observer import LeaderTimeline, Observer, Trajectories, clusters_of
from swarm.mission.plots import PLOT_NAMES, floor_plan, leader_segments, plot_explored, received_rate, write_plots
from swarm.mission.report import _why_short, defences_of, finish_report, time_to, write_report
from swarm.mission.report_md import write_report_page
from swarm.sim.coverage import ReachableSpace
from swarm.sim.worlds import load_world
from tests.file_models import agent_row_data, agent_summary_data, mission_report_data, observer_status_data
from tests.mission.spin_patches import spin_patches

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


# --- time_to -----------------------------------------------------------------------------------------------------


def test_time_to_is_the_first_time_each_threshold_is_reached_and_null_when_never() -> None:
    timeline = [[0.0, 0.0], [2.0, 0.3], [4.1, 0.5], [6.0, 0.89], [8.0, 0.93], [10.0, 0.9501], [12.0, 0.97]]
    assert time_to(timeline) == {"0.5": 4.1, "0.9": 8.0, "0.95": 10.0, "0.99": None}


def test_time_to_of_an_empty_timeline_is_all_null() -> None:
    assert time_to([]) == {"0.5": None, "0.9": None, "0.95": None, "0.99": None}


def test_time_to_takes_the_first_crossing_even_if_the_fraction_dips_later() -> None:
    # a patch rejected late cannot lower the fused fraction, but the function must not depend on monotony
    assert time_to([[1.0, 0.6], [2.0, 0.4], [3.0, 0.7]], thresholds=(0.5,)) == {"0.5": 1.0}


# --- overlap -----------------------------------------------------------------------------------------------------


def test_overlap_is_the_share_of_known_cells_seen_by_two_or_more_producers() -> None:
    known = np.array([[1, 1, 1, 0, 0, 0, 0, 0], [0, 1, 1, 1, 0, 0, 0, 0], [0, 0, 1, 0, 1, 0, 0, 0]], dtype=bool)
    # known by >= 1: cells 0-4 (5); by >= 2: cells 1, 2 (2)
    assert overlap_fraction(known) == pytest.approx(2 / 5)


def test_overlap_of_disjoint_or_empty_coverage() -> None:
    assert overlap_fraction(np.array([[1, 0], [0, 1]], dtype=bool)) == 0.0
    assert overlap_fraction(np.array([[1, 1], [1, 1]], dtype=bool)) == 1.0
    assert overlap_fraction(np.zeros((2, 5), dtype=bool)) == 0.0
    assert overlap_fraction(np.zeros((0, 5), dtype=bool)) == 0.0


def test_coverage_keeps_one_map_per_producer_and_measures_their_overlap(tmp_path: Path) -> None:
    config = load_config(None, {"mission.world": "box", "mapping.patch_frames": 50})
    for producer, yaws in ((1, range(0, 200, 30)), (2, range(150, 360, 30))):  # views overlapping on 150-180
        for seq, data in enumerate(spin_patches(config, producer, yaws=yaws)):
            (tmp_path / f"{producer}.1.{seq}.patch").write_bytes(data)

    coverage = SwarmCoverage(config, tmp_path)
    coverage.update(t=3.0)
    snapshot = coverage.snapshot()
    by_agent = snapshot["explored_by_agent"]
    assert set(by_agent) == {"1", "2"}
    one, two = by_agent["1"][-1][1], by_agent["2"][-1][1]
    assert by_agent["1"][-1][0] == 3.0
    assert 0.0 < one < coverage.fraction and 0.0 < two < coverage.fraction
    # both halves are needed for the whole turn, and they share the 150-180 degree views
    assert coverage.fraction <= one + two
    assert 0.0 < snapshot["overlap_fraction"] < 1.0
    known = np.stack([coverage._producer_known[1], coverage._producer_known[2]])
    assert snapshot["overlap_fraction"] == pytest.approx(overlap_fraction(known), abs=1e-4)
    assert json.loads(json.dumps(snapshot))["explored_by_agent"]["2"][0] == [3.0, round(two, 4)]
    assert snapshot["unexplored"] and snapshot["unexplored"][0]["volume_m3"] > 0  # the spins saw part of the box
    ObserverStatus.model_validate(observer_status_data(**coverage.snapshot()))  # it fits the observer's file

    coverage.update(t=5.0)  # nothing new: one more point per producer, same values
    assert [t for t, _ in coverage.snapshot()["explored_by_agent"]["1"]] == [3.0, 5.0]
    assert coverage.snapshot()["explored_by_agent"]["1"][1][1] == one


# --- leader timeline and trajectories ----------------------------------------------------------------------------


def test_clusters_group_fresh_active_agents_by_their_leader() -> None:
    now = 100.0
    agents = {
        1: {"leader": 1, "phase": Phase.FLYING, "last_heard": 99.9},
        2: {"leader": 1, "phase": Phase.FLYING, "last_heard": 99.0},
        3: {"leader": 3, "phase": Phase.FLYING, "last_heard": 98.5},
        4: {"leader": 1, "phase": Phase.FLYING, "last_heard": 97.5},  # silent for 2.5 s: in no cluster
        5: {"leader": 1, "phase": Phase.LANDED, "last_heard": 99.9},
        6: {"leader": 6, "phase": Phase.FAILED, "last_heard": 99.9},
        7: {"heartbeats": 0, "alive": True},  # joined, never heard
    }
    assert clusters_of(agents, now) == [(1, (1, 2)), (3, (3,))]


def test_leader_timeline_records_a_split_and_the_merge_back_once_each() -> None:
    timeline = LeaderTimeline()
    together = [(1, (1, 2, 3))]
    split = [(1, (1, 2)), (3, (3,))]
    assert timeline.update(0.5, together)
    assert not timeline.update(1.0, together)
    assert timeline.update(1.5, split)
    assert not timeline.update(2.0, list(reversed(split)))  # same clusters, other order: no change
    assert timeline.update(2.5, together)
    assert timeline.entries == [
        {"t": 0.5, "leader": 1, "members": [1, 2, 3]},
        {"t": 1.5, "leader": 1, "members": [1, 2]},
        {"t": 1.5, "leader": 3, "members": [3]},
        {"t": 2.5, "leader": 1, "members": [1, 2, 3]},
    ]


class FakeClock:
    def __init__(self, t: float) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


def _heartbeat(agent: int, leader: int, seq: int, x: float, phase: Phase = Phase.FLYING) -> AgentState:
    return AgentState(
        id=agent,
        epoch=1,
        seq=seq,
        t=1000.0,
        position=(x, 2.0 * agent, 1.23456),
        velocity=(0.0, 0.0, 0.0),
        yaw_deg=0.0,
        flight_mode="OFFBOARD",
        phase=phase,
        role="leader" if leader == agent else "explorer",
        leader=leader,
    )


def test_observer_builds_leaders_and_trajectories_from_heartbeats(monkeypatch: pytest.MonkeyPatch) -> None:
    clock = FakeClock(1000.0)
    monkeypatch.setattr(observer_module.time, "time", clock)
    observer = Observer(load_config(None, {}), Path("unused.json"))

    def tick(beats: list[tuple[int, int, str]]) -> None:
        """0.2 s of heartbeats at 5 Hz, then the snapshot's leader update."""
        clock.t += 0.2
        for agent, leader, phase in beats:
            observer._on_state("k", _heartbeat(agent, leader, int(clock.t * 10), clock.t - 1000.0, phase))
        observer._follow_leaders()

    for _ in range(5):
        tick([(1, 1, Phase.FLYING), (2, 1, Phase.FLYING), (3, 1, Phase.FLYING)])
    for _ in range(5):  # drone 3 loses the others and leads itself
        tick([(1, 1, Phase.FLYING), (2, 1, Phase.FLYING), (3, 3, Phase.FLYING)])
    for _ in range(5):  # back together
        tick([(1, 1, Phase.FLYING), (2, 1, Phase.FLYING), (3, 1, Phase.FLYING)])
    for _ in range(15):  # drone 2 lands; drone 3 goes silent and drops out after 2 s
        tick([(1, 1, Phase.FLYING), (2, 1, Phase.LANDED)])

    pairs = [(e["leader"], e["members"]) for e in observer.leaders.entries]
    assert pairs == [(1, [1, 2, 3]), (1, [1, 2]), (3, [3]), (1, [1, 2, 3]), (1, [1, 3]), (1, [1])]
    times = [e["t"] for e in observer.leaders.entries]
    assert times == sorted(times) and times[1] == times[2]  # the split is one state: two entries, one t
    assert times[-1] - times[-2] == pytest.approx(2.0, abs=0.21)  # drone 3 dropped 2 s after its last beat

    samples = observer.trajectories.snapshot()
    assert set(samples) == {"1", "2", "3"}
    ts = [s[0] for s in samples["1"]]
    assert all(b - a >= 0.5 - 1e-9 for a, b in zip(ts, ts[1:]))  # thinned: 30 beats -> one per 0.5 s at most
    assert 10 <= len(ts) <= 13
    assert samples["1"][0][1:] == [round(ts[0], 3), 2.0, 1.235]


def test_a_connecting_agents_heartbeats_are_not_trajectory_samples(monkeypatch: pytest.MonkeyPatch) -> None:
    # before telemetry the heartbeat's position is (0, 0, 0): the plot drew a line from the origin to each spawn
    clock = FakeClock(1000.0)
    monkeypatch.setattr(observer_module.time, "time", clock)
    observer = Observer(load_config(None, {}), Path("unused.json"))
    observer._on_state("k", _heartbeat(1, 1, 1, 0.0, Phase.CONNECTING))
    assert observer.trajectories.snapshot() == {}
    assert observer.agents[1]["phase"] == Phase.CONNECTING  # the heartbeat itself still counts
    clock.t += 1.0
    observer._on_state("k", _heartbeat(1, 1, 2, 3.0, Phase.READY))
    assert [s[1] for s in observer.trajectories.snapshot()["1"]] == [3.0]


def test_trajectories_keep_one_sample_per_half_second_per_agent() -> None:
    tracks = Trajectories()
    kept = [tracks.add(1, t, (t, 0.0, 1.0)) for t in (0.0, 0.2, 0.49, 0.5, 0.9, 1.1)]
    assert kept == [True, False, False, True, False, True]
    assert tracks.add(2, 0.2, (0.0, 0.0, 1.0))  # agents are thinned independently
    assert tracks.snapshot()["1"] == [[0.0, 0.0, 0.0, 1.0], [0.5, 0.5, 0.0, 1.0], [1.1, 1.1, 0.0, 1.0]]


# --- plot data ---------------------------------------------------------------------------------------------------


def test_leader_segments_follow_the_states_until_the_next_change() -> None:
    leaders = [
        {"t": 1.0, "leader": 1, "members": [1, 2, 3]},
        {"t": 4.0, "leader": 1, "members": [1, 2]},
        {"t": 4.0, "leader": 3, "members": [3]},
        {"t": 9.0, "leader": 1, "members": [1, 2, 3]},
    ]
    segments = leader_segments(leaders, end_t=12.0)
    assert segments[1] == [(1.0, 12.0, 1)]  # merged: it followed itself all along
    assert segments[3] == [(1.0, 4.0, 1), (4.0, 9.0, 3), (9.0, 12.0, 1)]


def test_received_rate_differences_the_cumulative_counter() -> None:
    t, rate = received_rate([[0.0, 0, 0], [1.0, 10, 2000], [2.0, 20, 2000], [2.0, 20, 2500], [4.0, 30, 6500]])
    assert list(t) == [1.0, 2.0, 4.0]
    assert list(rate) == pytest.approx([2.0, 0.0, 2.0])  # the zero-length interval is dropped


def test_floor_plan_of_the_box_world_shows_its_walls_stub_and_pillar() -> None:
    world = load_world("box")
    lo, hi = world.bounds
    plan = floor_plan(world, lo, hi, float(world.default_start[2]) + 1.0)
    assert plan.solid.shape == (round((hi[1] - lo[1]) / 0.1), round((hi[0] - lo[0]) / 0.1))
    assert plan.extent == pytest.approx((0.0, 8.0, 0.0, 6.0))

    def at(x: float, y: float) -> bool:
        return bool(plan.solid[int(y / 0.1), int(x / 0.1)])

    assert plan.solid[0, :].all() and plan.solid[-1, :].all() and plan.solid[:, 0].all()  # the outer walls
    assert at(4.07, 4.5) and at(6.0, 1.5)  # the wall stub x 4.0-4.15, y 3-5.85; the pillar at (6, 1.5)
    assert not at(2.0, 3.0) and not at(4.07, 2.0)  # the start; beside the stub's end
    assert 0.0 < plan.solid.mean() < 0.3


def test_a_figure_without_data_is_skipped(tmp_path: Path) -> None:
    assert plot_explored([], {}, tmp_path / "explored.png") is None
    assert not (tmp_path / "explored.png").exists()


# --- whole report: figures and page -------------------------------------------------------------------------------


def _synthetic_run(tmp_path: Path) -> tuple[dict[str, Any], dict[str, Any], dict[int, dict[str, Any]]]:
    world = load_world("box")
    lo, hi = world.bounds
    sx, sy, sz = world.default_start
    timeline = [[2.0 * i, min(1.0, 0.1 * i)] for i in range(12)]
    leaders = [
        {"t": 0.5, "leader": 1, "members": [1, 2]},
        {"t": 6.0, "leader": 1, "members": [1]},
        {"t": 6.0, "leader": 2, "members": [2]},
        {"t": 12.0, "leader": 1, "members": [1, 2]},
    ]
    by_agent = {"1": [[t, f * 0.6] for t, f in timeline], "2": [[t, f * 0.55] for t, f in timeline]}
    observer = observer_status_data(
        t=23.0,
        explored_timeline=timeline,
        explored_by_agent=by_agent,
        overlap_fraction=0.1234,
        leaders=leaders,
        trajectories={
            str(k): [[0.5 * i, sx + 0.1 * i * (1 if k == 1 else -1), sy + 0.05 * i, sz + 1.0] for i in range(30)]
            for k in (1, 2)
        },
    )
    summaries = {
        k: agent_summary_data(k, timeline=[[float(i), 100 * i, 1500 * i * k + (i % 3) * 200] for i in range(20)])
        for k in (1, 2)
    }
    report = mission_report_data(
        status="complete",
        reason="every drone explored and landed",
        world="box",
        drones=2,
        duration_s=23.4,
        collisions=0,
        explored_fraction=1.0,
        explored_timeline=timeline,
        time_to=time_to(timeline),
        explored_by_agent=by_agent,
        overlap_fraction=0.1234,
        leaders=leaders,
        converged=True,
        bandwidth={
            "bytes_per_agent_s": 4321.5,
            "whole_map_baseline_bytes_per_agent_s": 74548.0,
            "baseline_ratio": 17.25,
            "baseline_loop_s": 2.0,
            "agent_seconds": 46.8,
        },
        agents=[
            agent_row_data(
                k,
                distance_m=12.5 * k,
                patches_sealed=7,
                patches_held=14,
                targets_assigned=3 * k,
                targets_self_selected=k - 1,
                landed=True,
                exit_code=0,
            )
            for k in (1, 2)
        ],
        mission={
            "name": "synthetic",
            "seed": 1,
            "max_time_s": 300.0,
            "volume": {"min": [float(v) for v in lo], "max": [float(v) for v in hi]},
            "spawns": [[sx, sy, sz]],
            "world": "box",
            "strategy": "coordinated",
        },
        plots=[],
        report_page=None,
    )
    return report, observer, summaries


def _models(
    report: dict[str, Any], observer: dict[str, Any], summaries: dict[int, dict[str, Any]]
) -> tuple[MissionReport, ObserverStatus, dict[int, AgentSummary]]:
    return (
        MissionReport.model_validate(report),
        ObserverStatus.model_validate(observer),
        {k: AgentSummary.model_validate(s) for k, s in summaries.items()},
    )


def test_write_plots_writes_four_non_empty_pngs(tmp_path: Path) -> None:
    report, observer, summaries = _models(*_synthetic_run(tmp_path))
    names = write_plots(tmp_path, report, observer, summaries)
    assert names == list(PLOT_NAMES)
    for name in names:
        data = (tmp_path / name).read_bytes()
        assert data.startswith(PNG_MAGIC) and len(data) > 5000, name


def test_write_plots_skips_figures_without_data(tmp_path: Path) -> None:
    report, _, _ = _synthetic_run(tmp_path)
    report.update(explored_timeline=[], explored_by_agent={}, leaders=[])
    assert write_plots(tmp_path, MissionReport.model_validate(report), None, {}) == []
    assert not list(tmp_path.glob("*.png"))


def test_report_page_has_the_headline_numbers_and_image_links(tmp_path: Path) -> None:
    report, _, _ = _synthetic_run(tmp_path)
    report["plots"] = list(PLOT_NAMES)
    text = write_report_page(tmp_path, MissionReport.model_validate(report)).read_text()
    assert text.startswith("# Exploration report: box, 2 drones, strategy coordinated")
    assert "complete" in text and "every drone explored and landed" in text
    assert "| duration | 23.4 s |" in text
    assert "| explored fraction | 1.000 |" in text
    assert "| time to 50% | 10.0 s |" in text and "| time to 99% | 20.0 s |" in text
    assert "| overlap fraction | 0.123 |" in text
    assert "| converged | yes |" in text
    assert "4321.5" in text and "17.25x" in text
    assert "| 2 | 25.0 | 7 | 14 | 6 | 1 | yes | 0 |" in text  # drone 2's row
    assert "- 6.0 s: drone 2 leads 2" in text
    for name in PLOT_NAMES:
        assert f"![]({name})" in text


def test_report_html_is_the_same_page_with_its_figures_inline_and_agent_text_escaped(tmp_path: Path) -> None:
    report, observer, summaries = _models(*_synthetic_run(tmp_path))
    report.reason = "drone 2 said <script>alert(1)</script>"
    finish_report(tmp_path, report, observer, summaries)
    page = (tmp_path / "report.html").read_text()
    assert page.startswith("<!DOCTYPE html>") and "<title>Exploration report: box, 2 drones" in page
    assert "<td>explored fraction</td>" in page and "<td>1.000</td>" in page
    for name in PLOT_NAMES:
        png = base64.b64encode((tmp_path / name).read_bytes()).decode()
        assert f'src="data:image/png;base64,{png}"' in page, name
    assert "<script>" not in page and "&lt;script&gt;alert(1)&lt;/script&gt;" in page


def test_report_page_lists_twenty_leader_entries_and_counts_the_rest(tmp_path: Path) -> None:
    report, _, _ = _synthetic_run(tmp_path)
    report["leaders"] = [{"t": float(i), "leader": 1, "members": [1]} for i in range(25)]
    text = write_report_page(tmp_path, MissionReport.model_validate(report)).read_text()
    assert "- 19.0 s: drone 1 leads 1" in text and "- 20.0 s:" not in text
    assert "5 more entries" in text


def test_write_report_renders_figures_and_page_from_the_run_directory(tmp_path: Path) -> None:
    report, observer, summaries = _synthetic_run(tmp_path)
    (tmp_path / "observer.json").write_text(json.dumps(observer))
    (tmp_path / "agents").mkdir()
    for k, summary in summaries.items():
        (tmp_path / "agents" / f"agent-{k}.json").write_text(json.dumps(summary))
    write_report(tmp_path, MissionReport.model_validate(report))
    written = json.loads((tmp_path / "report.json").read_text())
    assert written["plots"] == list(PLOT_NAMES) and written["report_page"] == "report.md"
    assert "plots_error" not in written
    assert "![](trajectories.png)" in (tmp_path / "report.md").read_text()


def test_a_plotting_failure_is_recorded_not_raised(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from swarm.mission import report as report_module

    def broken(*args: Any) -> list[str]:
        raise RuntimeError("no fonts")

    monkeypatch.setattr(report_module, "write_plots", broken)
    report, observer, summaries = _models(*_synthetic_run(tmp_path))
    finish_report(tmp_path, report, observer, summaries)
    assert report.plots_error == "RuntimeError: no fonts"
    assert report.plots == [] and report.report_page == "report.md"
    assert json.loads(report.to_json())["plots_error"] == "RuntimeError: no fonts"
    assert (tmp_path / "report.md").exists()


# --- where the swarm did not go --------------------------------------------------------------------------------


def test_unexplored_regions_are_the_largest_unknown_pieces_of_reachable_space_with_their_boxes() -> None:
    mask = np.ones((10, 4, 2), dtype=bool)
    mask[5, :, :] = False  # a wall splitting the reachable space in two
    space = ReachableSpace(np.array([1.0, 0.0, 0.0]), 0.5, mask, np.zeros((int(mask.sum()), 3)))
    unknown = np.zeros(mask.shape, dtype=bool)
    unknown[6:10, 1:3, :] = True  # 16 cells (2 m3) east of the wall
    unknown[0, 0, 0] = True  # a speck of 0.125 m3
    unknown[2, 3, 1] = True
    known = ~unknown[mask]
    regions = unexplored_regions(space, known, keep=5)
    assert regions[0] == {"volume_m3": 2.0, "lo": [4.0, 0.5, 0.0], "hi": [6.0, 1.5, 1.0]}
    assert [r["volume_m3"] for r in regions] == [2.0, 0.12, 0.12]
    assert unexplored_regions(space, known, keep=1) == regions[:1]
    assert unexplored_regions(space, np.ones(int(mask.sum()), dtype=bool)) == []


def test_a_mission_below_its_coverage_target_names_the_largest_unexplored_part() -> None:
    agents = [AgentRow.model_validate(agent_row_data(exploration_done_reason="leader 1: no reachable frontier"))]
    region = UnexploredRegion(volume_m3=37.6, lo=(0.5, 8.9, 3.9), hi=(10.7, 11.5, 6.7))
    reason = _why_short(0.9335, agents, [region])
    assert reason.startswith("exploration ended at 93.3 % explored, below 95%: leader 1: no reachable frontier;")
    assert reason.endswith(
        "the largest unexplored part: 37.6 m3 in x 0.5-10.7, y 8.9-11.5, z 3.9-6.7 (observer.json unexplored)"
    )
    assert "unexplored" not in _why_short(0.9335, agents)


def test_an_agents_defences_sum_its_bus_drops_over_kinds_and_leave_out_the_zeros(tmp_path: Path) -> None:
    traffic = {
        kind: {"sent_msgs": 1, "sent_bytes": 1, "recv_msgs": 9, "recv_bytes": 9, "dropped": dropped}
        for kind, dropped in (("state", {"invalid": 2, "rate": 5}), ("patch_chunk", {"invalid": 1, "backlog": 0}))
    }
    summary = AgentSummary.model_validate(
        agent_summary_data(
            3, traffic=traffic, exploration_rejected={"gain_clamped": 4, "visited_off_track": 0}, frames=10
        )
    )
    defences = defences_of(summary)
    assert defences.bus_dropped == {"invalid": 3, "rate": 5}
    assert defences.exploration_rejected == {"gain_clamped": 4}
    assert defences.patch_store_failures == {} and defences.sync_limits == {}
    assert defences_of(None) == Defences()

    report, _, _ = _synthetic_run(tmp_path)
    report["agents"][1]["defences"] = defences.model_dump()
    text = write_report_page(tmp_path, MissionReport.model_validate(report)).read_text()
    assert "- drone 2: exploration rejected: gain_clamped 4; bus dropped: invalid 3, rate 5" in text
    assert "- drone 1" not in text


def test_a_report_written_before_the_defences_were_counted_still_reads() -> None:
    row = agent_row_data(1)
    assert "defences" not in row
    assert AgentRow.model_validate(row).defences == Defences()
