"""The view gain: what a candidate is worth is the unknown volume its viewpoint's camera would see."""

import math

import numpy as np
import pytest

from swarm.config import CameraSettings, ExploreSettings
from swarm.explore.frontiers import LOOK_AHEAD_M, ExplorationGrid, ViewModel
from swarm.patches.fused import FREE, OCCUPIED, UNKNOWN
from tests.explore.synthetic import room_states, set_states, state_grid

RES = 0.2
SETTINGS = ExploreSettings(body_height_m=0.0)
CAMERA = ViewModel.from_camera(CameraSettings())  # 90 x 73.7 degrees, 0.3 to 8 m


def _grid(states: np.ndarray, settings: ExploreSettings = SETTINGS, view: ViewModel | None = CAMERA) -> ExplorationGrid:
    return ExplorationGrid.from_states(
        (0.0, 0.0, 0.0), RES, states, settings, floor_z=0.0, top_z=states.shape[2] * RES, view=view
    )


def _frustum_m3(view: ViewModel, far: float) -> float:
    """Volume of the camera's field of view between min_range_m and `far`: (r^3/3) * hfov * 2 sin(vfov/2)."""
    solid = math.radians(view.hfov_deg) * 2 * math.sin(math.radians(view.vfov_deg) / 2)
    return (far**3 - view.min_range_m**3) / 3 * solid


def _open_space() -> tuple[np.ndarray, tuple[float, float, float]]:
    """20 m of unknown all round an eye in the middle, which sits in a small known free cube."""
    states = state_grid((20.0, 20.0, 20.0), UNKNOWN)
    set_states(states, (9.6, 9.6, 9.6), (10.4, 10.4, 10.4), FREE)
    return states, (10.1, 10.1, 10.1)


def test_the_vertical_field_of_view_follows_the_image_shape() -> None:
    assert CAMERA.vfov_deg == pytest.approx(2 * math.degrees(math.atan(0.75)))  # 160 x 120 pixels, 90 degrees
    wide = ViewModel.from_camera(CameraSettings(width=120, height=120))
    assert wide.vfov_deg == pytest.approx(90.0)


def test_in_open_unknown_space_the_view_gain_is_the_volume_of_the_field_of_view() -> None:
    states, eye = _open_space()
    grid = _grid(states)
    gain = grid.view_gain(np.array([eye]), np.array([(eye[0] + 1.0, eye[1], eye[2])]))[0]
    # the known cube round the eye (0.4 m each way) is not unknown: only a sliver of the 0.3..8 m cone
    assert gain == pytest.approx(_frustum_m3(CAMERA, 8.0), rel=0.05)
    # a camera looking down sees as much in open space, a shorter range far less
    down = ViewModel(CAMERA.hfov_deg, CAMERA.vfov_deg, 30.0, CAMERA.min_range_m, CAMERA.max_range_m)
    assert _grid(states, view=down).view_gain(np.array([eye]), np.array([(eye[0] + 1, eye[1], eye[2])]))[0] == (
        pytest.approx(gain, rel=0.02)
    )
    short = ViewModel(CAMERA.hfov_deg, CAMERA.vfov_deg, 0.0, CAMERA.min_range_m, 4.0)
    assert _grid(states, view=short).view_gain(np.array([eye]), np.array([(eye[0] + 1, eye[1], eye[2])]))[0] == (
        pytest.approx(_frustum_m3(short, 4.0), rel=0.1)
    )


def test_an_obstacle_ends_the_view_and_the_camera_looks_where_the_point_is() -> None:
    states, eye = _open_space()
    set_states(states, (12.0, 0.0, 0.0), (12.19, 20.0, 20.0), OCCUPIED)  # a wall 1.9 m east of the eye
    grid = _grid(states)
    east, west = (eye[0] + 1.0, eye[1], eye[2]), (eye[0] - 1.0, eye[1], eye[2])
    facing_wall, facing_away = grid.view_gain(np.array([eye, eye]), np.array([east, west]))
    assert facing_away == pytest.approx(_frustum_m3(CAMERA, 8.0), rel=0.05)
    # the pyramid up to the wall at most (4/3 D^3 tan(hfov/2) tan(vfov/2)), less what is known round the eye
    pyramid = 4 / 3 * 1.9**3 * math.tan(math.radians(CAMERA.hfov_deg / 2)) * math.tan(math.radians(CAMERA.vfov_deg / 2))
    assert 0.0 < facing_wall < pyramid


def test_without_a_camera_or_with_the_box_model_frontiers_carry_the_box_gain() -> None:
    states = room_states(known_to_x=4.0)
    here = (1.0, 3.0, 1.5)
    box = _grid(states, settings=SETTINGS.model_copy(update={"gain_model": "box"})).frontiers(here)
    assert box == _grid(states, view=None).frontiers(here)
    assert [f.gain for f in box] == pytest.approx(
        list(_grid(states, view=None).gain_at(np.array([f.point for f in box])))
    )
    assert _grid(states, view=None).view_gain(np.array([here]), np.array([(2.0, 3.0, 1.5)])).tolist() == [0.0]


