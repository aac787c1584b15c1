"""`swarm agent --check`: what an agent would find on this vehicle before it flies, without flying.

It connects to the autopilot as the agent does (MAVSDK), reads the vehicle's health and the PX4 parameters that
decide what the vehicle does when its agent dies (`swarm.agent.px4_params`), prints them, and exits: 0 when the
agent, with this configuration, would take off; 1 when it would refuse, with one line per reason. It never arms,
never switches modes and never writes a parameter (under `agent.px4_params = "set"` it prints what the agent
would write). Meant for the first minutes next to a real PX4: props off, on the bench.
"""

from __future__ import annotations

import asyncio
import time
from dataclasses import dataclass, field

from swarm.agent.autopilot import Autopilot, FlightError, local_frame
from swarm.agent.px4_params import FLOAT_PARAMS, INT_PARAMS, safe_writes, unsafe
from swarm.config import SwarmConfig

HEALTH_POLL_S = 0.2


@dataclass
class Preflight:
    """What the check found; `ready` when the agent would take off."""

    url: str
    health: dict[str, bool] = field(default_factory=dict)
    params: dict[str, float] = field(default_factory=dict)
    problems: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    @property
    def ready(self) -> bool:
        return not self.problems

    def lines(self) -> list[str]:
        out = [f"autopilot {self.url}"]
        out += [f"  health {name}: {'ok' if ok else 'NOT OK'}" for name, ok in self.health.items()]
        out += [f"  param {name} = {value:g}" for name, value in self.params.items()]
        out += [f"  note: {note}" for note in self.notes]
        out += [f"  problem: {problem}" for problem in self.problems]
        out.append("ready: the agent would take off" if self.ready else "not ready: the agent would refuse to fly")
        return out


async def check_vehicle(config: SwarmConfig, ap: Autopilot | None = None) -> Preflight:
    """Connect, wait up to `agent.health_timeout_s` for the vehicle to be healthy, read the parameters."""
    s = config.agent
    ap = ap or Autopilot(s.autopilot, config.mission.origin, s.command_timeout_s, local_frame(s))
    found = Preflight(ap.url)
    try:
        await ap.connect(s.connect_timeout_s)
        found.health = await _health(ap, s.health_timeout_s)
        if not all(found.health.values()):
            bad = ", ".join(name for name, ok in found.health.items() if not ok)
            found.problems.append(f"not healthy within {s.health_timeout_s:g} s: {bad}")
        if s.px4_params == "off":
            found.notes.append("agent.px4_params = 'off': the agent reads and writes no parameter")
            return found
        found.params = await ap.read_params(INT_PARAMS, FLOAT_PARAMS)
        findings = unsafe(found.params)
        if s.px4_params == "set":
            writes = ", ".join(f"{name}={value}" for name, value in safe_writes(found.params).items())
            found.notes.append(f"agent.px4_params = 'set': the agent would write {writes} before arming")
        else:
            found.problems += [f"{f.param}={f.value:g}: {f.reason}" for f in findings]
            if findings:
                found.notes.append("agent.px4_params = 'set' makes the agent write Hold values before arming")
        return found
    except FlightError as exc:
        found.problems.append(str(exc))
        return found
    finally:
        await ap.close()


async def _health(ap: Autopilot, timeout_s: float) -> dict[str, bool]:
    """The vehicle's health as soon as every item is ok, or as it is after `timeout_s`."""
    deadline = time.monotonic() + timeout_s
    while True:
        items = await ap.read_health()
        if all(items.values()) or time.monotonic() > deadline:
            return items
        await asyncio.sleep(HEALTH_POLL_S)


def preflight_command(config: SwarmConfig) -> int:
    """`swarm agent --check`: print what was found; 0 when ready, 1 when not."""
    found = asyncio.run(check_vehicle(config))
    for line in found.lines():
        print(line, flush=True)
    return 0 if found.ready else 1
