"""Fault specs and the FaultInjector on real child processes (`sleep`), without a mission."""

from __future__ import annotations

import json
import signal
import time
from pathlib import Path

import psutil
import pytest

from swarm.cli import main
from swarm.config import ConfigError, FaultSpec, load_config
from swarm.mission.faults import FaultInjector
from swarm.mission.processes import Child, start_child
from tests.file_models import sim_status, vehicle_status

AIRBORNE = sim_status(vehicle_status(1, landed_state="in_air", armed=True))
ON_GROUND = sim_status(vehicle_status(1, landed_state="on_ground"))


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("kill:agent=1@60", FaultSpec(kind="kill", agent=1, at=60.0)),
        ("restart:agent=2@80", FaultSpec(kind="restart", agent=2, at=80.0)),
        ("restart:agent=2@80+5", FaultSpec(kind="restart", agent=2, at=80.0, duration=5.0)),
        ("freeze:agent=3@40+10", FaultSpec(kind="freeze", agent=3, at=40.0, duration=10.0)),
        ("telemetry-loss:agent=2@50.5+5", FaultSpec(kind="telemetry-loss", agent=2, at=50.5, duration=5.0)),
    ],
)
def test_fault_specs_parse_and_print_back(text: str, expected: FaultSpec) -> None:
    spec = FaultSpec.model_validate(text)
    assert spec == expected
    assert FaultSpec.model_validate(str(spec)) == spec


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("kill:agent=1@60+3", "has no duration"),
        ("freeze:agent=1@3", "needs a duration"),
        ("telemetry-loss:agent=1@3", "needs a duration"),
        ("explode:agent=1@3", "kind"),
        ("kill agent 1 at 3", "is not KIND:agent=K@T"),
        ("kill:agent=4@3", "names agent 4 but the mission has 3 drones"),
    ],
)
def test_bad_fault_specs_are_one_clear_config_error(text: str, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        load_config(overrides={"mission.drones": 3, "mission.faults": [text]})


def test_bad_fault_on_the_command_line_is_one_line_and_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["run", "--drones", "2", "--fault", "freeze:agent=2@5"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "needs a duration" in err


def _sleeper(tmp_path: Path, name: str) -> Child:
    return start_child(name, ["sleep", "60"], tmp_path / f"{name}.log")


def _status(child: Child) -> str:
    return psutil.Process(child.pid).status()


def _wait_for_status(child: Child, wanted: str) -> str:
    deadline = time.monotonic() + 5.0
    while (status := _status(child)) != wanted and time.monotonic() < deadline:
        time.sleep(0.02)
    return status


@pytest.mark.sim
def test_faults_wait_for_take_off_then_kill_freeze_and_restart_real_processes(tmp_path: Path) -> None:
    agents = {k: _sleeper(tmp_path, f"agent-{k}") for k in (1, 2, 3)}
    started: list[tuple[int, int]] = []

    def start_again(k: int, n: int) -> Child:
        started.append((k, n))
        return _sleeper(tmp_path, f"agent-{k}.restart{n}")

    specs = [FaultSpec.model_validate(s) for s in ("kill:agent=1@1", "restart:agent=2@1+2", "freeze:agent=3@1+2")]
    faults = FaultInjector(specs, tmp_path / "control.json", start_again)
    try:
        faults.tick(5.0, ON_GROUND, agents)
        assert faults.takeoff_t is None and faults.records == []
        faults.tick(10.0, AIRBORNE, agents)  # take-off: fault times count from here
        assert faults.takeoff_t == 10.0 and faults.records == []
        old_2 = agents[2]
        faults.tick(11.0, AIRBORNE, agents)
        assert agents[1].poll() == -signal.SIGKILL and old_2.poll() == -signal.SIGKILL
        assert faults.restarting == {2}
        assert _wait_for_status(agents[3], psutil.STATUS_STOPPED) == psutil.STATUS_STOPPED
        assert faults.excuses(1, -signal.SIGKILL) and faults.killed_for_good(1)
        assert not faults.excuses(2, -signal.SIGKILL) and not faults.excuses(1, 1)

        faults.tick(13.0, AIRBORNE, agents)
        assert started == [(2, 1)] and agents[2] is not old_2 and agents[2].poll() is None
        assert faults.restarting == set()
        assert _wait_for_status(agents[3], psutil.STATUS_SLEEPING) == psutil.STATUS_SLEEPING
        report = faults.report()
        assert [[a["result"].split(" as ")[0] for a in f["actions"]] for f in report] == [
            ["killed (exit -9)"],
            ["killed (exit -9)", "started again"],
            ["stopped (SIGSTOP)", "continued (SIGCONT)"],
        ]
        assert all(f["takeoff_t"] == 10.0 for f in report)
    finally:
        for child in agents.values():
            child.stop(1.0)


@pytest.mark.sim
def test_telemetry_loss_writes_the_control_file_and_finish_restores_everything(tmp_path: Path) -> None:
    agents = {1: _sleeper(tmp_path, "agent-1"), 2: _sleeper(tmp_path, "agent-2")}
    control = tmp_path / "control.json"
    specs = [FaultSpec.model_validate(s) for s in ("telemetry-loss:agent=2@0+30", "freeze:agent=1@0+30")]
    faults = FaultInjector(specs, control, lambda k, n: _sleeper(tmp_path, "never"))
    try:
        faults.tick(1.0, AIRBORNE, agents)
        assert json.loads(control.read_text()) == {"telemetry_off": [2]}
        assert faults.excuses(2, 3) and not faults.excuses(2, 1)
        assert _wait_for_status(agents[1], psutil.STATUS_STOPPED) == psutil.STATUS_STOPPED
        faults.finish()  # the mission ended before the faults did
        assert json.loads(control.read_text()) == {"telemetry_off": []}
        assert _wait_for_status(agents[1], psutil.STATUS_SLEEPING) == psutil.STATUS_SLEEPING
    finally:
        for child in agents.values():
            child.stop(1.0)
