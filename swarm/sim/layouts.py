"""Procedural layouts of the built-in worlds, as lists of axis-aligned boxes (z-up metres, floor top at z = 0).

Pure data, no meshing: `worlds.py` turns a `BuildingLayout` into a triangle mesh. Boxes in a layout must not overlap
(they may touch: the mesher shrinks every box but the floor slab by half a millimetre, so that inside/outside
ray parity stays exact).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from itertools import pairwise

from swarm.config import Vec3

AxisBox = tuple[Vec3, Vec3]  # (min corner, max corner)

WALL = 0.15
DOOR_WIDTH = 1.1
DOOR_HEIGHT = 2.1
SLAB = 0.2


Rect = tuple[float, float, float, float]  # (x0, y0, x1, y1): a floor-plan rectangle
Doorway = tuple[float, float, float]  # (centre along the wall, width, height)


@dataclass
class BuildingLayout:
    """Boxes of a building of `storeys` equal storeys: storey k's floor top is at k * (size[2] + SLAB)."""

    name: str
    size: Vec3  # interior extent: x, y, floor-to-ceiling height of one storey
    default_start: Vec3
    boxes: list[AxisBox] = field(default_factory=list)
    storeys: int = 1
    rooms: list[AxisBox] = field(default_factory=list)  # free space of each room and corridor (generated plans)
    doors: list[AxisBox] = field(default_factory=list)  # free space of each doorway, through the wall

    @property
    def height(self) -> float:
        """Interior height from the ground floor to the roof slab."""
        return self.storeys * self.size[2] + (self.storeys - 1) * SLAB

    def floor_z(self, storey: int) -> float:
        return storey * (self.size[2] + SLAB)

    def add(self, lo: Vec3, hi: Vec3) -> None:
        self.boxes.append((lo, hi))

    def shell(self, wall: float = WALL, holes: dict[int, list[Rect]] | None = None) -> None:
        """Ground slab (top at z = 0, always the first box), a slab between storeys (with `holes[k]` cut out of
        the slab under storey k), the roof slab and four outer walls per storey."""
        sx, sy, h = self.size
        self.add((0.0, 0.0, -SLAB), (sx, sy, 0.0))
        for k in range(1, self.storeys):
            z = self.floor_z(k)
            for x0, y0, x1, y1 in slab_pieces(sx, sy, (holes or {}).get(k, [])):
                self.add((x0, y0, z - SLAB), (x1, y1, z))
        top = self.height
        self.add((0.0, 0.0, top), (sx, sy, top + SLAB))
        for k in range(self.storeys):
            z0, z1 = self.floor_z(k), self.floor_z(k) + h
            self.add((0.0, 0.0, z0), (sx, wall, z1))
            self.add((0.0, sy - wall, z0), (sx, sy, z1))
            self.add((0.0, wall, z0), (wall, sy - wall, z1))
            self.add((sx - wall, wall, z0), (sx, sy - wall, z1))

    def wall_x(
        self,
        y0: float,
        x0: float,
        x1: float,
        doors: Sequence[float | Doorway] = (),
        thickness: float = WALL,
        storey: int = 0,
    ) -> None:
        """A wall along x from x0 to x1 (y from y0 to y0 + thickness), with doorways centred at `doors` (a centre
        alone is a DOOR_WIDTH x DOOR_HEIGHT doorway)."""
        self._wall(0, y0, x0, x1, doors, thickness, storey)

    def wall_y(
        self,
        x0: float,
        y0: float,
        y1: float,
        doors: Sequence[float | Doorway] = (),
        thickness: float = WALL,
        storey: int = 0,
    ) -> None:
        """A wall along y from y0 to y1 (x from x0 to x0 + thickness), with doorways centred at `doors`."""
        self._wall(1, x0, y0, y1, doors, thickness, storey)

    def _wall(
        self,
        axis: int,
        across: float,
        a0: float,
        a1: float,
        doors: Sequence[float | Doorway],
        thickness: float,
        storey: int,
    ) -> None:
        floor, h = self.floor_z(storey), self.size[2]

        def box(s0: float, s1: float, z0: float, z1: float) -> AxisBox:
            if axis == 0:
                return (s0, across, floor + z0), (s1, across + thickness, floor + z1)
            return (across, s0, floor + z0), (across + thickness, s1, floor + z1)

        start = a0
        for centre, width, height in sorted(d if isinstance(d, tuple) else (d, DOOR_WIDTH, DOOR_HEIGHT) for d in doors):
            d0, d1 = centre - width / 2, centre + width / 2
            self.add(*box(start, d0, 0.0, h))
            self.add(*box(d0, d1, height, h))  # lintel
            self.doors.append(box(d0, d1, 0.0, height))
            start = d1
        self.add(*box(start, a1, 0.0, h))

    def block(self, centre_xy: tuple[float, float], size: Vec3, storey: int = 0) -> None:
        """A closed block standing on the floor (desk, pillar, rack, pallet)."""
        (cx, cy), (sx, sy, sz), z = centre_xy, size, self.floor_z(storey)
        self.add((cx - sx / 2, cy - sy / 2, z), (cx + sx / 2, cy + sy / 2, z + sz))

    def pillar(self, centre_xy: tuple[float, float], side: float = 0.4, storey: int = 0) -> None:
        self.block(centre_xy, (side, side, self.size[2]), storey)