def test_frontiers_are_ranked_by_what_their_viewpoints_see() -> None:
    # The 8 x 6 m room with a wall at x = 4 m and a door onto the unknown far half, and a 1.2 m cube of unknown
    # floating in the known half's south-west corner: the door's frontiers come first, and every frontier's
    # gain is what the camera sees from its viewpoint facing its point.
    states = room_states(known_to_x=4.2, wall_x=4.0, door=True)
    set_states(states, (0.4, 0.4, 0.8), (1.6, 1.6, 2.0), UNKNOWN)
    grid = _grid(states)
    frontiers = grid.frontiers((3.0, 4.0, 1.5))
    door = [f for f in frontiers if f.point[0] > 3.5]
    cube = [f for f in frontiers if f.point[0] < 3.5]
    assert door and cube
    assert min(f.gain for f in door) > 3 * max(f.gain for f in cube)
    assert [f.gain for f in frontiers] == sorted((f.gain for f in frontiers), reverse=True)
    np.testing.assert_allclose(
        [f.gain for f in frontiers],
        grid.view_gain(np.array([f.viewpoint for f in frontiers]), np.array([f.point for f in frontiers])),
    )


def test_a_frontier_seen_from_its_own_cell_is_looked_at_on_its_unknown_side() -> None:
    # The room known up to y = 4 m: the frontier cells at y = 3.9 m are safe, reachable cells themselves, so
    # their viewpoint is their own centre and gives no direction; they are looked at northwards (+y), where the
    # unknown is, and their point moves LOOK_AHEAD_M that way.
    states = state_grid((8.0, 6.0, 3.0), OCCUPIED)
    set_states(states, (0.2, 0.2, 0.2), (7.8, 5.8, 2.8), FREE)
    set_states(states, (0.0, 4.0, 0.0), (8.0, 6.0, 3.0), UNKNOWN)
    frontiers = _grid(states).frontiers((4.0, 2.0, 1.5))
    own_cell = [f for f in frontiers if f.viewpoint[1] == pytest.approx(3.9)]
    assert own_cell
    for f in own_cell:
        assert f.point[1] - f.viewpoint[1] == pytest.approx(LOOK_AHEAD_M, abs=0.3)
        assert abs(f.point[0] - f.viewpoint[0]) < 0.75 and f.point[2] == pytest.approx(f.viewpoint[2])
        assert f.gain > 1.0


def test_the_eye_is_taken_at_its_cells_centre_and_the_camera_turned_to_the_nearest_degree() -> None:
    states, eye = _open_space()
    set_states(states, (12.0, 0.0, 0.0), (12.19, 20.0, 20.0), OCCUPIED)  # a wall east: the heading matters
    grid = _grid(states)
    off_centre = (eye[0] + 0.09, eye[1] - 0.09, eye[2] + 0.05)  # the same 0.2 m cell
    ahead = np.array([1.0, 0.5, 0.0])
    looks = np.array([eye + ahead, off_centre + ahead])  # the same heading from both
    turned = np.array([eye + ahead] * 2)
    turned[1, :2] = (
        eye[0] + math.cos(math.atan2(0.5, 1.0) + math.radians(0.4)),
        eye[1] + math.sin(math.atan2(0.5, 1.0) + math.radians(0.4)),
    )
    gains = grid.view_gain(np.array([eye, off_centre]), looks)
    assert gains[0] == gains[1] > 0.0
    assert grid.view_gain(np.array([eye, eye]), turned).tolist() == [gains[0]] * 2  # 0.4 degrees: the same heading
    assert grid.view_gain(np.array([eye]), np.array([(eye[0] + 1.0, eye[1] - 0.5, eye[2])]))[0] != gains[0]


def test_a_view_out_of_the_grid_sees_nothing_beyond_its_edge() -> None:
    # All unknown: a ray that leaves the grid must stop there, not wrap round into the next row of cells (with a
    # 1 m min range, the first samples are already 5 cells out).
    states = state_grid((6.0, 6.0, 3.0), UNKNOWN)
    set_states(states, (2.8, 0.0, 1.4), (3.0, 0.2, 1.6), FREE)
    far_start = ViewModel(CAMERA.hfov_deg, CAMERA.vfov_deg, 0.0, 1.0, CAMERA.max_range_m)
    grid = _grid(states, view=far_start)
    eye = (2.9, 0.1, 1.5)  # in the grid's first row of cells along y
    outwards, inwards = grid.view_gain(np.array([eye, eye]), np.array([(2.9, -1.0, 1.5), (2.9, 1.0, 1.5)]))
    assert outwards == 0.0
    assert inwards > 10.0


def test_the_way_to_the_unknown_is_the_mean_offset_of_the_unknown_cells_in_the_gain_cube() -> None:
    """`_unknown_direction`, gathered for all points at once, against a loop over each point's clipped cube; points
    in the grid, at its edges and off it (a cube that misses the grid sees nothing)."""
    from tests.explore.synthetic import warehouse_states

    grid = _grid(warehouse_states(known_to_x=10.0, speckle=0.05, seed=4)[:100, :60, :20])
    shape = np.array(grid._unknown.shape)
    half = round(SETTINGS.gain_radius_m / RES)
    rng = np.random.default_rng(7)
    size = shape * RES
    points = np.vstack([rng.uniform(-0.2, 1.2, (40, 3)) * size, [[20.1, 6.0, 2.0], [22.5, 6.0, 2.0]]])
    expected = np.zeros((len(points), 3))
    for row, cell in enumerate(np.floor(points / RES).astype(np.int64)):
        lo, hi = np.clip(cell - half, 0, shape), np.clip(cell + half + 1, 0, shape)
        found = np.argwhere(grid._unknown[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]])
        if len(found):
            expected[row] = (found.mean(axis=0) + lo - cell) * RES
    got = grid._unknown_direction(points)
    assert np.allclose(got, expected, atol=1e-12)
    assert np.count_nonzero(expected.any(axis=1)) >= 10  # some points see unknown cells, some do not
    assert np.count_nonzero(~expected.any(axis=1)) >= 5
    assert got[-2].any() and not got[-1].any()  # just off the grid: its cube reaches in; 2.5 m off: it does not
