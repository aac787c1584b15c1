"""`import open3d` without its notebook viewer's dependencies.

Open3D's `open3d.visualization` imports `draw_plotly`, which imports plotly, dash, IPython and requests at once,
whether or not anyone draws. No Swarm process draws with plotly, and in every one of them (each agent, the
simulator, the observer) that import cost about 20 MB of memory and 0.7 s of CPU at start (an agent's imports:
175 -> 154 MB RSS, 2.3 -> 1.6 s): on 2 cores, ten agents starting together would spend 7 s of CPU on a web viewer.
`defer_plotly()` puts a stand-in for that one module where Python looks first (`sys.modules`); its three
functions import the real module on first call, so `open3d.visualization.draw_plotly(...)` still works for a
user at a prompt.

Invariant: it changes nothing once `open3d` has been imported (it is then too late, and harmless to skip).
"""

from __future__ import annotations

import importlib
import sys
import types
from typing import Any

DRAW_PLOTLY = "open3d.visualization.draw_plotly"
DEFERRED = ("get_plotly_fig", "draw_plotly", "draw_plotly_server")

__all__ = ["DRAW_PLOTLY", "defer_plotly"]


def defer_plotly() -> None:
    if "open3d" in sys.modules or DRAW_PLOTLY in sys.modules:
        return
    stand_in = types.ModuleType(DRAW_PLOTLY, "Imports Open3D's plotly viewer on first use (swarm.lean_open3d).")
    for name in DEFERRED:
        setattr(stand_in, name, _on_first_call(name))
    sys.modules[DRAW_PLOTLY] = stand_in


def _on_first_call(name: str) -> Any:
    def call(*args: Any, **kwargs: Any) -> Any:
        if getattr(sys.modules.get(DRAW_PLOTLY), "__file__", None) is None:
            del sys.modules[DRAW_PLOTLY]  # the stand-in: import the real module in its place
        return getattr(importlib.import_module(DRAW_PLOTLY), name)(*args, **kwargs)

    call.__name__ = name
    return call