def slab_pieces(sx: float, sy: float, holes: Sequence[Rect]) -> list[Rect]:
    """Rectangles covering [0, sx] x [0, sy] minus the (disjoint) holes, without overlaps: the grid of every
    hole edge, with the cells outside the holes merged into runs along x."""
    xs = sorted({0.0, sx, *(v for h in holes for v in (h[0], h[2]))})
    ys = sorted({0.0, sy, *(v for h in holes for v in (h[1], h[3]))})
    pieces: list[Rect] = []
    for y0, y1 in pairwise(ys):
        run: float | None = None
        for x0, x1 in pairwise(xs):
            cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
            in_hole = any(h[0] < cx < h[2] and h[1] < cy < h[3] for h in holes)
            if in_hole and run is not None:
                pieces.append((run, y0, x0, y1))
                run = None
            elif not in_hole and run is None:
                run = x0
        if run is not None:
            pieces.append((run, y0, xs[-1], y1))
    return pieces


def office() -> BuildingLayout:
    """30 x 20 x 3 m office floor: a west lobby, a central corridor, four rooms south and three north."""
    lay = BuildingLayout("office", (30.0, 20.0, 3.0), default_start=(3.0, 10.0, 0.0))
    lay.shell()
    w = WALL
    corridor_s, corridor_n = 8.8, 11.2  # corridor free space in y
    lobby_x = 6.0  # the lobby is x < 6; its east wall leaves the corridor mouth open
    lay.wall_y(lobby_x, w, corridor_s - w)
    lay.wall_y(lobby_x, corridor_n + w, 20.0 - w)
    # corridor walls with one door per room
    lay.wall_x(corridor_s - w, lobby_x + w, 30.0 - w, doors=[9.0, 15.0, 21.0, 27.0])
    lay.wall_x(corridor_n, lobby_x + w, 30.0 - w, doors=[10.0, 18.0, 26.0])
    # partitions between rooms
    for x in (12.0, 18.0, 24.0):
        lay.wall_y(x, w, corridor_s - w)
    for x in (14.0, 22.0):
        lay.wall_y(x, corridor_n + w, 20.0 - w)
    # furniture: desks in some rooms, a reception desk and pillars in the lobby
    for centre in ((9.0, 3.0), (21.0, 4.0), (26.5, 2.5), (10.0, 16.5), (18.0, 17.0), (25.5, 15.5)):
        lay.block(centre, (1.6, 0.8, 0.75))
    lay.block((3.0, 16.5), (2.4, 0.8, 1.1))
    lay.pillar((3.0, 5.0))
    lay.pillar((3.0, 13.5))
    return lay


def warehouse() -> BuildingLayout:
    """40 x 25 x 6 m hall: a loading area with pillars and pallets in the south, rows of racks in the north."""
    lay = BuildingLayout("warehouse", (40.0, 25.0, 6.0), default_start=(6.0, 3.5, 0.0))
    lay.shell(wall=0.2)
    rack_depth, rack_height, aisle = 1.0, 4.5, 2.6
    for row in range(5):
        y0 = 7.5 + row * (rack_depth + aisle)
        for x0, x1 in ((3.0, 18.0), (21.0, 37.0)):  # a 3 m cross aisle in the middle
            lay.add((x0, y0, 0.0), (x1, y0 + rack_depth, rack_height))
    for x in (12.0, 20.0, 28.0):
        lay.pillar((x, 4.0), side=0.5)
    for centre in ((16.0, 1.5), (17.5, 1.5), (33.0, 2.0), (33.0, 3.5)):
        lay.block(centre, (1.2, 1.0, 1.0))
    return lay


