"""Fault injection for `swarm run --fault SPEC` (`mission.faults`): kill, restart, freeze and telemetry loss.

The supervision loop ticks a `FaultInjector` with the mission time and the simulator's status. A fault's time
counts from take-off (the first vehicle off the ground), as link scenarios do, so a slow start on a busy machine
does not move it; the records give mission times. Each fault becomes one or two actions on the
real processes: SIGKILL, SIGSTOP/SIGCONT, a new agent process (which takes a new epoch and takes over its drone
in the air), or the simulator's control file that silences a vehicle's downlink. Every action is recorded with
its mission time; `finish()` undoes what is still in force (a frozen agent is continued, telemetry restored) so
nothing outlives the mission. Which exits a fault explains (a killed agent's -9, a failsafe exit 3 after
telemetry loss) is answered by `excuses`, so the mission can still be `complete`.
"""

from __future__ import annotations

import signal
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from swarm.config import FaultSpec
from swarm.files import write_model
from swarm.mission.links import any_vehicle_airborne
from swarm.mission.processes import Child
from swarm.sim.status import SimControl, SimStatus

KILL_WAIT_S = 5.0
FAILSAFE_EXIT_CODE = 3  # the agent's exit code after a telemetry-loss failsafe landing (swarm.agent.main)

StartAgent = Callable[[int, int], Child]  # (agent id, restart number) -> the new process


@dataclass(order=True)
class _Action:
    t: float
    order: int
    fault: FaultSpec = field(compare=False)
    step: str = field(compare=False)  # "start" or "end"


class FaultInjector:
    def __init__(self, faults: list[FaultSpec], control_path: Path, start_agent: StartAgent) -> None:
        self.faults = list(faults)
        self.control_path = control_path
        self.start_agent = start_agent
        self.records: list[dict[str, Any]] = []
        self.restarts: dict[int, int] = {}  # agent -> restarts done
        self._pending = sorted(
            [_Action(f.at, 2 * i, f, "start") for i, f in enumerate(self.faults)]
            + [
                _Action(f.at + (f.duration or 0.0), 2 * i + 1, f, "end")
                for i, f in enumerate(self.faults)
                if f.kind != "kill"
            ]
        )
        self._down: set[int] = set()  # killed, waiting for their restart
        self._frozen: dict[int, Child] = {}
        self._silent: set[int] = set()
        self._killed: set[int] = set()  # killed for good
        self._telemetry_lost: set[int] = set()
        self.takeoff_t: float | None = None  # mission time of the first take-off

    @property
    def restarting(self) -> set[int]:
        """Agents between their kill and their new process: their exit is not the end of them."""
        return set(self._down)

    def tick(self, t: float, sim: SimStatus | None, agents: dict[int, Child]) -> None:
        if self.takeoff_t is None:
            if not any_vehicle_airborne(sim):
                return
            self.takeoff_t = t
        while self._pending and self._pending[0].t <= t - self.takeoff_t:
            action = self._pending.pop(0)
            self._apply(action, t, agents)

    def _apply(self, action: _Action, t: float, agents: dict[int, Child]) -> None:
        fault, k = action.fault, action.fault.agent
        child = agents.get(k)
        record: dict[str, Any] = {
            "t": round(t, 2),
            "wall_t": round(time.time(), 3),
            "index": action.order // 2,
            "agent": k,
            "step": action.step,
        }
        if fault.kind in ("kill", "restart") and action.step == "start":
            record["result"] = self._kill(child)
            if record["result"].startswith("killed"):
                (self._down if fault.kind == "restart" else self._killed).add(k)
        elif fault.kind == "restart":
            if k not in self._down:
                record["result"] = "not started again: it had exited before the kill"
            else:
                self._down.discard(k)
                self.restarts[k] = self.restarts.get(k, 0) + 1
                agents[k] = self.start_agent(k, self.restarts[k])
                record["result"] = f"started again as pid {agents[k].pid}"
        elif fault.kind == "freeze" and action.step == "start":
            if child is None or child.poll() is not None:
                record["result"] = "not running"
            else:
                child.signal(signal.SIGSTOP)
                self._frozen[k] = child
                record["result"] = "stopped (SIGSTOP)"
        elif fault.kind == "freeze":
            frozen = self._frozen.pop(k, None)
            if frozen is not None:
                frozen.signal(signal.SIGCONT)
            record["result"] = "continued (SIGCONT)" if frozen is not None else "was not frozen"
        else:  # telemetry-loss
            (self._silent.add if action.step == "start" else self._silent.discard)(k)
            if action.step == "start":
                self._telemetry_lost.add(k)
            write_model(self.control_path, SimControl(telemetry_off=sorted(self._silent)))
            record["result"] = "vehicle silent" if action.step == "start" else "vehicle sending again"
        self.records.append(record)

    @staticmethod
    def _kill(child: Child | None) -> str:
        if child is None or child.poll() is not None:
            return "had already exited"
        child.signal(signal.SIGCONT)  # a frozen process dies of SIGKILL too, but do not leave it stopped
        child.signal(signal.SIGKILL)
        code = child.stop(KILL_WAIT_S)  # reaps it and closes its log
        return f"killed (exit {code})"

    def killed_for_good(self, k: int) -> bool:
        return k in self._killed

    def excuses(self, k: int, code: int) -> bool:
        """Whether agent k's non-zero exit `code` is what one of its faults does."""
        if k in self._killed and code == -signal.SIGKILL:
            return True
        return k in self._telemetry_lost and code == FAILSAFE_EXIT_CODE

    def finish(self) -> None:
        """Undo what is still in force: continue frozen agents, let every vehicle send again."""
        for child in self._frozen.values():
            child.signal(signal.SIGCONT)
        self._frozen.clear()
        if self._silent:
            self._silent.clear()
            write_model(self.control_path, SimControl(telemetry_off=[]))

    def report(self) -> list[dict[str, Any]]:
        """Each fault as asked, with what was done and when (`actions`), in the order they were given."""
        return [
            {
                "fault": str(f),
                "kind": f.kind,
                "agent": f.agent,
                "at": f.at,
                "duration": f.duration,
                "takeoff_t": self.takeoff_t,
                "actions": [
                    {key: v for key, v in r.items() if key != "index"} for r in self.records if r["index"] == i
                ],
            }
            for i, f in enumerate(self.faults)
        ]
