"""Typed files between processes: written and read through the same model, and a bad file is one clear line."""

from __future__ import annotations

from pathlib import Path

import pytest

from swarm.errors import SwarmError
from swarm.files import FileFormatError, FileModel, read_model, write_model


class Example(FileModel):
    count: int
    names: list[str]


def test_a_model_written_is_read_back_equal(tmp_path: Path) -> None:
    path = tmp_path / "example.json"
    write_model(path, Example(count=3, names=["a"]))
    assert read_model(path, Example) == Example(count=3, names=["a"])
    assert [p.name for p in tmp_path.iterdir()] == ["example.json"]  # no temp file left beside it


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ('{"names": []}', "count: Field required"),
        ('{"count": "three", "names": []}', "count: Input should be a valid integer"),
        ('{"count": 1, "names": [], "extra": 0}', "extra: unknown field"),
        ('{"count": 1, "names": [', "not JSON"),
        ("", "not JSON"),
    ],
)
def test_a_file_that_does_not_validate_is_one_line_naming_file_model_and_problem(
    tmp_path: Path, text: str, says: str
) -> None:
    path = tmp_path / "example.json"
    path.write_text(text)
    with pytest.raises(FileFormatError) as caught:
        read_model(path, Example)
    message = str(caught.value)
    assert "\n" not in message
    assert message.startswith(f"{path}: not a valid Example: ")
    assert says in message
    assert isinstance(caught.value, SwarmError)  # the CLI prints it and exits non-zero


def test_a_missing_file_is_not_a_format_error(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError):
        read_model(tmp_path / "absent.json", Example)


def test_the_cli_reports_a_bad_file_as_one_line_and_fails(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from swarm.cli import main
    from swarm.mission import run as run_module
    from swarm.mission.report import read_summary

    (tmp_path / "agents").mkdir()
    (tmp_path / "agents" / "agent-1.json").write_text('{"id": 1}')

    def mission_reading_a_bad_summary(
        config: object, live: bool | None = None, stream_to: str | None = None
    ) -> dict[str, object]:
        read_summary(tmp_path, 1)
        raise AssertionError("an invalid summary was read")

    monkeypatch.setattr(run_module, "run_mission", mission_reading_a_bad_summary)
    assert main(["run", "--out", str(tmp_path / "run")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"swarm run: error: {tmp_path}/agents/agent-1.json: not a valid AgentSummary: epoch: Field required"]
