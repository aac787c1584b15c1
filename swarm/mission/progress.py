"""Live progress of `swarm run`: a rich table on a terminal, a plain line every few seconds otherwise (CI logs)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from rich.console import Console, Group
from rich.live import Live
from rich.table import Table
from rich.text import Text

if TYPE_CHECKING:
    from swarm.mission.files import ObserverStatus
    from swarm.mission.run import RunPlan
    from swarm.sim.status import SimStatus

PLAIN_PERIOD_S = 10.0


class ProgressView:
    def __init__(self, plan: RunPlan, live: bool | None = None) -> None:
        self.plan = plan
        self.console = Console(stderr=True)
        self.live_mode = self.console.is_terminal if live is None else live
        self._live: Live | None = None
        self._last_plain = -PLAIN_PERIOD_S

    def __enter__(self) -> ProgressView:
        if self.live_mode:
            self._live = Live(console=self.console, refresh_per_second=4, transient=False)
            self._live.__enter__()
        else:
            m = self.plan.config.mission
            self.console.print(f"swarm run: {m.drones} drones in '{self.plan.world.name}', output {self.plan.out}")
        return self

    def __exit__(self, *exc: object) -> None:
        if self._live is not None:
            self._live.__exit__(*exc)  # type: ignore[arg-type]

    def update(
        self, elapsed: float, sim: SimStatus | None, observer: ObserverStatus | None, exit_codes: dict[int, int]
    ) -> None:
        rows = _rows(sim, observer, exit_codes)
        collisions = sim.collisions if sim is not None else 0  # nothing to show before the first status
        explored = 100.0 * observer.explored_fraction if observer is not None else 0.0
        if self._live is not None:
            self._live.update(self._render(elapsed, rows, collisions, explored))
        elif elapsed - self._last_plain >= PLAIN_PERIOD_S:
            self._last_plain = elapsed
            phases = " ".join(f"{r['id']}:{r['phase']}" for r in rows)
            self.console.print(
                f"[{elapsed:6.1f} s] explored {explored:5.1f} %  collisions {collisions}  {phases}", highlight=False
            )

    def _render(self, elapsed: float, rows: list[dict[str, Any]], collisions: int, explored: float) -> Group:
        m = self.plan.config.mission
        title = Text(
            f"swarm run · {self.plan.world.name} · {m.drones} drones · {elapsed:5.1f} / {m.max_time_s:.0f} s · "
            f"explored {explored:.1f} % · collisions {collisions}",
            style="bold",
        )
        table = Table(expand=False)
        for column in ("drone", "phase", "role", "mode", "position (m)", "flown (m)"):
            table.add_column(column)
        for r in rows:
            table.add_row(str(r["id"]), r["phase"], r["role"], r["mode"], r["position"], r["distance"])
        return Group(title, table)


def _rows(sim: SimStatus | None, observer: ObserverStatus | None, exit_codes: dict[int, int]) -> list[dict[str, Any]]:
    agents = observer.agents if observer is not None else {}
    rows = []
    for v in sim.vehicles if sim is not None else []:
        seen = agents.get(str(v.id))
        phase = (seen.phase if seen is not None else None) or "starting"
        if v.id in exit_codes:
            phase = "exited" if exit_codes[v.id] == 0 else f"exit {exit_codes[v.id]}"
        rows.append(
            {
                "id": v.id,
                "phase": phase,
                "role": (seen.role if seen is not None else None) or "-",
                "mode": v.mode,
                "position": "({:5.1f}, {:5.1f}, {:4.1f})".format(*v.position),
                "distance": f"{v.distance_m:6.1f}",
            }
        )
    return rows
