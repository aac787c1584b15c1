import time

import numpy as np
import pytest

from swarm.errors import WorldError
from swarm.sim import layouts
from swarm.sim.worlds import BUILTIN_WORLDS, World, boxes_to_mesh, load_world, spawn_points


@pytest.mark.parametrize("name", sorted(BUILTIN_WORLDS))
def test_builtin_world_is_sane(name: str) -> None:
    world = load_world(name)
    lo, hi = world.bounds
    size = hi - lo
    assert world.name == name
    assert world.vertices.dtype == np.float64 and world.triangles.dtype == np.int32
    assert 50 < len(world.triangles) < 20000
    assert 5 < size[0] < 50 and 5 < size[1] < 40 and 2.5 < size[2] < 7
    assert world.closed
    start = np.array(world.default_start)
    assert start[2] == 0.0
    assert world.floor_below([start + [0, 0, 0.1]])[0] == pytest.approx(0.0, abs=1e-3)  # floor top at z = 0
    column = start + np.array([[0, 0, h] for h in np.arange(0.6, 2.01, 0.1)])  # 0.5 m clear of all but the floor
    assert np.all(world.distance(column) > 0.5) and not world.is_inside_solid(column).any()
    assert world.distance([start + [0, 0, 1]])[0] < size[2]  # a ceiling above


def test_builtin_boxes_do_not_overlap() -> None:
    """Inside/outside by ray parity is exact only when the boxes of a layout do not overlap."""
    for make in layouts.LAYOUTS.values():
        boxes = np.array(make().boxes)
        lo, hi = boxes[:, 0], boxes[:, 1]
        overlap = np.all((lo[:, None] < hi[None] - 1e-9) & (lo[None] < hi[:, None] - 1e-9), axis=2)
        np.fill_diagonal(overlap, False)
        assert not overlap.any(), make.__name__


def test_inside_solid_matches_the_boxes(office_world: World) -> None:
    boxes = layouts.office().boxes
    rng = np.random.default_rng(1)
    lo, hi = office_world.bounds
    pts = rng.uniform(lo, hi, size=(20000, 3))
    truth = np.zeros(len(pts), dtype=bool)
    for a, b in boxes:
        truth |= np.all((pts > a) & (pts < b), axis=1)
    clear_of_surfaces = office_world.distance(pts) > 2e-3  # the mesh boxes are shrunk by 0.5 mm
    assert np.array_equal(office_world.is_inside_solid(pts)[clear_of_surfaces], truth[clear_of_surfaces])


def test_office_doorways_let_a_drone_through(office_world: World) -> None:
    # the door of the first south room, centred at x = 9 in the corridor wall at y = 8.65 .. 8.8
    path = np.array([[9.0, y, z] for y in np.arange(7.5, 10.0, 0.05) for z in (1.0, 1.5, 1.8)])
    assert np.all(office_world.distance(path) > 0.25)


@pytest.mark.parametrize("suffix", [".ply", ".obj", ".stl"])
def test_saved_mesh_loads_back(tmp_path, box_world: World, suffix: str) -> None:
    path = tmp_path / f"room{suffix}"
    box_world.save(path)
    loaded = load_world(str(path))
    assert loaded.name == "room"
    assert len(loaded.triangles) == len(box_world.triangles)
    for a, b in zip(loaded.bounds, box_world.bounds):
        np.testing.assert_allclose(a, b, atol=1e-4)
    assert loaded.closed
    # the automatic start is free floor: on the floor, with a clear column
    start = np.array(loaded.default_start)
    assert start[2] == pytest.approx(0.0, abs=1e-3)
    assert np.all(loaded.distance([start + [0, 0, h] for h in (0.5, 1.0, 1.5, 2.0)]) >= 0.5 - 1e-3)
    assert len(spawn_points(loaded, None, 3, 1.5)) == 3


def _one_line_world_error(spec: str) -> str:
    with pytest.raises(WorldError) as info:
        load_world(spec)
    message = str(info.value)
    assert "\n" not in message and message
    return message


def test_unknown_world_names_the_builtins() -> None:
    message = _one_line_world_error("atlantis")
    assert "atlantis" in message and all(name in message for name in BUILTIN_WORLDS)


def test_missing_mesh_file(tmp_path) -> None:
    assert "missing.ply" in _one_line_world_error(str(tmp_path / "missing.ply"))