def box() -> BuildingLayout:
    """One closed 8 x 6 x 3 m room with a wall stub and a pillar: the small world for fast tests."""
    lay = BuildingLayout("box", (8.0, 6.0, 3.0), default_start=(2.0, 3.0, 0.0))
    lay.shell()
    lay.wall_y(4.0, 3.0, 6.0 - WALL)
    lay.pillar((6.0, 1.5))
    return lay


def atrium() -> BuildingLayout:
    """24 x 16 m, two 3 m storeys joined by a 6 x 5 m atrium void over the ground floor's hall: four rooms south
    and three north of the hall; upstairs a gallery round the void with two rooms west, three east, one north."""
    lay = BuildingLayout("atrium", (24.0, 16.0, 3.0), default_start=(3.0, 8.0, 0.0), storeys=2)
    void = (9.0, 5.5, 15.0, 10.5)
    lay.shell(holes={1: [void]})
    w = WALL
    # ground floor: the hall is y 4.15 .. 11.85, the void above its middle
    lay.wall_x(4.0, w, 24.0 - w, doors=[3.0, 9.0, 15.0, 21.0])
    lay.wall_x(11.85, w, 24.0 - w, doors=[4.0, 12.0, 20.0])
    for x in (6.0, 12.0, 18.0):
        lay.wall_y(x, w, 4.0)
    for x in (8.0, 16.0):
        lay.wall_y(x, 12.0, 16.0 - w)
    for x, y in ((8.3, 5.0), (15.7, 5.0), (8.3, 11.0), (15.7, 11.0)):  # the gallery's pillars, round the void
        lay.pillar((x, y))
    for centre in ((3.0, 1.5), (15.0, 2.0), (21.0, 1.2), (4.0, 14.5), (20.0, 14.0)):
        lay.block(centre, (1.6, 0.8, 0.75))
    lay.block((20.5, 8.0), (0.8, 2.4, 1.1))  # reception desk
    # upper floor: rooms west of x = 6 and east of x = 18, one north of y = 12.5
    lay.wall_y(6.0, w, 16.0 - w, doors=[4.0, 12.0], storey=1)
    lay.wall_x(8.0, w, 6.0, storey=1)
    lay.wall_y(18.0, w, 16.0 - w, doors=[3.0, 8.0, 13.0], storey=1)
    for y in (5.5, 10.5):
        lay.wall_x(y, 18.0 + w, 24.0 - w, storey=1)
    lay.wall_x(12.5, 6.0 + w, 18.0, doors=[12.0], storey=1)
    for centre in ((3.0, 2.0), (3.0, 14.0), (21.0, 2.5), (21.5, 14.0), (12.0, 14.5)):
        lay.block(centre, (1.6, 0.8, 0.75), storey=1)
    lay.block((12.0, 2.0), (2.0, 0.9, 0.8), storey=1)  # a bench in the south gallery
    return lay


def hall() -> BuildingLayout:
    """48 x 32 x 4 m hall: a grid of pillars, free-standing partitions and pallets, and six rooms along the
    north side behind a wall with one door each."""
    lay = BuildingLayout("hall", (48.0, 32.0, 4.0), default_start=(4.0, 4.0, 0.0))
    lay.shell(wall=0.2)
    lay.wall_x(26.0, 0.2, 47.8, doors=[4.0, 12.0, 20.0, 28.0, 36.0, 44.0])
    for x in (8.0, 16.0, 24.0, 32.0, 40.0):
        lay.wall_y(x, 26.15, 31.8)
    for x in range(6, 43, 6):
        for y in (6.0, 13.0, 20.0):
            lay.pillar((float(x), y), side=0.5)
    lay.wall_y(21.0, 3.0, 10.0)  # partitions between the pillar lines
    lay.wall_x(16.5, 26.0, 34.0)
    lay.wall_y(39.0, 15.0, 23.0)
    lay.wall_x(16.5, 0.2, 4.0)  # a stub from the west wall
    for centre in ((9.0, 2.0), (10.4, 2.0), (27.0, 9.5), (27.0, 11.0), (44.5, 9.0), (15.0, 22.5)):
        lay.block(centre, (1.2, 1.0, 1.0))  # pallets
    lay.add((34.0, 0.2, 0.0), (44.0, 1.0, 2.4))  # shelving along the south wall
    for x in (4.0, 12.0, 20.0, 28.0, 36.0, 44.0):
        lay.block((x, 30.5), (1.6, 0.8, 0.75))  # a desk in each room
    return lay


LAYOUTS = {"office": office, "warehouse": warehouse, "box": box, "atrium": atrium, "hall": hall}
