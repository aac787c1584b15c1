import numpy as np
import pytest
from scipy import ndimage

from swarm.config import load_config
from swarm.sim import layouts
from swarm.sim.coverage import ReachableSpace, explored_fraction, mission_reachable_space, reachable_free_space
from swarm.sim.worlds import World

RES, CLEARANCE = 0.2, 0.2


@pytest.fixture(scope="module")
def space(box_world: World) -> ReachableSpace:
    lo, hi = box_world.bounds
    return reachable_free_space(box_world, lo, hi, RES, box_world.default_start, CLEARANCE)


def inside_any_box(points: np.ndarray) -> np.ndarray:
    inside = np.zeros(len(points), dtype=bool)
    for a, b in layouts.box().boxes:
        inside |= np.all((points > a) & (points < b), axis=1)
    return inside


def all_centres(space: ReachableSpace) -> np.ndarray:
    idx = np.stack(np.meshgrid(*[np.arange(n) for n in space.mask.shape], indexing="ij"), axis=-1).reshape(-1, 3)
    return space.origin + (idx + 0.5) * space.resolution


def room_interior(p: np.ndarray) -> np.ndarray:
    return np.all((p > [0.15, 0.15, 0.0]) & (p < [7.85, 5.85, 3.0]), axis=1)


def box_distance(p: np.ndarray) -> np.ndarray:
    """(N,) Euclidean distance of points to the nearest box of the layout (0 inside)."""
    boxes = np.array(layouts.box().boxes)
    gap = np.maximum(np.maximum(boxes[None, :, 0] - p[:, None], p[:, None] - boxes[None, :, 1]), 0.0)
    return np.linalg.norm(gap, axis=2).min(axis=1)


def test_reachable_space_is_the_room_interior(box_world: World, space: ReachableSpace) -> None:
    c = space.centres
    assert space.mask.shape == (40, 30, 17) and space.mask.sum() == len(c)
    assert np.allclose(space.origin, [0.0, 0.0, -0.2])
    assert np.all(box_world.distance(c) >= CLEARANCE) and not inside_any_box(c).any()
    to_pillar = np.linalg.norm(np.maximum(np.abs(c[:, :2] - [6.0, 1.5]) - 0.2, 0.0), axis=1)
    assert to_pillar.min() >= CLEARANCE - 1e-3  # neither the pillar's interior nor its clearance
    assert ndimage.label(space.mask)[1] == 1
    # independently: the lattice points inside the room that keep the clearance from every box of the layout
    every = all_centres(space)
    expected = every[room_interior(every) & (box_distance(every) >= CLEARANCE - 1e-6)]
    assert len(c) == len(expected) and np.allclose(c, expected)
    assert c[:, 2].min() == pytest.approx(0.3) and c[:, 2].max() == pytest.approx(2.7)
    assert {(round(x, 1), round(y, 1)) for x, y in c[:, :2]} >= {(2.1, 3.1), (6.1, 4.9), (7.5, 0.5)}


def test_space_outside_the_building_is_not_reachable(box_world: World, space: ReachableSpace) -> None:
    lo, hi = box_world.bounds
    big = reachable_free_space(box_world, lo - 1.0, hi + 1.0, RES, box_world.default_start, CLEARANCE)
    assert ndimage.label(big.mask)[1] == 1
    assert len(big.centres) == len(space.centres)
    assert np.all((big.centres > lo) & (big.centres < hi))


def test_explored_fraction_bounds_and_half_room(space: ReachableSpace) -> None:
    assert explored_fraction(space, lambda p: np.zeros(len(p), dtype=bool)) == 0.0
    assert explored_fraction(space, lambda p: np.ones(len(p), dtype=bool)) == 1.0

    # a map knowing exactly the voxels (0.1 m) of the west half of the room, looked up like a TSDF's state_at
    voxel, mid = 0.1, 4.0

    def known_west(points: np.ndarray) -> np.ndarray:
        return (np.floor(points[:, 0] / voxel) + 0.5) * voxel < mid

    share = explored_fraction(space, known_west)
    assert share == pytest.approx(np.mean(space.centres[:, 0] < mid))
    # west: x from 0.35 to 4 (the stub's clearance is mostly east); east: x from 4 to 7.65 less the pillar
    assert share == pytest.approx(0.5, abs=0.04)


def test_explored_fraction_rejects_a_bad_answer(space: ReachableSpace) -> None:
    with pytest.raises(ValueError, match="shape"):
        explored_fraction(space, lambda p: np.ones(3, dtype=bool))


def test_mission_defaults_and_a_start_far_from_free_space(box_world: World) -> None:
    config = load_config(overrides={"mission.world": "box"})
    default = mission_reachable_space(box_world, config)
    assert default.resolution == 0.2 and default.mask.shape == (40, 30, 17)
    lo, hi = box_world.bounds
    with pytest.raises(ValueError, match="take-off"):
        reachable_free_space(box_world, lo, hi, RES, (0.0, 3.0, 5.0), CLEARANCE)  # 1 m above the ceiling slab
