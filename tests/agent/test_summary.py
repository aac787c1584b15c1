"""The agent's summary file: every key always written, read back through the same model."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from swarm.agent.summary import NO_MAPPING, SCRIPTED_EXPLORATION, AgentSummary
from swarm.files import FileFormatError, read_model, write_model
from tests.file_models import agent_summary, agent_summary_data


def test_a_summary_round_trips_with_its_nested_counters(tmp_path: Path) -> None:
    summary = agent_summary(
        sensor_stream={"frames": 40, "not_taken": 2, "pixels_masked_as_peers": 10, "camera_silences": 0},
        frontiers_given_up=[
            {"viewpoint": [1.0, 2.0, 1.0], "point": [2.0, 2.0, 1.0], "reason": "unreachable", "at_s": 3.0}
        ],
        whole_map_baseline={"loop_s": 2.0, "loops": 10, "bytes": 123_000},
    )
    path = tmp_path / "agent-1.json"
    write_model(path, summary)
    back = read_model(path, AgentSummary)
    assert back == summary
    assert back.sync.holdings.entries[0].ranges == [(0, 1)]
    assert back.traffic["state"].recv_bytes == 600
    assert back.frontiers_given_up[0].reason == "unreachable"


def test_an_agent_that_neither_explores_nor_maps_writes_every_key() -> None:
    keys = set(SCRIPTED_EXPLORATION) | set(NO_MAPPING)
    assert keys <= set(AgentSummary.model_fields)
    assert not [name for name, field in AgentSummary.model_fields.items() if not field.is_required()]


@pytest.mark.parametrize(
    ("change", "says"),
    [
        (lambda d: d.pop("sync"), "sync: Field required"),
        (lambda d: d["sync"].pop("patches_held"), "sync.patches_held: Field required"),
        (lambda d: d.update(bytes_received="lots"), "bytes_received: Input should be a valid integer"),
    ],
)
def test_a_summary_missing_a_key_or_of_a_wrong_type_is_one_line(tmp_path: Path, change, says: str) -> None:  # type: ignore[no-untyped-def]
    data = agent_summary_data()
    change(data)
    path = tmp_path / "agent-1.json"
    path.write_text(json.dumps(data))
    with pytest.raises(FileFormatError, match=f"agent-1.json: not a valid AgentSummary: {says}"):
        read_model(path, AgentSummary)
