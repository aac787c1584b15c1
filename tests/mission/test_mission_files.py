"""observer.json and report.json through their models, and report.json's committed JSON Schema."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from swarm.files import FileFormatError, read_model, write_model
from swarm.mission import files as mission_files
from swarm.mission.files import SCHEMA_PATH, MapNodeStatus, MissionReport, ObserverStatus, schema_text
from swarm.mission.report import read_report
from tests.file_models import (
    TRAFFIC,
    mission_report,
    mission_report_data,
    observer_status,
    observer_status_data,
    sync_stats,
)


def test_an_observer_status_round_trips(tmp_path: Path) -> None:
    status = observer_status(explored_fraction=0.5, explored_timeline=[[1.0, 0.5]], reachable_cells=100)
    path = tmp_path / "observer.json"
    write_model(path, status, indent=None)
    back = read_model(path, ObserverStatus)
    assert back == status
    assert back.agents["1"].phase == "flying" and back.agents["1"].holdings is None  # heard, no digest yet


def test_an_observer_status_with_a_wrong_type_is_one_line(tmp_path: Path) -> None:
    path = tmp_path / "observer.json"
    path.write_text(json.dumps(observer_status_data(leader_changes="many")))
    with pytest.raises(FileFormatError, match="not a valid ObserverStatus: leader_changes: Input should be"):
        read_model(path, ObserverStatus)


def test_a_report_round_trips_and_carries_its_schema_version(tmp_path: Path) -> None:
    report = mission_report()
    path = tmp_path / "report.json"
    path.write_text(report.to_json())
    assert read_report(path) == report
    written = json.loads(path.read_text())
    assert written["schema_version"] == 1
    assert "plots_error" not in written  # only when a figure failed
    assert set(written) == set(mission_report_data())


def test_a_report_of_another_schema_version_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "report.json"
    path.write_text(json.dumps(mission_report_data(schema_version=2)))
    with pytest.raises(FileFormatError, match="not a valid MissionReport: schema_version: Input should be 1"):
        read_report(path)


def test_a_report_missing_an_agent_key_is_one_line(tmp_path: Path) -> None:
    data = mission_report_data()
    del data["agents"][0]["patches_held"]
    path = tmp_path / "report.json"
    path.write_text(json.dumps(data))
    with pytest.raises(FileFormatError, match=r"agents\[0\]\.patches_held: Field required"):
        read_report(path)


def test_the_committed_report_schema_is_the_generated_one() -> None:
    assert SCHEMA_PATH.read_text() == schema_text(), "docs/report.schema.json is stale: python -m swarm.mission.files"
    assert json.loads(SCHEMA_PATH.read_text())["properties"]["schema_version"]["const"] == 1
    assert MissionReport.model_json_schema()["additionalProperties"] is False


def test_check_fails_on_a_stale_schema_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    stale = tmp_path / "report.schema.json"
    stale.write_text("{}\n")
    monkeypatch.setattr(mission_files, "SCHEMA_PATH", stale)
    assert mission_files.main(["--check"]) == 1
    assert mission_files.main([]) == 0
    assert mission_files.main(["--check"]) == 0


def test_a_map_node_status_round_trips_and_a_bad_one_is_one_line(tmp_path: Path) -> None:
    status = MapNodeStatus.model_validate(
        {
            "id": 1,
            "epoch": 1,
            "done": False,
            "t": 1_700_000_000.0,
            "sealed": [{"id": "1.1.0", "t": 1_700_000_000.0, "bytes": 2048}],
            "held": ["1.1.0"],
            "held_at": {"1.1.0": 1_700_000_000.0},
            "fused_digest": "",
            "fused_patches": 1,
            "peers": [2],
            "leader": 1,
            "role": "leader",
            "cluster": [1, 2],
            "first_peer_t": None,
            "sync": sync_stats(),
            "traffic": TRAFFIC,
        }
    )
    path = tmp_path / "node-1.json"
    write_model(path, status, indent=None)
    assert read_model(path, MapNodeStatus) == status
    data = status.model_dump()
    data["sealed"][0]["bytes"] = "big"
    path.write_text(json.dumps(data))
    with pytest.raises(FileFormatError, match=r"not a valid MapNodeStatus: sealed\[0\]\.bytes"):
        read_model(path, MapNodeStatus)
