"""The run's Rerun recording (`swarm.mission.recording`) and its MCAP export (`swarm.mission.export`), unit tier:
pure functions, and a recording written to a file and read back through Rerun's own reader. The recording of a
real mission is checked in tests/mission/test_explore_e2e.py (the leader-kill mission)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from rerun.chunk import RrdReader
from rosbags.highlevel import AnyReader

from swarm.bus.messages import AgentState
from swarm.bus.phase import Phase
from swarm.errors import SwarmError
from swarm.mission.export import export_mcap, stamp_ns
from swarm.mission.recording import (
    MAP_BYTES_PER_S,
    MAP_CPU_SHARE,
    MAP_PERIOD_S,
    RECORDING_NAME,
    TILE_GROWTH_MIN,
    MissionRecording,
    Throttle,
    add_report,
    cluster_text,
    entity_rows,
    entity_spans,
    gain_colors,
    map_period_s,
    map_tiles,
    patches_held,
    recording_ids,
    report_events,
    tile_fingerprint,
    tile_grew,
    tile_path,
    yaw_quaternion,
)
from swarm.mission.rrd_files import BLUEPRINT_NAME, run_recording_id
from swarm.mission.viewer import has_display, run_recordings, viewer_argv
from swarm.patches.digest import PatchDigest
from swarm.patches.meshing import write_ply
from swarm.patches.patch import PatchId
from swarm.roles.messages import FrontierReport, TargetAssignment, as_points
from tests.file_models import agent_summary, mission_report

pytestmark = pytest.mark.unit


def _state(k: int, position: tuple[float, float, float], leader: int = 1, **extra: object) -> AgentState:
    fields: dict[str, object] = {
        "id": k,
        "epoch": 1,
        "seq": 0,
        "t": 1.0,
        "position": position,
        "velocity": (0.0, 0.0, 0.0),
        "yaw_deg": 90.0,
        "flight_mode": "OFFBOARD",
        "phase": Phase.FLYING,
        "role": "leader" if k == leader else "explorer",
        "leader": leader,
    }
    return AgentState.model_validate({**fields, **extra})


def test_run_recording_id_is_one_per_run() -> None:
    a = run_recording_id(Path("runs/x"), 1_700_000_000.1234)
    assert a == run_recording_id(Path("/elsewhere/x"), 1_700_000_000.1234)  # every process of the run agrees
    assert a != run_recording_id(Path("runs/x"), 1_700_000_001.0)
    assert a != run_recording_id(Path("runs/y"), 1_700_000_000.1234)


def test_patches_held_counts_inclusive_ranges() -> None:
    ids = [PatchId(1, 1, s) for s in (0, 1, 2, 5)] + [PatchId(2, 7, 0)]
    assert patches_held(PatchDigest.of(ids).to_wire_model()) == 5
    assert patches_held(PatchDigest.of([]).to_wire_model()) == 0


def test_yaw_quaternion_turns_about_z() -> None:
    x, y, z, w = yaw_quaternion(90.0)
    assert (x, y) == (0.0, 0.0)
    assert z == pytest.approx(math.sqrt(0.5)) and w == pytest.approx(math.sqrt(0.5))
    assert yaw_quaternion(0.0) == (0.0, 0.0, 0.0, 1.0)


def test_gain_colors_run_from_blue_to_red() -> None:
    colors = gain_colors(np.array([0.0, 5.0, 10.0]))
    assert colors.dtype == np.uint8 and colors.shape == (3, 3)
    assert tuple(colors[0]) == (40, 90, 255) and tuple(colors[2]) == (255, 40, 40)
    assert colors[0][0] < colors[1][0] < colors[2][0]
    assert gain_colors(np.zeros(2)).tolist() == [[40, 90, 255]] * 2
    assert gain_colors(np.zeros(0)).shape == (0, 3)


def test_cluster_text_names_each_leader_and_its_members() -> None:
    assert cluster_text([(1, (1, 3)), (2, (2,))]) == "leader 1: 1, 3\nleader 2: 2"
    assert cluster_text([]) == "no cluster"


def test_throttle_lets_one_through_per_period_per_key() -> None:
    throttle = Throttle(0.5)
    assert throttle.ready(1, 0.0) and throttle.ready(2, 0.1)
    assert not throttle.ready(1, 0.4)
    assert throttle.ready(1, 0.5)


def test_large_maps_are_refreshed_less_often() -> None:
    assert map_period_s(10_000, 0.01) == MAP_PERIOD_S
    assert map_period_s(3_000_000, 0.01) == pytest.approx(3_000_000 / MAP_BYTES_PER_S)
    assert map_period_s(10_000, 0.5) == pytest.approx(0.5 / MAP_CPU_SHARE)


def _two_squares() -> tuple[np.ndarray, np.ndarray]:
    """Two unit squares (two triangles each), one at the origin and one 3 m along x: two 2 m tiles."""
    square = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    vertices = np.vstack([square + 0.1, square + [3.1, 0, 0]])
    triangles = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    return vertices, triangles


def test_map_tiles_cut_the_mesh_into_cubes_with_their_own_vertices() -> None:
    vertices, triangles = _two_squares()
    tiles = map_tiles(vertices, triangles, tile_m=2.0)
    assert sorted(tiles) == [(0, 0, 0), (1, 0, 0)]
    tile_vertices, tile_triangles = tiles[(1, 0, 0)]
    assert tile_vertices.dtype == np.float32 and tile_triangles.dtype == np.uint32
    assert len(tile_vertices) == 4 and tile_triangles.max() == 3
    assert np.allclose(tile_vertices[tile_triangles], vertices[triangles[2:]])  # the same triangles
    assert map_tiles(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int32)) == {}
    assert tile_path((1, -2, 0)) == "map/t1_-2_0"


def test_a_tile_is_logged_again_when_it_grew_or_shrank_enough() -> None:
    assert tile_grew(None, 5)
    assert not tile_grew(100, 100 + TILE_GROWTH_MIN) and tile_grew(100, 100 + TILE_GROWTH_MIN + 1)
    assert not tile_grew(1000, 1100) and tile_grew(1000, 1101) and tile_grew(1000, 899)


def test_a_tile_fingerprint_ignores_order_and_sees_change() -> None:
    vertices, triangles = _two_squares()
    v, t = map_tiles(vertices, triangles)[(0, 0, 0)]
    shuffled = v[::-1].copy(), (len(v) - 1 - t)[::-1].copy()  # the same surface, listed backwards
    assert tile_fingerprint(*shuffled) == tile_fingerprint(v, t)
    moved = v.copy()
    moved[0, 2] += 0.01
    assert tile_fingerprint(moved, t) != tile_fingerprint(v, t)


def test_a_refresh_logs_only_the_tiles_that_changed(tmp_path: Path) -> None:
    path = tmp_path / RECORDING_NAME
    recording = MissionRecording(path, "run-1")
    vertices, triangles = _two_squares()
    assert recording.map(1.0, vertices, triangles) > 0
    assert recording.map(2.0, vertices, triangles) == 0  # nothing changed
    moved = vertices.copy()
    moved[4:, 2] += 0.05  # the second square moved up: refined in place, not logged again until the end
    assert recording.map(3.0, moved, triangles) == 0
    assert recording.map(3.5, moved, triangles, exact=True) == 4 * 12 + 2 * 12
    recording.map(4.0, vertices[:4], triangles[:2])  # the second square gone
    recording.close()
    spans = entity_spans([path])
    assert spans["/map/t0_0_0"].rows == 1
    assert spans["/map/t1_0_0"].rows == 3 and spans["/map/t1_0_0"].last_s == 4.0  # logged, changed, cleared


def test_report_events_hold_faults_links_partitions_and_the_end() -> None:
    report = mission_report(
        duration_s=40.0,
        faults=[
            {
                "fault": "kill:agent=1@6",
                "kind": "kill",
                "agent": 1,
                "at": 6.0,
                "duration": None,
                "takeoff_t": 9.0,
                "actions": [{"t": 15.0, "wall_t": 1.0, "agent": 1, "step": "start", "result": "killed (exit -9)"}],
            }
        ],
        impairments=[{"t": 12.0, "at": 3.0, "link": "1-2", "profile": "loss 30%"}],
        partitions=[{"start": 20.0, "end": 25.0, "components": [[1], [2, 3]]}],
    )
    events = report_events(report)
    assert [e.t for e in events] == [12.0, 15.0, 20.0, 25.0, 40.0]
    assert events[1].text == "fault kill:agent=1@6: start: killed (exit -9)" and events[1].level == "WARN"
    assert events[2].text == "partition: 1 | 2,3" and events[2].level == "ERROR"
    assert events[-1].text.startswith("mission complete")


def _record(path: Path) -> None:
    recording = MissionRecording(path, "run-1")
    recording.world(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]]))
    for i in range(11):  # 0.5 s apart: every one passes the pose throttle
        t = 1.0 + 0.5 * i
        recording.state(t, _state(1, (float(i), 0.0, 1.0), heading_to=(9.0, 0.0, 1.0)))
        recording.state(t, _state(2, (0.0, float(i), 1.0)))
    recording.clusters(1.0, [(1, (1, 2))])
    frontiers = FrontierReport(
        id=2,
        epoch=1,
        seq=3,
        position=(0.0, 0.0, 1.0),
        viewpoints=as_points([(1, 1, 1), (2, 2, 1)]),
        points=as_points([(1, 2, 1), (2, 3, 1)]),
        gains=np.array([3.0, 9.0], dtype=np.float32),
    )
    recording.frontiers(2.0, frontiers)
    assignment = TargetAssignment(
        leader=1,
        epoch=1,
        round=1,
        members=[1, 2],
        drones=[2],
        viewpoints=as_points([(2, 2, 1)]),
        points=as_points([(2, 3, 1)]),
    )
    recording.targets(2.5, assignment)
    recording.explored(3.0, 0.4, {1: 0.3, 2: 0.2})
    assert recording.map_due(3.0, version=1)
    recording.map(3.0, np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]]), version=1)
    assert not recording.map_due(3.0 + MAP_PERIOD_S, version=1)  # unchanged map: not logged again
    assert not recording.map_due(3.5, version=2)  # changed, too soon
    assert recording.map_due(3.0 + MAP_PERIOD_S, version=2)
    recording.event(4.0, "agent 2 left", "WARN")
    recording.close()


def test_a_recording_reads_back_with_its_entities_and_times(tmp_path: Path) -> None:
    path = tmp_path / RECORDING_NAME
    _record(path)
    assert recording_ids(path) == ["run-1"]
    spans = entity_spans([path])
    for entity in ("/world", "/drones/1/pose", "/drones/2/pose", "/drones/1/trajectory", "/drones/1/segment"):
        assert entity in spans, sorted(spans)
    assert spans["/world"].first_s is None  # static
    assert spans["/drones/1/pose"].rows == 11
    assert (spans["/drones/1/pose"].first_s, spans["/drones/1/pose"].last_s) == (1.0, 6.0)
    for entity in ("/frontiers/2", "/drones/2/target", "/swarm/clusters", "/series/explored/swarm", "/map/t0_0_0"):
        assert spans[entity].rows == 1, entity
    assert spans["/series/leader/2"].rows == 11
    [(t, [position])] = entity_rows([path], "/drones/2/target", "Points3D:positions")
    assert t == 2.5 and position == pytest.approx([2.0, 2.0, 1.0])
    [(_, gains)] = entity_rows([path], "/frontiers/2", "gain")
    assert gains == pytest.approx([3.0, 9.0])
    translations = entity_rows([path], "/drones/1/pose", "Transform3D:translation")
    assert [row[0][0] for _, row in translations] == pytest.approx([float(i) for i in range(11)])


def test_the_harness_part_merges_into_the_observers_recording(tmp_path: Path) -> None:
    _record(tmp_path / RECORDING_NAME)
    report = mission_report(duration_s=6.5)
    path = add_report(tmp_path, "run-1", report, {1: agent_summary(1, frame_rate_hz=9.5)})
    assert path == tmp_path / RECORDING_NAME
    assert recording_ids(path) == ["run-1"]
    spans = entity_spans([path])
    assert spans["/drones/1/pose"].rows == 11  # the observer's part is all there
    assert spans["/series/bytes_sent/1"].rows == 5
    assert spans["/events"].rows == 2  # the observer's "agent 2 left" and the harness's end of mission
    assert [v for _, v in entity_rows([path], "/series/frame_rate_hz/1", "Scalars:scalars")] == [[9.5]]
    assert sorted(p.name for p in tmp_path.iterdir()) == [BLUEPRINT_NAME, RECORDING_NAME]  # no part left behind
    [blueprint] = RrdReader(tmp_path / BLUEPRINT_NAME).blueprints()
    assert blueprint.application_id == "swarm"  # the layout the viewer opens the run with


def test_without_the_observers_recording_the_harness_part_is_the_recording(tmp_path: Path) -> None:
    path = add_report(tmp_path, "run-2", mission_report(), {})
    assert recording_ids(path) == ["run-2"]
    assert "/events" in entity_spans([path])


def _run_dir(tmp_path: Path) -> Path:
    run = tmp_path / "run"
    run.mkdir()
    _record(run / RECORDING_NAME)
    (run / "report.json").write_text(mission_report(duration_s=6.5).to_json())
    write_ply(
        run / "map.ply", np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]), np.array([[0, 1, 2], [0, 2, 3]])
    )
    return run


def test_the_mcap_export_opens_with_rosbags(tmp_path: Path) -> None:
    run = _run_dir(tmp_path)
    bag = tmp_path / "bag"
    counts = export_mcap(run, bag)
    expected = {
        "/drone1/odom": 11,
        "/drone2/odom": 11,
        "/drone1/path": 1,
        "/drone2/path": 1,
        "/drone2/target": 1,
        "/map": 1,
    }
    assert counts == expected
    with AnyReader([bag]) as reader:
        topics = {c.topic: (c.msgtype, c.msgcount) for c in reader.connections}
        assert {t: n for t, (_, n) in topics.items()} == expected
        assert topics["/drone1/odom"][0] == "nav_msgs/msg/Odometry"
        assert topics["/map"][0] == "sensor_msgs/msg/PointCloud2"
        started = mission_report().started_at
        odom = [c for c in reader.connections if c.topic == "/drone1/odom"]
        stamps, xs = [], []
        for connection, t_ns, raw in reader.messages(connections=odom):
            message = reader.deserialize(raw, connection.msgtype)
            stamps.append(t_ns)
            xs.append(message.pose.pose.position.x)
        assert stamps[0] == stamp_ns(started, 1.0) and stamps == sorted(stamps)
        assert xs == pytest.approx([float(i) for i in range(11)])
        [(connection, _, raw)] = list(reader.messages(connections=[c for c in reader.connections if c.topic == "/map"]))
        cloud = reader.deserialize(raw, connection.msgtype)
        assert cloud.width == 4 and cloud.point_step == 12
        points = np.frombuffer(bytes(cloud.data), dtype="<f4").reshape(-1, 3)
        assert points.tolist() == [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]


def test_the_export_refuses_a_directory_without_a_run_and_an_existing_bag(tmp_path: Path) -> None:
    with pytest.raises(SwarmError, match="no report.json"):
        export_mcap(tmp_path, tmp_path / "bag")
    run = _run_dir(tmp_path)
    (tmp_path / "bag").mkdir()
    with pytest.raises(SwarmError, match="already exists"):
        export_mcap(run, tmp_path / "bag")


def test_the_viewer_opens_every_recording_of_a_run_and_binds_to_loopback(tmp_path: Path) -> None:
    with pytest.raises(SwarmError, match="no such run directory"):
        run_recordings(tmp_path / "nope")
    with pytest.raises(SwarmError, match="no recording"):
        run_recordings(tmp_path)
    (tmp_path / "agents").mkdir()
    for path in (tmp_path / RECORDING_NAME, tmp_path / "agents" / "agent-1.rrd"):
        path.write_bytes(b"")
    (tmp_path / BLUEPRINT_NAME).write_bytes(b"")
    paths = run_recordings(tmp_path)
    assert paths == [tmp_path / "agents" / "agent-1.rrd", tmp_path / RECORDING_NAME, tmp_path / BLUEPRINT_NAME]
    argv = viewer_argv(Path("/bin/rerun"), paths, web_port=9090)
    assert argv[:3] == ["/bin/rerun", "--bind", "127.0.0.1"]
    assert "--web-viewer" in argv and argv[-3:] == [str(p) for p in paths]
    assert "--web-viewer" not in viewer_argv(Path("/bin/rerun"), paths)
    assert not has_display({}) and has_display({"DISPLAY": ":0"})


def test_the_report_page_says_how_to_open_the_recording(tmp_path: Path) -> None:
    from swarm.mission.report_md import render_report_page, write_report_page

    report = mission_report(run_dir="runs/r1")
    assert "swarm view runs/r1" in render_report_page(report, recording=True)
    assert "## Recording" not in render_report_page(report)
    assert "## Recording" not in write_report_page(tmp_path, report).read_text()
    (tmp_path / RECORDING_NAME).write_bytes(b"")
    assert "swarm view runs/r1" in write_report_page(tmp_path, report).read_text()


def test_a_live_viewer_is_one_swarm_run_starts_on_loopback_or_one_named_by_its_url(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from swarm.mission import viewer

    running = viewer.LiveViewer("rerun+http://127.0.0.1:9999/proxy")
    assert running.url == "rerun+http://127.0.0.1:9999/proxy" and running.start().process is None
    assert running.wait() == 0
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_SOCKET", raising=False)
    with pytest.raises(SwarmError, match="no display for --view"):
        viewer.LiveViewer("native")
    checked: list[tuple[str, int]] = []
    monkeypatch.setattr(viewer, "ensure_free", lambda host, port, kind, what: checked.append((host, port)))
    monkeypatch.setattr(viewer, "find_free_base", lambda host, count, kind, start, step: start + 1)
    web = viewer.LiveViewer("web", web_port=9191)
    assert checked == [("127.0.0.1", 9191)]
    assert web.url == "rerun+http://127.0.0.1:9877/proxy"
    argv = web.argv()
    assert argv[1:5] == ["--bind", "127.0.0.1", "--port", "9877"]
    assert argv[-3:] == ["--serve-web", "--web-viewer-port", "9191"]
    assert "rerun%2Bhttp%3A%2F%2F127.0.0.1%3A9877%2Fproxy" in web.describe()
    assert viewer.viewer_env()["CI"] == "1"  # Rerun's viewer sends no usage data


def test_a_web_viewer_opens_the_systems_browser_only_where_there_is_a_display(monkeypatch: pytest.MonkeyPatch) -> None:
    from swarm.mission import viewer

    for name in (*viewer.DISPLAY_VARIABLES, "BROWSER"):
        monkeypatch.delenv(name, raising=False)
    assert viewer.viewer_env()["BROWSER"] == "true"  # Rerun runs `true URL` instead of a browser
    assert viewer.viewer_env(open_browser=False)["BROWSER"] == "true"
    assert "BROWSER" not in viewer.viewer_env(open_browser=True)
    monkeypatch.setenv("DISPLAY", ":0")
    assert "BROWSER" not in viewer.viewer_env()


@pytest.mark.parametrize("view", ["native", "web", "rerun+http://127.0.0.1:9876/proxy", None])
def test_mission_view_takes_a_mode_or_a_viewers_url(view: str | None) -> None:
    from swarm.config import load_config

    assert load_config(overrides={"mission.view": view}).mission.view == view


def test_a_mission_view_that_is_neither_is_one_clear_error() -> None:
    from swarm.config import ConfigError, load_config

    with pytest.raises(ConfigError, match="mission.view.*native or web or a viewer's rerun"):
        load_config(overrides={"mission.view": "http://127.0.0.1:9090"})
