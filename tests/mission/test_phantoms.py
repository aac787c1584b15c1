"""The referee's phantom check: map surface near a flown path and off the world is a phantom obstacle."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import open3d as o3d

from swarm.mission.phantoms import flown_paths, phantom_check
from swarm.sim.worlds import load_world


def test_paths_are_filled_in_between_samples_and_lifted_to_the_body_centre() -> None:
    points = flown_paths({"1": [[0.0, 1.0, 1.0, 1.0], [0.5, 2.0, 1.0, 1.0]], "2": [[0.0, 3.0, 3.0, 1.0]]}, 0.2)
    assert len(points) == 1 + 20 + 1  # one sample alone, and 1 m filled every 5 cm with its end
    assert np.allclose(points[:, 2], 1.2) and points[:, 0].min() == 1.0 and points[:, 0].max() == 3.0


def test_a_sphere_where_a_drone_flew_is_counted_and_the_wall_it_passed_is_not(tmp_path: Path) -> None:
    box = load_world("box")  # 8 x 6 m; its wall stub faces x = 4
    mesh = tmp_path / "map.ply"
    drone = o3d.geometry.TriangleMesh.create_sphere(radius=0.2).translate((2.0, 3.0, 1.2))
    wall_x = float(box.bounds[0][0])
    wall = o3d.geometry.TriangleMesh.create_box(0.01, 0.5, 0.5).translate((wall_x, 1.0, 1.0))
    o3d.io.write_triangle_mesh(str(mesh), drone + wall)
    trajectories = {
        "1": [[0.0, 1.0, 3.0, 1.0], [2.0, 3.0, 3.0, 1.0]],  # through the sphere
        "2": [[0.0, wall_x + 0.2, 1.0, 1.0], [2.0, wall_x + 0.2, 1.5, 1.0]],
    }  # along the outer wall
    found = phantom_check(mesh, trajectories, box, lift_m=0.2)
    assert found is not None
    sphere_vertices = len(drone.vertices)
    assert found["phantoms"] == sphere_vertices and found["near_paths"] > sphere_vertices
    assert all(abs(v[0] - 2.0) <= 0.21 for v in found["examples"])
    assert phantom_check(tmp_path / "none.ply", trajectories, box, lift_m=0.2) is None
