"""`swarm.lean_open3d`: Swarm's processes import Open3D without its plotly viewer, which still works when called."""

from __future__ import annotations

import subprocess
import sys
import types

import pytest

from swarm import lean_open3d

VIEWER_DEPENDENCIES = ("dash", "plotly", "IPython")


@pytest.mark.sim  # a fresh interpreter: this one imported open3d long ago
def test_a_swarm_process_imports_open3d_without_plotly_and_the_viewer_still_draws() -> None:
    script = f"""
import sys
import swarm.agent.main
import open3d as o3d
print(*[m for m in {VIEWER_DEPENDENCIES!r} if m in sys.modules])
figure = o3d.visualization.get_plotly_fig([o3d.geometry.TriangleMesh.create_box()])
print(type(figure).__name__, *[m for m in {VIEWER_DEPENDENCIES!r} if m in sys.modules])
"""
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120, check=True)
    before, after = out.stdout.splitlines()
    assert before == "", f"imported with the agent: {before}"
    assert after.startswith("Figure") and "plotly" in after.split()


def test_the_stand_in_is_placed_only_before_open3d_is_imported(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delitem(sys.modules, "open3d", raising=False)  # as in a fresh process (monkeypatch puts both back)
    monkeypatch.delitem(sys.modules, lean_open3d.DRAW_PLOTLY, raising=False)
    lean_open3d.defer_plotly()
    stand_in = sys.modules[lean_open3d.DRAW_PLOTLY]
    assert isinstance(stand_in, types.ModuleType) and getattr(stand_in, "__file__", None) is None
    assert all(callable(getattr(stand_in, name)) for name in lean_open3d.DEFERRED)

    del sys.modules[lean_open3d.DRAW_PLOTLY]
    monkeypatch.setitem(sys.modules, "open3d", types.ModuleType("open3d"))
    lean_open3d.defer_plotly()
    assert lean_open3d.DRAW_PLOTLY not in sys.modules  # too late once open3d is in: nothing is replaced
