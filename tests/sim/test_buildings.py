import time

import numpy as np
import pytest

from swarm.cli import main
from swarm.errors import WorldError
from swarm.sim import buildings
from swarm.sim.coverage import reachable_free_space
from swarm.sim.layouts import SLAB, BuildingLayout
from swarm.sim.worlds import World, floor_levels, load_world, world_from_layout

DRONE_RADIUS = 0.2
# flood fills run on a 0.2 m grid: a 0.9 m door leaves a 0.3 m band of centres 0.3 m clear, which always holds
# a grid column; the doorway test below checks the full 0.45 m (radius + 0.25 m) geometrically
FILL_CLEARANCE, FILL_RESOLUTION = 0.3, 0.2


def _boxes_overlap(lay: BuildingLayout) -> bool:
    boxes = np.array(lay.boxes)
    lo, hi = boxes[:, 0], boxes[:, 1]
    overlap = np.all((lo[:, None] < hi[None] - 1e-9) & (lo[None] < hi[:, None] - 1e-9), axis=2)
    np.fill_diagonal(overlap, False)
    return bool(overlap.any())


def _reachable(world: World) -> np.ndarray:
    lo, hi = world.bounds
    return reachable_free_space(world, lo, hi, FILL_RESOLUTION, world.default_start, FILL_CLEARANCE).centres


def test_the_same_seed_gives_the_same_mesh_and_other_seeds_differ() -> None:
    a, b = load_world("gen:5:size=20x15,storeys=2"), load_world("gen:5:size=20x15,storeys=2")
    assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.triangles, b.triangles)
    assert a.default_start == b.default_start
    others = [load_world(f"gen:{seed}:size=20x15,storeys=2") for seed in (6, 7)]
    assert all(o.vertices.shape != a.vertices.shape or not np.array_equal(o.vertices, a.vertices) for o in others)


@pytest.mark.parametrize("seed", range(12))
def test_a_generated_building_is_closed_in_range_and_its_boxes_do_not_overlap(seed: int) -> None:
    lay = buildings.generate(seed)
    world = world_from_layout(lay)
    width, depth, height = lay.size
    assert 15.0 <= width <= 40.0 and 10.0 <= depth <= 30.0  # the default size range
    assert 2.8 <= height <= 3.5 and lay.storeys in (1, 2)
    assert world.closed and not _boxes_overlap(lay)
    lo, hi = world.bounds
    np.testing.assert_allclose(hi - lo, [width, depth, lay.height + 2 * SLAB], atol=1e-3)
    assert floor_levels(world) == [round(lay.floor_z(k), 2) for k in range(lay.storeys)]
    assert world.name == f"gen-{seed}"


def test_options_set_size_storeys_and_furniture() -> None:
    lay = buildings.layout_from_spec("gen:3:size=60x40,storeys=3")
    assert lay.size[:2] == (60.0, 40.0) and lay.storeys == 3 and lay.name == "gen-3-60x40-3s"
    assert not _boxes_overlap(lay)
    bare = buildings.layout_from_spec("gen:3:size=60x40,storeys=3,furniture=0")
    assert len(bare.boxes) < len(lay.boxes) and bare.name == "gen-3-60x40-3s-bare"
    few = buildings.layout_from_spec("gen:3:size=30x20,storeys=1,rooms=4")
    many = buildings.layout_from_spec("gen:3:size=30x20,storeys=1,rooms=30")
    assert len(few.rooms) < len(many.rooms)


@pytest.mark.parametrize("seed", range(8))
def test_doors_are_09_to_14_m_wide_and_open_for_a_drone_with_clearance(seed: int) -> None:
    lay = buildings.generate(seed)
    world = world_from_layout(lay)
    doors = np.array(lay.doors)
    assert len(doors) >= len(lay.rooms) - lay.storeys  # a connected plan needs rooms - 1 doors per storey
    extent = doors[:, 1] - doors[:, 0]
    width = extent[:, :2].max(axis=1)
    assert np.all(width >= 0.9 - 1e-9) and np.all(width <= 1.4 + 1e-9)
    assert np.all((extent[:, 2] >= 2.0 - 1e-9) & (extent[:, 2] <= 2.1 + 1e-9))
    for lo, hi in doors:
        centre = (lo + hi) / 2
        along = 0 if hi[0] - lo[0] > hi[1] - lo[1] else 1
        column = np.array([[centre[0], centre[1], lo[2] + z] for z in (0.5, 1.0, 1.5)])
        assert np.all(world.distance(column) >= 0.45 - 2e-3)  # radius 0.2 + clearance 0.25
        beyond = np.tile(centre, (2, 1))  # just past each jamb is wall: the doorway is no wider than recorded
        beyond[:, along] = [lo[along] - 0.05, hi[along] + 0.05]
        beyond[:, 2] = lo[2] + 1.0
        assert world.is_inside_solid(beyond).all()


