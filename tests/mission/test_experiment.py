"""`swarm experiment dropout` without missions: the scenarios it writes, the rows and table it computes from
reports, its figure, how it carries on past a failed condition, and the inputs it refuses. `run` is a fake."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from rich.console import Console

from swarm.config import ConfigError, SwarmConfig, load_config
from swarm.errors import SwarmError
from swarm.mission import experiment as ex
from swarm.mission.experiment_plot import plot_dropout, x_positions
from swarm.mission.run import INTERRUPTED
from swarm.netem.scenario import load_scenario

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def config(drones: int = 3, **mission: Any) -> SwarmConfig:
    overrides = {"mission.drones": drones, "mission.world": "box", **{f"mission.{k}": v for k, v in mission.items()}}
    return load_config(None, overrides)


def report(
    status: str = "complete",
    duration: float = 100.0,
    explored: float = 0.97,
    t95: float | None = 80.0,
    converged: bool = True,
    bps: float = 4000.0,
    leader_changes: int = 1,
    heals: list[float | None] | None = None,
) -> dict[str, Any]:
    return {
        "status": status,
        "reason": "" if status == "complete" else f"it went {status}",
        "duration_s": duration,
        "explored_fraction": explored,
        "converged": converged,
        "time_to": {"0.5": 10.0, "0.95": t95},
        "bandwidth": {"bytes_per_agent_s": bps},
        "collisions": 0,
        "agents": [{"id": k, "bytes_received": 1000 * k} for k in (1, 2, 3)],
        "leader_changes": leader_changes,
        "convergence_after_heal_s": [{"heal_t": 50.0, "members": [1, 2, 3], "s": s} for s in heals or []],
        "impairments": [{"t": 0.0}],
        "partitions": [],
    }


class FakeRun:
    """Stands in for run_mission: records each config, answers from a table of condition name -> report/error."""

    def __init__(self, answers: dict[str, dict[str, Any] | Exception]) -> None:
        self.answers = answers
        self.configs: list[SwarmConfig] = []

    def __call__(self, cfg: SwarmConfig, live: bool | None = None) -> dict[str, Any]:
        assert live is False
        self.configs.append(cfg)
        name = Path(cfg.mission.out).name
        assert Path(cfg.mission.links).is_file()  # type: ignore[attr-defined]
        answer = self.answers.get(name, report())
        if isinstance(answer, Exception):
            raise answer
        Path(cfg.mission.out).mkdir(parents=True)
        return answer | {"run_dir": str(cfg.mission.out)}


# --- conditions and scenarios ------------------------------------------------------------------------------------


def test_scenarios_load_and_hold_the_right_events(tmp_path: Path) -> None:
    found = ex.conditions([0.0, 0.1, 0.3, 0.5], True, 3, 20.0, 50.0)
    assert [c.name for c in found] == ["loss-0", "loss-10", "loss-30", "loss-50", "cut-heal"]
    assert [c.baseline for c in found] == [True, False, False, False, False]
    paths = ex.write_scenarios(found, tmp_path, 3)
    assert set(paths) == {c.name for c in found} and all(p.parent == tmp_path for p in paths.values())
    baseline = load_scenario(paths["loss-0"])
    assert baseline.name == "loss-0" and baseline.events == []
    for level in (10, 30, 50):
        [event] = load_scenario(paths[f"loss-{level}"]).events
        assert (event.at, event.link, event.loss, event.cut, event.restore) == (0.0, "all", level / 100, None, False)
    cut, heal = load_scenario(paths["cut-heal"]).events
    assert (cut.at, cut.link, cut.cut, cut.loss) == (20.0, "3", True, None)
    assert (heal.at, heal.link, heal.restore) == (50.0, "3", True)


def test_the_baseline_is_always_run_and_levels_are_sorted_once_each() -> None:
    found = ex.conditions([0.3, 0.05, 0.3], False, 2, 20.0, 50.0)
    assert [(c.name, c.loss) for c in found] == [("loss-0", 0.0), ("loss-5", 0.05), ("loss-30", 0.3)]
    assert found[0].label == "0 % loss (baseline)"


def test_condition_config_runs_on_the_virtual_radio_with_its_links(tmp_path: Path) -> None:
    base = config()
    cfg = ex.condition_config(base, tmp_path / "loss-10", tmp_path / "loss-10.toml")
    assert cfg.mission.out == tmp_path / "loss-10"
    assert cfg.mission.network == "netns"  # type: ignore[attr-defined]
    assert cfg.mission.links == tmp_path / "loss-10.toml"  # type: ignore[attr-defined]
    assert cfg.mission.world == "box" and cfg.mission.drones == 3
    assert base.mission.out is None and cfg.agent is not base.agent  # the experiment's config is untouched


# --- rows and table ------------------------------------------------------------------------------------------------


def rows_for(reports: dict[str, dict[str, Any] | None], cut: bool = True) -> list[dict[str, Any]]:
    found = ex.conditions([0.0, 0.1, 0.5], cut, 3, 20.0, 50.0)
    rows = [ex.make_row(c, Path(c.name), Path(f"{c.name}.toml"), reports.get(c.name), "boom") for c in found]
    ex.relative(rows)
    return rows


def test_rows_compare_each_condition_with_the_unimpaired_run() -> None:
    rows = rows_for(
        {
            "loss-0": report(duration=100.0, explored=0.97, t95=80.0, bps=4000.0, leader_changes=1),
            "loss-10": report(duration=135.0, explored=0.955, t95=None, bps=3000.0, leader_changes=4),
            "loss-50": report(
                status="timeout", duration=420.0, explored=0.4, t95=None, converged=False, leader_changes=9
            ),
            "cut-heal": report(duration=120.0, t95=88.0, heals=[3.5, 7.25], leader_changes=3),
        }
    )
    base, l10, l50, cut = rows
    assert base["vs_baseline"] is None and base["baseline"]
    assert l10["vs_baseline"] == {
        "duration": 1.35,
        "time_to_95": None,
        "bytes_per_agent_s": 0.75,
        "explored_points": -1.5,
        "leader_changes": 3,
    }
    assert l10["bytes_received"] == 6000 and l10["impairments_applied"] == 1 and l10["scenario"] == "loss-10.toml"
    assert cut["convergence_after_heal_s"] == 7.25 and cut["heals"] == 2 and cut["heals_unconverged"] == 0
    assert cut["vs_baseline"]["time_to_95"] == 1.1
    assert base["heals"] == 0 and base["convergence_after_heal_s"] is None

    assert ex.cells(base) == ["0 % loss (baseline)", "complete", "100.0", "97.0 %", "80.0", "yes", "-", "4.0", "1"]
    assert ex.cells(l10) == [
        "10 % loss",
        "complete",
        "135.0 (×1.35)",
        "95.5 % (-1.5 pt)",
        "never",
        "yes",
        "-",
        "3.0 (×0.75)",
        "4 (+3)",
    ]
    assert ex.cells(l50)[1:3] == ["timeout", "420.0 (×4.20)"] and ex.cells(l50)[5] == "NO"
    assert ex.cells(cut)[4] == "88.0 (×1.10)" and ex.cells(cut)[6] == "7.2"  # the slowest heal


def test_a_heal_that_never_converged_and_a_condition_that_never_ran() -> None:
    rows = rows_for({"loss-0": report(), "loss-10": None, "cut-heal": report(heals=[2.0, None])})
    _, never_ran, _, cut = rows
    assert never_ran["status"] == "failed" and never_ran["reason"] == "boom" and never_ran["vs_baseline"] is None
    assert ex.cells(never_ran) == ["10 % loss", "failed"] + ["-"] * 7
    assert cut["convergence_after_heal_s"] is None and cut["heals_unconverged"] == 1
    assert ex.cells(cut)[6] == "never"


def test_without_a_baseline_report_nothing_is_relative() -> None:
    rows = rows_for({"loss-0": None, "loss-10": report(), "loss-50": report(), "cut-heal": report()})
    assert all(r["vs_baseline"] is None for r in rows)
    assert ex.cells(rows[1])[2] == "100.0"


def test_missing_new_report_keys_are_dashes_not_crashes() -> None:
    old = report()
    for key in ("leader_changes", "convergence_after_heal_s", "impairments", "partitions"):
        del old[key]
    rows = rows_for({"loss-0": old, "loss-10": old})
    assert ex.cells(rows[1])[8] == "-" and rows[1]["vs_baseline"]["leader_changes"] is None


def test_the_table_has_one_row_per_condition() -> None:
    rows = rows_for({"loss-0": report(), "loss-10": report(), "loss-50": None, "cut-heal": report(heals=[1.0])})
    console = Console(width=250, record=True)
    console.print(ex.table(config(), rows))
    text = console.export_text()
    assert all(column.split(",")[0] in text for column in ex.COLUMNS)
    assert "cut drone 3 at 20 s, heal at 50 s" in text and "50 % loss" in text and "failed" in text


# --- the figure ----------------------------------------------------------------------------------------------------


def test_the_figure_is_a_png_even_with_missing_points(tmp_path: Path) -> None:
    rows = rows_for(
        {
            "loss-0": report(),
            "loss-10": report(status="timeout", t95=None),
            "loss-50": None,
            "cut-heal": report(heals=[4.0]),
        }
    )
    path = plot_dropout(rows, tmp_path / "dropout.png", "test")
    data = path.read_bytes()
    assert data[:8] == PNG_MAGIC and len(data) > 20_000


def test_the_cut_and_heal_sits_right_of_the_loss_levels() -> None:
    rows = rows_for({})
    xs, divider = x_positions(rows)
    assert xs[:3] == [0.0, 10.0, 50.0] and xs[3] > divider > 50.0
    assert x_positions(rows_for({}, cut=False))[0] == [0.0, 10.0, 50.0]


# --- the whole experiment with a fake run --------------------------------------------------------------------------


def test_the_experiment_runs_every_condition_and_writes_table_json_and_figure(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    fake = FakeRun({"loss-30": report(duration=150.0, leader_changes=5), "cut-heal": report(heals=[6.0])})
    code = ex.experiment_dropout(config(), [0.0, 0.1, 0.3, 0.5], True, tmp_path, run=fake)
    assert code == 0
    assert [Path(c.mission.out).name for c in fake.configs] == ["loss-0", "loss-10", "loss-30", "loss-50", "cut-heal"]
    assert all(c.mission.network == "netns" for c in fake.configs)  # type: ignore[attr-defined]
    summary = json.loads((tmp_path / "experiment.json").read_text())
    assert summary["plot"] == "dropout.png" and summary["levels"] == [0.0, 0.1, 0.3, 0.5]
    assert summary["cut_and_heal"] == {"drone": 3, "cut_at_s": 20.0, "heal_at_s": 50.0}
    names = ("loss-0", "loss-10", "loss-30", "loss-50", "cut-heal")
    assert [r["run_dir"] for r in summary["rows"]] == [str(tmp_path / n) for n in names]
    assert [r["scenario"] for r in summary["rows"]] == [str(tmp_path / f"{n}.toml") for n in names]
    assert summary["rows"][2]["vs_baseline"]["duration"] == 1.5
    assert (tmp_path / "dropout.png").read_bytes()[:8] == PNG_MAGIC
    out = capsys.readouterr().out
    assert "×1.50" in out and "dropout.png" in out and "experiment.json" in out


def test_a_failed_condition_is_a_row_and_the_others_still_run(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    fake = FakeRun({"loss-10": SwarmError("[netns] unavailable"), "loss-50": report(status="timeout")})
    code = ex.experiment_dropout(config(), [0.1, 0.5], True, tmp_path, run=fake)
    assert code == 1
    assert len(fake.configs) == 4  # loss-0, loss-10, loss-50, cut-heal
    rows = json.loads((tmp_path / "experiment.json").read_text())["rows"]
    assert [r["status"] for r in rows] == ["complete", "failed", "timeout", "complete"]
    assert rows[1]["reason"] == "[netns] unavailable"
    assert (tmp_path / "dropout.png").is_file()
    assert "loss-10: failed: [netns] unavailable" in capsys.readouterr().out  # printed as is, not as markup


def test_an_interrupted_mission_ends_the_experiment(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    stopped = report(status="failed") | {"reason": INTERRUPTED}
    fake = FakeRun({"loss-10": stopped})
    ex.experiment_dropout(config(), [0.1, 0.5], True, tmp_path, run=fake)
    assert [Path(c.mission.out).name for c in fake.configs] == ["loss-0", "loss-10"]  # not loss-50, cut-heal
    rows = json.loads((tmp_path / "experiment.json").read_text())["rows"]
    assert [r["reason"] for r in rows] == ["", INTERRUPTED]
    assert "interrupted" in capsys.readouterr().out


def test_a_bug_in_a_run_is_not_swallowed(tmp_path: Path) -> None:
    with pytest.raises(KeyError):
        ex.experiment_dropout(config(), [0.1], False, tmp_path, run=FakeRun({"loss-0": KeyError("bug")}))


def test_without_the_cut_and_heal_one_drone_pair_is_enough(tmp_path: Path) -> None:
    fake = FakeRun({})
    assert ex.experiment_dropout(config(drones=2), [0.2], False, tmp_path, run=fake) == 0
    assert [Path(c.mission.out).name for c in fake.configs] == ["loss-0", "loss-20"]
    assert not (tmp_path / "cut-heal.toml").exists()


# --- bad input -------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("levels", "cut", "drones", "cut_at", "heal_at", "words"),
    [
        ([0.1, 1.0], True, 3, 20.0, 50.0, "loss level 1 "),
        ([-0.1], True, 3, 20.0, 50.0, "loss level -0.1"),
        ([10.0], False, 3, 20.0, 50.0, "(10 % is 0.1)"),
        ([float("nan")], False, 3, 20.0, 50.0, "loss level nan"),
        ([0.1], True, 3, 50.0, 50.0, "must come after the cut"),
        ([0.1], True, 3, 60.0, 50.0, "must come after the cut"),
        ([0.1], True, 3, -1.0, 50.0, "cut time"),
        ([0.1], True, 3, 20.0, float("inf"), "heal time"),
        ([0.1], True, 3, 20.0, 500.0, "max time"),
        ([0.1], True, 1, 20.0, 50.0, "at least 2 drones"),
        ([0.1], False, 1, 20.0, 50.0, "at least 2 drones"),
    ],
)
def test_bad_input_is_one_line_and_runs_nothing(
    tmp_path: Path, levels: list[float], cut: bool, drones: int, cut_at: float, heal_at: float, words: str
) -> None:
    fake = FakeRun({})
    with pytest.raises(ConfigError) as err:
        ex.experiment_dropout(config(drones), levels, cut, tmp_path / "x", cut_at, heal_at, run=fake)
    assert words in str(err.value) and "\n" not in str(err.value)
    assert not fake.configs and not (tmp_path / "x").exists()


def test_a_used_output_directory_is_refused_before_anything_runs(tmp_path: Path) -> None:
    (tmp_path / "loss-10").mkdir()
    (tmp_path / "loss-10" / "report.json").write_text("{}")
    fake = FakeRun({})
    with pytest.raises(ConfigError, match="loss-10 is not empty"):
        ex.experiment_dropout(config(), [0.1], True, tmp_path, run=fake)
    assert not fake.configs


def test_a_figure_that_cannot_be_drawn_fails_the_experiment_but_keeps_the_table(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    def broken(*_: Any) -> Path:
        raise RuntimeError("no fonts")

    monkeypatch.setattr(ex, "plot_dropout", broken)
    assert ex.experiment_dropout(config(), [0.1], False, tmp_path, run=FakeRun({})) == 1
    assert json.loads((tmp_path / "experiment.json").read_text())["plot"] is None
    out = capsys.readouterr().out
    assert "figure not written: RuntimeError: no fonts" in out and "10 % loss" in out