def test_garbage_mesh_file(tmp_path) -> None:
    path = tmp_path / "garbage.ply"
    path.write_bytes(b"this is not a mesh\x00\x01\x02" * 50)
    assert "garbage.ply" in _one_line_world_error(str(path))


def test_empty_mesh_file(tmp_path) -> None:
    path = tmp_path / "empty.obj"
    path.write_text("# no geometry\nv 0 0 0\nv 1 0 0\n")
    assert "no triangles" in _one_line_world_error(str(path))


def test_unsupported_extension(tmp_path) -> None:
    path = tmp_path / "world.txt"
    path.write_text("hello")
    assert ".txt" in _one_line_world_error(str(path))


def test_absurdly_large_mesh(tmp_path) -> None:
    vertices, triangles = boxes_to_mesh([((0, 0, 0), (5000, 10, 3))])
    path = tmp_path / "huge.ply"
    World("huge", vertices, triangles, (1, 1, 0)).save(path)
    assert "1000 m" in _one_line_world_error(str(path))


def test_non_finite_vertices(tmp_path) -> None:
    path = tmp_path / "nan.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n")
    message = _one_line_world_error(str(path))
    assert "non-finite" in message or "no triangles" in message


def test_spawn_points_are_spaced_clear_and_on_the_floor(office_world: World) -> None:
    points = np.array(spawn_points(office_world, None, 8, 1.5, clearance=0.5))
    assert len(points) == 8
    gaps = np.linalg.norm(points[:, None] - points[None], axis=2) + np.eye(8) * 99
    assert gaps.min() >= 1.5 - 1e-9
    assert np.allclose(points[:, 2], 0.0)
    for p in points:
        column = p + np.array([[0, 0, h] for h in np.arange(0.5, 2.01, 0.25)])
        assert np.all(office_world.distance(column) >= 0.5 - 1e-3)
    assert tuple(points[0]) == office_world.default_start  # the start itself is free, so it comes first
    assert spawn_points(office_world, None, 8, 1.5) == [tuple(p) for p in points]  # deterministic


def test_spawn_points_from_a_raised_start_stand_on_the_floor(box_world: World) -> None:
    points = spawn_points(box_world, (2.0, 3.0, 1.2), 2, 1.0)
    assert [p[2] for p in points] == [0.0, 0.0]


def test_spawn_start_inside_a_wall(box_world: World) -> None:
    with pytest.raises(WorldError, match="inside a wall"):
        spawn_points(box_world, (4.07, 4.0, 0.0), 2, 1.5)  # in the wall stub


def test_spawn_start_outside_the_world(box_world: World) -> None:
    with pytest.raises(WorldError, match="outside the world"):
        spawn_points(box_world, (50.0, 3.0, 0.0), 2, 1.5)


def test_spawn_too_many_for_the_room(box_world: World) -> None:
    with pytest.raises(WorldError, match="take-off points"):
        spawn_points(box_world, None, 16, 2.0)


def test_occupancy_marks_walls_and_frees_rooms(office_world: World) -> None:
    started = time.process_time()
    origin, grid = office_world.occupancy(0.2)
    assert time.process_time() - started < 4.0  # < 2 s on one core; headroom for a busy machine
    assert grid.dtype == bool and grid.shape == (150, 100, 17)

    def cell(p: tuple[float, float, float]) -> bool:
        return bool(grid[tuple(np.floor((np.array(p) - origin) / 0.2).astype(int))])

    assert cell((15.0, 0.07, 1.5))  # south outer wall
    assert cell((12.07, 4.0, 1.5))  # a partition
    assert cell((15.0, 10.0, -0.1))  # floor slab
    assert not cell((15.0, 4.5, 1.5))  # centre of a south room
    assert not cell((20.0, 10.0, 1.5))  # corridor
    assert not cell((9.0, 8.7, 1.1))  # in a doorway


def test_occupancy_over_a_sub_box(box_world: World) -> None:
    origin, grid = box_world.occupancy(0.5, lo=np.array([1.0, 1.0, 0.5]), hi=np.array([3.0, 2.0, 2.0]))
    assert np.allclose(origin, [1.0, 1.0, 0.5]) and grid.shape == (4, 2, 3)
    assert not grid.any()