@pytest.mark.parametrize(("doors", "low", "high"), [("1.1-1.4", 1.1, 1.4), ("1.2", 1.2, 1.2), ("0.9-2", 0.9, 2.0)])
def test_the_doors_option_draws_every_door_width_from_its_range(doors: str, low: float, high: float) -> None:
    lay = buildings.layout_from_spec(f"gen:3:size=16x12,storeys=2,doors={doors}")
    extent = np.array(lay.doors)[:, 1] - np.array(lay.doors)[:, 0]
    width = extent[:, :2].max(axis=1)
    assert len(width) >= len(lay.rooms) - lay.storeys
    assert np.all(width >= low - 1e-9) and np.all(width <= high + 1e-9)
    assert lay.name == f"gen-3-16x12-2s-d{low:g}-{high:g}"
    assert not _boxes_overlap(lay)


@pytest.mark.parametrize(
    "spec", ["gen:1", "gen:2", "gen:4:size=24x16,storeys=2", "gen:9:size=18x12,storeys=3", "gen:3:size=16x12,doors=0.9"]
)
def test_every_room_of_every_storey_is_reachable_by_flight_from_the_start(spec: str) -> None:
    lay = buildings.layout_from_spec(spec)
    world = world_from_layout(lay)
    centres = _reachable(world)
    for lo, hi in lay.rooms:
        inside = np.all((centres > np.array(lo)) & (centres < np.array(hi)), axis=1)
        assert inside.any(), f"room {lo} - {hi} of {spec} is not reachable"
    for k in range(1, lay.storeys):  # above each slab
        assert np.any(centres[:, 2] > lay.floor_z(k) + 0.5)


@pytest.mark.parametrize("name", ["atrium", "hall"])
def test_the_atrium_and_hall_worlds_are_reachable_everywhere_they_should_be(name: str) -> None:
    world = load_world(name)
    centres = _reachable(world)
    levels = floor_levels(world)
    assert len(levels) == (2 if name == "atrium" else 1)
    lo, hi = world.bounds
    assert (20 <= hi[0] - lo[0] <= 26 and 14 <= hi[1] - lo[1] <= 18) if name == "atrium" else hi[0] - lo[0] == 48
    for floor in levels:  # most of each storey's free floor area is reachable (not cut off behind a wall)
        band = centres[(centres[:, 2] > floor + 0.9) & (centres[:, 2] < floor + 1.1)]
        assert len(band) * FILL_RESOLUTION**2 > 0.6 * (hi[0] - lo[0]) * (hi[1] - lo[1])


def test_generation_is_well_under_a_second_for_40_by_30_m() -> None:
    started = time.process_time()
    world = load_world("gen:11:size=40x30,storeys=2")
    elapsed = time.process_time() - started
    assert elapsed < 0.3 and len(world.triangles) > 1000  # about 10 ms measured


@pytest.mark.parametrize(
    ("spec", "words"),
    [
        ("gen:abc", "not a whole number"),
        ("gen:", "not a whole number"),
        ("gen:1:colour=red", "unknown option"),
        ("gen:1:size=70x20", "outside 15x10 .. 60x40"),
        ("gen:1:size=14x10", "outside 15x10 .. 60x40"),
        ("gen:1:size=20", "not WxD"),
        ("gen:1:storeys=4", "from 1 to 3"),
        ("gen:1:storeys=0", "from 1 to 3"),
        ("gen:1:furniture=yes", "0 or 1"),
        ("gen:1:size=20x15,size=20x15", "given twice"),
        ("gen:1:doors=wide", "not MIN-MAX"),
        ("gen:1:doors=0.6-1.2", "from 0.9 to 2"),
        ("gen:1:doors=1.4-1.1", "the smaller first"),
        ("gen:1:doors=2.5", "from 0.9 to 2"),
        ("gen:1:doors=1.2,doors=1.3", "'doors' given twice"),
    ],
)
def test_bad_specs_raise_one_line_world_errors(spec: str, words: str) -> None:
    with pytest.raises(WorldError) as info:
        load_world(spec)
    message = str(info.value)
    assert words in message and spec in message and "\n" not in message


def test_the_world_command_writes_a_mesh_that_loads_back(tmp_path, capsys) -> None:
    path = tmp_path / "building.ply"
    assert main(["world", "gen:7:size=30x20,storeys=2", "--out", str(path)]) == 0
    printed = capsys.readouterr().out
    assert "gen-7-30x20-2s" in printed and "2 storeys" in printed and "triangles" in printed
    original, loaded = load_world("gen:7:size=30x20,storeys=2"), load_world(str(path))
    assert len(loaded.triangles) == len(original.triangles) and loaded.closed
    assert floor_levels(loaded) == floor_levels(original)
    start = np.array(loaded.default_start)  # found by find_default_start: free floor with a clear column
    assert loaded.floor_below([start + [0, 0, 0.1]])[0] == pytest.approx(start[2], abs=1e-3)
    assert np.all(loaded.distance([start + [0, 0, h] for h in (0.5, 1.0, 1.5)]) >= 0.5 - 1e-3)


def test_the_world_command_refuses_a_bad_output_name(tmp_path, capsys) -> None:
    assert main(["world", "box", "--out", str(tmp_path / "box.txt")]) == 1
    err = capsys.readouterr().err
    assert ".txt" in err and err.count("\n") == 1
