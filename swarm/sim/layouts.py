"""Procedural layouts of the built-in worlds, as lists of axis-aligned boxes (z-up metres, floor top at z = 0).

Pure data, no meshing: `worlds.py` turns a `Layout` into a triangle mesh. Boxes in a layout must not overlap
(they may touch: the mesher shrinks every box but the floor slab by half a millimetre, so that inside/outside
ray parity stays exact).
"""

from __future__ import annotations

from dataclasses import dataclass, field

Vec3 = tuple[float, float, float]
AxisBox = tuple[Vec3, Vec3]  # (min corner, max corner)

WALL = 0.15
DOOR_WIDTH = 1.1
DOOR_HEIGHT = 2.1
SLAB = 0.2


@dataclass
class Layout:
    name: str
    size: Vec3  # interior extent: x, y, floor-to-ceiling height
    default_start: Vec3
    boxes: list[AxisBox] = field(default_factory=list)

    def add(self, lo: Vec3, hi: Vec3) -> None:
        self.boxes.append((lo, hi))

    def shell(self, wall: float = WALL) -> None:
        """Floor slab (top at z = 0), ceiling slab (bottom at z = height) and four outer walls."""
        sx, sy, h = self.size
        self.add((0.0, 0.0, -SLAB), (sx, sy, 0.0))
        self.add((0.0, 0.0, h), (sx, sy, h + SLAB))
        self.add((0.0, 0.0, 0.0), (sx, wall, h))
        self.add((0.0, sy - wall, 0.0), (sx, sy, h))
        self.add((0.0, wall, 0.0), (wall, sy - wall, h))
        self.add((sx - wall, wall, 0.0), (sx, sy - wall, h))

    def wall_x(self, y0: float, x0: float, x1: float, doors: list[float] = (), thickness: float = WALL) -> None:
        """A wall along x from x0 to x1 (y from y0 to y0 + thickness), with doorways centred at `doors`."""
        self._wall(0, y0, x0, x1, sorted(doors), thickness)

    def wall_y(self, x0: float, y0: float, y1: float, doors: list[float] = (), thickness: float = WALL) -> None:
        """A wall along y from y0 to y1 (x from x0 to x0 + thickness), with doorways centred at `doors`."""
        self._wall(1, x0, y0, y1, sorted(doors), thickness)

    def _wall(self, axis: int, across: float, a0: float, a1: float, doors: list[float], thickness: float) -> None:
        h = self.size[2]

        def box(s0: float, s1: float, z0: float, z1: float) -> None:
            if axis == 0:
                self.add((s0, across, z0), (s1, across + thickness, z1))
            else:
                self.add((across, s0, z0), (across + thickness, s1, z1))

        start = a0
        for centre in doors:
            d0, d1 = centre - DOOR_WIDTH / 2, centre + DOOR_WIDTH / 2
            box(start, d0, 0.0, h)
            box(d0, d1, DOOR_HEIGHT, h)  # lintel
            start = d1
        box(start, a1, 0.0, h)

    def block(self, centre_xy: tuple[float, float], size: Vec3) -> None:
        """A closed block standing on the floor (desk, pillar, rack, pallet)."""
        (cx, cy), (sx, sy, sz) = centre_xy, size
        self.add((cx - sx / 2, cy - sy / 2, 0.0), (cx + sx / 2, cy + sy / 2, sz))

    def pillar(self, centre_xy: tuple[float, float], side: float = 0.4) -> None:
        self.block(centre_xy, (side, side, self.size[2]))


def office() -> Layout:
    """30 x 20 x 3 m office floor: a west lobby, a central corridor, four rooms south and three north."""
    lay = Layout("office", (30.0, 20.0, 3.0), default_start=(3.0, 10.0, 0.0))
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


def warehouse() -> Layout:
    """40 x 25 x 6 m hall: a loading area with pillars and pallets in the south, rows of racks in the north."""
    lay = Layout("warehouse", (40.0, 25.0, 6.0), default_start=(6.0, 3.5, 0.0))
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


def box() -> Layout:
    """One closed 8 x 6 x 3 m room with a wall stub and a pillar: the small world for fast tests."""
    lay = Layout("box", (8.0, 6.0, 3.0), default_start=(2.0, 3.0, 0.0))
    lay.shell()
    lay.wall_y(4.0, 3.0, 6.0 - WALL)
    lay.pillar((6.0, 1.5))
    return lay


LAYOUTS = {"office": office, "warehouse": warehouse, "box": box}
