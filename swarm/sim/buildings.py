"""Procedural buildings: random indoor worlds from a seed, as `BuildingLayout` boxes (`--world gen:SEED[:opts]`).

A building is one to three equal storeys over the same footprint. Each storey's plan is a binary space
partition of the free rectangle inside the outer walls: a region is cut by a wall (one door) or, when large, by a
corridor between two walls (one door in each), until its rooms reach the target area; an unsplit large region is
a hall with pillars. Storeys are joined through holes in the slab between them: an atrium void, or a stairwell (a
hole with a flight of solid steps under it).

Invariants, which make every room of every storey reachable from the start by a drone of radius 0.2 m with
0.25 m of clearance (the tests check it with a flood fill on the mesh):
- Every split puts a door in its wall(s), so the leaves of the partition form a connected graph (each half is
  connected, and the door joins them). Doors are 0.9-1.4 m wide (the `doors` option picks another range within
  0.9-2.0 m) and 2.0-2.1 m high.
- A door's approach (`_APPROACH` m deep on both sides, `_DOOR_SIDE` m beyond each jamb) and every slab hole
  widened by `_HOLE_MARGIN` m are keep-out zones: no later wall, furniture or pillar enters them. So a door
  always opens onto its room's free middle, and walls stand clear of every hole.
- Rooms are at least `_MIN_ROOM` m on a side. Furniture stands against the walls and is at most `_WALL_DEPTH`
  deep, a table stands in the middle only with `_TABLE_RING` m free around it, and pillars are `_PILLAR_GAP` m
  from walls and each other: each room's middle (the room less `_WALL_DEPTH` on every side) stays connected and
  every door's approach reaches it.
- Holes are at least `_MIN_HOLE` m across the free part (a stair flight takes one side of a stairwell), and no
  two holes (with margins) overlap, so a stair always stands on solid floor.

Everything is drawn from `numpy.random.default_rng(seed)`: the same seed and options give the same boxes.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np

from swarm.errors import WorldError
from swarm.sim.layouts import SLAB, WALL, BuildingLayout, Doorway, Rect

PREFIX = "gen:"
MIN_SIZE, MAX_SIZE = (15.0, 10.0), (60.0, 40.0)
DEFAULT_MAX_SIZE = (40.0, 30.0)  # with no size option the seed draws one up to this
MAX_STOREYS = 3
MIN_ROOMS, MAX_ROOMS = 1, 200
SPEC_HELP = "gen:SEED[:size=WxD,storeys=N,rooms=N,furniture=0|1,doors=MIN-MAX]"

DOOR_WIDTHS = (0.9, 1.4)  # drawn from this range unless the spec's doors option narrows or moves it
DOOR_WIDTH_LIMITS = (0.9, 2.0)  # what the doors option accepts: narrower breaks the reachability invariant
DOOR_HEIGHTS = (2.0, 2.1)
STOREY_HEIGHTS = (2.8, 3.5)
_MIN_ROOM = 3.0  # smallest side of a room (corridors excepted)
_CORRIDOR = (1.6, 2.6)  # corridor widths
_APPROACH = 1.2  # keep-out depth in front of a door, both sides
_DOOR_SIDE = 0.4  # keep-out beyond each jamb
_JAMB = 0.5  # a door's edge keeps this far from a wall's end or a wall abutting it
_HOLE_MARGIN = 1.2  # walls keep this far from a slab hole
_MIN_HOLE = 2.4  # free width of a hole a drone climbs through
_WALL_DEPTH = 0.6  # deepest piece of furniture against a wall
_TABLE_RING = 1.0  # free space around a table in a room's middle
_PILLAR_GAP = 1.5  # pillars keep this far from walls; their grid pitch is larger
_START_CLEAR = 2.0  # half side of the furniture-free square around the start


@dataclass(frozen=True)
class BuildingOptions:
    """What a `gen:` spec asks for; None lets the seed draw it."""

    seed: int
    size: tuple[float, float] | None = None
    storeys: int | None = None
    rooms: int | None = None
    furniture: bool = True
    door_widths: tuple[float, float] | None = None

    @property
    def name(self) -> str:
        """A path-safe name that tells specs apart: gen-7, gen-7-30x20-2s, gen-7-r12-bare."""
        parts = [f"gen-{self.seed}"]
        if self.size is not None:
            parts.append(f"{self.size[0]:g}x{self.size[1]:g}")
        if self.storeys is not None:
            parts.append(f"{self.storeys}s")
        if self.rooms is not None:
            parts.append(f"r{self.rooms}")
        if not self.furniture:
            parts.append("bare")
        if self.door_widths is not None:
            parts.append(f"d{self.door_widths[0]:g}-{self.door_widths[1]:g}")
        return "-".join(parts)


def is_spec(spec: str) -> bool:
    return spec.startswith(PREFIX)


def parse_spec(spec: str) -> BuildingOptions:
    """`gen:SEED` or `gen:SEED:key=value,...` (size=WxD, storeys=N, rooms=N, furniture=0|1, doors=MIN-MAX or
    doors=W, in metres); WorldError else."""
    body = spec[len(PREFIX) :] if is_spec(spec) else spec
    seed_text, _, option_text = body.partition(":")
    if not re.fullmatch(r"\d+", seed_text):
        raise WorldError(f"world '{spec}': seed '{seed_text}' is not a whole number (use {SPEC_HELP})")
    values: dict[str, object] = {"seed": int(seed_text)}
    for item in filter(None, option_text.split(",")):
        key, eq, value = item.partition("=")
        key, value = key.strip(), value.strip()
        if not eq or key not in ("size", "storeys", "rooms", "furniture", "doors"):
            raise WorldError(f"world '{spec}': unknown option '{item}' (use {SPEC_HELP})")
        field_name = "door_widths" if key == "doors" else key
        if field_name in values:
            raise WorldError(f"world '{spec}': option '{key}' given twice")
        values[field_name] = _option(spec, field_name, value)
    return BuildingOptions(**values)  # type: ignore[arg-type]


def _option(spec: str, key: str, value: str) -> object:
    if key == "size":
        match = re.fullmatch(r"(\d+(?:\.\d+)?)x(\d+(?:\.\d+)?)", value)
        if not match:
            raise WorldError(f"world '{spec}': size '{value}' is not WxD in metres, e.g. size=30x20")
        w, d = float(match[1]), float(match[2])
        if not (MIN_SIZE[0] <= w <= MAX_SIZE[0] and MIN_SIZE[1] <= d <= MAX_SIZE[1]):
            raise WorldError(
                f"world '{spec}': size {value} is outside {MIN_SIZE[0]:g}x{MIN_SIZE[1]:g} .. "
                f"{MAX_SIZE[0]:g}x{MAX_SIZE[1]:g} m (width x depth)"
            )
        return (w, d)
    if key == "door_widths":
        return _door_widths(spec, value)
    if key == "furniture":
        if value not in ("0", "1"):
            raise WorldError(f"world '{spec}': furniture must be 0 or 1 (got '{value}')")
        return value == "1"
    low, high = (1, MAX_STOREYS) if key == "storeys" else (MIN_ROOMS, MAX_ROOMS)
    if not re.fullmatch(r"\d+", value) or not low <= int(value) <= high:
        raise WorldError(f"world '{spec}': {key} must be a whole number from {low} to {high} (got '{value}')")
    return int(value)


def _door_widths(spec: str, value: str) -> tuple[float, float]:
    match = re.fullmatch(r"(\d+(?:\.\d+)?)(?:-(\d+(?:\.\d+)?))?", value)
    if not match:
        raise WorldError(f"world '{spec}': doors '{value}' is not MIN-MAX or W in metres, e.g. doors=1.1-1.4")
    low = float(match[1])
    high = float(match[2]) if match[2] is not None else low
    lo_limit, hi_limit = DOOR_WIDTH_LIMITS
    if not lo_limit <= low <= high <= hi_limit:
        raise WorldError(
            f"world '{spec}': doors {value} must be widths from {lo_limit:g} to {hi_limit:g} m, the smaller first"
        )
    return (low, high)


def layout_from_spec(spec: str) -> BuildingLayout:
    options = parse_spec(spec)
    return generate(
        options.seed,
        options.size,
        options.storeys,
        options.rooms,
        options.furniture,
        name=options.name,
        door_widths=options.door_widths or DOOR_WIDTHS,
    )


# --- plans -------------------------------------------------------------------------------------------------------


def _overlaps(a: Rect, b: Rect) -> bool:
    """Open-interior overlap: rectangles that only touch do not overlap."""
    return a[0] < b[2] - 1e-9 and b[0] < a[2] - 1e-9 and a[1] < b[3] - 1e-9 and b[1] < a[3] - 1e-9


def _grow(r: Rect, m: float) -> Rect:
    return (r[0] - m, r[1] - m, r[2] + m, r[3] + m)


def _area(r: Rect) -> float:
    return (r[2] - r[0]) * (r[3] - r[1])


@dataclass
class _Wall:
    axis: int  # 0: runs along x (constant y), 1: runs along y
    across: float  # low coordinate of its thickness
    a0: float  # extent along its axis
    a1: float
    corridor: bool  # one side is a corridor (extra doors are likely)
    doors: list[Doorway] = field(default_factory=list)

    def footprint(self) -> Rect:
        if self.axis == 0:
            return (self.a0, self.across, self.a1, self.across + WALL)
        return (self.across, self.a0, self.across + WALL, self.a1)

    def approach(self, centre: float, width: float) -> Rect:
        """The keep-out zone of a door at `centre`."""
        s0, s1 = centre - width / 2 - _DOOR_SIDE, centre + width / 2 + _DOOR_SIDE
        c0, c1 = self.across - _APPROACH, self.across + WALL + _APPROACH
        return (s0, c0, s1, c1) if self.axis == 0 else (c0, s0, c1, s1)


@dataclass
class _Storey:
    index: int
    rooms: list[Rect] = field(default_factory=list)
    corridors: list[Rect] = field(default_factory=list)
    halls: list[Rect] = field(default_factory=list)  # rooms kept large on purpose: pillars go there
    walls: list[_Wall] = field(default_factory=list)
    keep_out: list[Rect] = field(default_factory=list)  # door approaches and hole margins


@dataclass(frozen=True)
class _Hole:
    slab: int  # the hole is in the floor of this storey
    rect: Rect
    stair_axis: int | None  # stairwell: the flight climbs along this axis; None: atrium void


class _Planner:
    def __init__(self, rng: np.random.Generator, target_area: float, door_widths: tuple[float, float]) -> None:
        self.rng = rng
        self.target_area = target_area
        self.door_widths = door_widths

    def door(self, wall: _Wall, lo: float, hi: float) -> Doorway | None:
        """A door of random width with its centre drawn in [lo, hi] less its half width; None if none fits."""
        width = math.floor(min(float(self.rng.uniform(*self.door_widths)), hi - lo) * 100) / 100
        if width < self.door_widths[0]:
            return None
        slack = math.floor((hi - lo - width) * 100) / 100
        centre = round(lo + width / 2 + slack * float(self.rng.random()), 3)
        return centre, width, round(float(self.rng.uniform(*DOOR_HEIGHTS)), 2)

    def partition(self, storey: _Storey, region: Rect, zones: list[Rect], depth: int = 0) -> None:
        """Cut `region` until its rooms reach the target area (see the module docstring)."""
        zones = [z for z in zones if _overlaps(z, region)]
        area, long_side = _area(region), max(region[2] - region[0], region[3] - region[1])
        target = self.target_area * float(self.rng.uniform(0.7, 1.4))
        if area <= target and long_side <= 2.5 * math.sqrt(self.target_area):
            storey.rooms.append(region)
            return
        short_side = min(region[2] - region[0], region[3] - region[1])
        if depth > 0 and area <= 8 * self.target_area and short_side >= 8.0 and self.rng.random() < 0.12:
            storey.rooms.append(region)
            storey.halls.append(region)
            return
        long_axis = 0 if region[2] - region[0] >= region[3] - region[1] else 1
        corridor = area >= 5 * self.target_area and self.rng.random() < 0.8
        if corridor and self._corridor(storey, region, zones, 1 - long_axis, depth):
            return
        axes = [long_axis, 1 - long_axis] if self.rng.random() < 0.85 else [1 - long_axis, long_axis]
        for axis in axes:
            if self._split(storey, region, zones, axis, depth):
                return
        storey.rooms.append(region)

    def _positions(self, region: Rect, zones: list[Rect], axis: int, span: float, margin: float) -> float | None:
        """A cut position s along `axis` (the band [s, s + span] across the whole region) clear of every zone,
        leaving at least `margin` on both sides; None when there is none."""
        lo, hi = region[axis] + margin, region[axis + 2] - margin - span
        if hi <= lo:
            return None
        allowed = [(lo, hi)]
        for z in zones:
            z0, z1 = z[axis] - span, z[axis + 2]  # band [s, s + span] overlaps z iff z0 < s < z1
            allowed = [piece for a, b in allowed for piece in ((a, min(b, z0)), (max(a, z1), b)) if piece[1] > piece[0]]
        if not allowed:
            return None
        # prefer cuts near the middle: draw a fraction, take the nearest allowed point
        want = region[axis] + (region[axis + 2] - region[axis]) * float(self.rng.uniform(0.3, 0.7)) - span / 2
        best = min((min(max(want, a), b) for a, b in allowed), key=lambda s: abs(s - want))
        return round(best, 2)

    def _cut(self, region: Rect, axis: int, s0: float, s1: float) -> Rect:
        """The part of region between s0 and s1 along axis."""
        return (s0, region[1], s1, region[3]) if axis == 0 else (region[0], s0, region[2], s1)

    def _wall_across(self, region: Rect, axis: int, s: float, corridor: bool) -> _Wall:
        """A wall of thickness WALL at s along `axis`, spanning the region: it runs along the other axis."""
        along = 1 - axis
        return _Wall(along, s, region[along], region[along + 2], corridor)

    def _door_in(self, storey: _Storey, wall: _Wall) -> None:
        door = self.door(wall, wall.a0 + _JAMB, wall.a1 - _JAMB)
        assert door is not None  # walls are at least _MIN_ROOM long
        wall.doors.append(door)
        storey.keep_out.append(wall.approach(door[0], door[1]))

    def _split(self, storey: _Storey, region: Rect, zones: list[Rect], axis: int, depth: int) -> bool:
        s = self._positions(region, zones, axis, WALL, _MIN_ROOM)
        if s is None:
            return False
        wall = self._wall_across(region, axis, s, corridor=False)
        self._door_in(storey, wall)
        storey.walls.append(wall)
        zones = zones + [wall.approach(wall.doors[0][0], wall.doors[0][1])]
        self.partition(storey, self._cut(region, axis, region[axis], s), zones, depth + 1)
        self.partition(storey, self._cut(region, axis, s + WALL, region[axis + 2]), zones, depth + 1)
        return True

    def _corridor(self, storey: _Storey, region: Rect, zones: list[Rect], axis: int, depth: int) -> bool:
        width = round(float(self.rng.uniform(*_CORRIDOR)), 2)
        s = self._positions(region, zones, axis, 2 * WALL + width, _MIN_ROOM)
        if s is None:
            return False
        walls = [self._wall_across(region, axis, s, True), self._wall_across(region, axis, s + WALL + width, True)]
        for wall in walls:
            self._door_in(storey, wall)
            storey.walls.append(wall)
            zones = zones + [wall.approach(wall.doors[0][0], wall.doors[0][1])]
        corridor = self._cut(region, axis, s + WALL, s + WALL + width)
        storey.rooms.append(corridor)
        storey.corridors.append(corridor)
        self.partition(storey, self._cut(region, axis, region[axis], s), zones, depth + 1)
        self.partition(storey, self._cut(region, axis, s + 2 * WALL + width, region[axis + 2]), zones, depth + 1)
        return True

    def extra_doors(self, storey: _Storey) -> None:
        """More doors where a wall segment between two abutting walls is long enough: most rooms beside a
        corridor open onto it, and some rooms get a second door (loops, not only a tree of rooms)."""
        for wall in storey.walls:
            blocked = [(d[0] - d[1] / 2 - _JAMB, d[0] + d[1] / 2 + _JAMB) for d in wall.doors]
            for other in storey.walls:
                if other.axis == wall.axis or not wall.a0 <= other.across <= wall.a1:
                    continue
                if _close(other.a1, wall.across) or _close(other.a0, wall.across + WALL):
                    blocked.append((other.across - _JAMB, other.across + WALL + _JAMB))
            free = [(wall.a0 + _JAMB, wall.a1 - _JAMB)]
            for b0, b1 in blocked:
                free = [p for a, b in free for p in ((a, min(b, b0)), (max(a, b1), b)) if p[1] - p[0] > 1e-6]
            for a, b in free:
                if b - a >= self.door_widths[0] and self.rng.random() < (0.7 if wall.corridor else 0.2):
                    door = self.door(wall, a, b)
                    if door is not None:
                        wall.doors.append(door)
                        storey.keep_out.append(wall.approach(door[0], door[1]))


def _close(a: float, b: float) -> bool:
    return abs(a - b) < 1e-6


# --- the building --------------------------------------------------------------------------------------------------


def generate(
    seed: int,
    size: tuple[float, float] | None = None,
    storeys: int | None = None,
    rooms: int | None = None,
    furniture: bool = True,
    name: str | None = None,
    door_widths: tuple[float, float] = DOOR_WIDTHS,
) -> BuildingLayout:
    """A random building (module docstring); `size` (W x D m), `storeys` and `rooms` (per storey) drawn from the
    seed when None; door widths drawn from `door_widths` (m)."""
    rng = np.random.default_rng(seed)
    if size is None:
        size = (_draw(rng, MIN_SIZE[0], DEFAULT_MAX_SIZE[0]), _draw(rng, MIN_SIZE[1], DEFAULT_MAX_SIZE[1]))
    if storeys is None:
        storeys = 1 + int(rng.random() < 0.5)
    width, depth = size
    height = _draw(rng, *STOREY_HEIGHTS, step=0.1)
    inner: Rect = (WALL, WALL, width - WALL, depth - WALL)
    if rooms is None:
        target_area = float(rng.uniform(12.0, 30.0))
    else:
        target_area = max(_area(inner) / rooms, _MIN_ROOM * _MIN_ROOM)
    lay = BuildingLayout(name or f"gen-{seed}", (width, depth, height), default_start=(0.0, 0.0, 0.0), storeys=storeys)

    holes = _holes(rng, inner, storeys)
    planner = _Planner(rng, target_area, door_widths)
    plans: list[_Storey] = []
    for k in range(storeys):
        storey = _Storey(k)
        near = [_grow(h.rect, _HOLE_MARGIN) for h in holes if h.slab in (k, k + 1)]
        storey.keep_out.extend(near)
        planner.partition(storey, inner, near)
        planner.extra_doors(storey)
        plans.append(storey)

    lay.shell(holes={k: [h.rect for h in holes if h.slab == k] for k in range(1, storeys)})
    for storey in plans:
        for wall in storey.walls:
            line = lay.wall_x if wall.axis == 0 else lay.wall_y
            line(wall.across, wall.a0, wall.a1, doors=wall.doors, storey=storey.index)
        z = lay.floor_z(storey.index)
        lay.rooms.extend(((r[0], r[1], z), (r[2], r[3], z + height)) for r in storey.rooms)
    for hole in holes:
        if hole.stair_axis is not None:
            _stair(lay, hole)

    start = _start(plans[0], holes)
    lay.default_start = (start[0], start[1], 0.0)
    start_zone = _grow((start[0], start[1], start[0], start[1]), _START_CLEAR)
    for storey in plans:
        own = [start_zone] if storey.index == 0 else []
        pillars = _pillars(lay, rng, storey, own)
        if furniture:
            _furnish(lay, rng, storey, own + pillars)
    return lay


def _draw(rng: np.random.Generator, lo: float, hi: float, step: float = 0.5) -> float:
    return round(float(lo + step * rng.integers(0, round((hi - lo) / step) + 1)), 2)


def _holes(rng: np.random.Generator, inner: Rect, storeys: int) -> list[_Hole]:
    """One hole in each slab between storeys: an atrium void or a stairwell, clear of the other holes (or, when
    the footprint has no room for that, right above the hole below: one void through both slabs)."""
    holes: list[_Hole] = []
    for slab in range(1, storeys):
        stairwell = rng.random() < 0.5
        for _ in range(200):
            if stairwell:
                axis = int(rng.integers(0, 2))
                sides = [round(float(rng.uniform(3.8, 4.8)), 2), round(float(rng.uniform(3.4, 3.8)), 2)]
                w, d = sides if axis == 0 else sides[::-1]
            else:
                axis = None
                w, d = round(float(rng.uniform(2.6, 6.0)), 2), round(float(rng.uniform(2.6, 5.0)), 2)
            room = _HOLE_MARGIN + 0.3
            if inner[2] - inner[0] < w + 2 * room or inner[3] - inner[1] < d + 2 * room:
                continue
            x0 = round(float(rng.uniform(inner[0] + room, inner[2] - room - w)), 2)
            y0 = round(float(rng.uniform(inner[1] + room, inner[3] - room - d)), 2)
            rect = (x0, y0, x0 + w, y0 + d)
            if not any(_overlaps(_grow(rect, 2 * _HOLE_MARGIN), h.rect) for h in holes):
                holes.append(_Hole(slab, rect, axis))
                break
        else:  # a small footprint: the void continues through this slab, right above the one below
            holes.append(_Hole(slab, holes[-1].rect, None))
    return holes


def _stair(lay: BuildingLayout, hole: _Hole) -> None:
    """A flight of solid steps, 1 m wide, along one side of a stairwell hole, from the lower floor to the hole's
    far edge at the upper floor's level; the rest of the hole is free to fly through."""
    x0, y0, x1, y1 = hole.rect
    z0, rise_total = lay.floor_z(hole.slab - 1), lay.size[2] + SLAB
    steps = math.ceil(rise_total / 0.2)
    axis = hole.stair_axis
    length = (x1 - x0) if axis == 0 else (y1 - y0)
    run = length / steps
    for i in range(steps):
        top = z0 + rise_total * (i + 1) / steps
        if axis == 0:
            lay.add((x0 + i * run, y0, z0), (x0 + (i + 1) * run, y0 + 1.0, top))
        else:
            lay.add((x0, y0 + i * run, z0), (x0 + 1.0, y0 + (i + 1) * run, top))


def _start(ground: _Storey, holes: list[_Hole]) -> tuple[float, float]:
    """The middle of the largest ground-floor room whose middle is clear of the stairs."""
    stairs = [h.rect for h in holes if h.slab == 1 and h.stair_axis is not None]
    for room in sorted(ground.rooms, key=lambda r: (-_area(r), r)):
        cx, cy = round((room[0] + room[2]) / 2, 2), round((room[1] + room[3]) / 2, 2)
        if not any(_overlaps(_grow((cx, cy, cx, cy), 1.0), _grow(s, _HOLE_MARGIN)) for s in stairs):
            return cx, cy
    raise WorldError("no ground-floor room is free for the start")  # unreachable: holes leave rooms beside them


def _pillars(lay: BuildingLayout, rng: np.random.Generator, storey: _Storey, keep_out: list[Rect]) -> list[Rect]:
    """A grid of pillars in each hall; returns their footprints."""
    placed: list[Rect] = []
    for hall in storey.halls:
        pitch = float(rng.uniform(4.0, 6.0))
        side = round(float(rng.uniform(0.4, 0.6)), 2)
        xs = np.arange(hall[0] + _PILLAR_GAP + pitch / 2, hall[2] - _PILLAR_GAP - side / 2, pitch)
        ys = np.arange(hall[1] + _PILLAR_GAP + pitch / 2, hall[3] - _PILLAR_GAP - side / 2, pitch)
        for x in xs:
            for y in ys:
                r = (x - side / 2, y - side / 2, x + side / 2, y + side / 2)
                if not any(_overlaps(r, z) for z in keep_out + storey.keep_out):
                    lay.pillar((round(float(x), 3), round(float(y), 3)), side, storey.index)
                    placed.append(_grow(r, _PILLAR_GAP))
    return placed


_WALL_PIECES = {  # name: (length range, depth range, height range), against a wall
    "cabinet": ((0.8, 1.2), (0.5, 0.6), (1.8, 2.0)),
    "shelf": ((1.5, 3.0), (0.35, 0.45), (2.0, 2.4)),
    "desk": ((1.2, 1.8), (0.6, 0.6), (0.72, 0.78)),
}


def _furnish(lay: BuildingLayout, rng: np.random.Generator, storey: _Storey, keep_out: list[Rect]) -> None:
    """Cabinets, shelves and desks against the walls of every room, and a table in the middle of some."""
    blocked = keep_out + storey.keep_out
    z = lay.floor_z(storey.index)
    for room in storey.rooms:
        if room in storey.corridors:
            continue
        placed: list[Rect] = []
        for _ in range(int(_area(room) / 8.0 * rng.uniform(0.5, 1.5))):
            name = list(_WALL_PIECES)[int(rng.integers(0, len(_WALL_PIECES)))]
            (l0, l1), (d0, d1), (h0, h1) = _WALL_PIECES[name]
            length, deep, high = (round(float(rng.uniform(a, b)), 2) for a, b in ((l0, l1), (d0, d1), (h0, h1)))
            side = int(rng.integers(0, 4))  # south, north, west, east wall of the room
            along = (room[2] - room[0]) if side < 2 else (room[3] - room[1])
            if along < length + 0.1:
                continue
            s = round(float(rng.uniform(0.05, along - length - 0.05)), 2)
            if side == 0:
                r = (room[0] + s, room[1], room[0] + s + length, room[1] + deep)
            elif side == 1:
                r = (room[0] + s, room[3] - deep, room[0] + s + length, room[3])
            elif side == 2:
                r = (room[0], room[1] + s, room[0] + deep, room[1] + s + length)
            else:
                r = (room[2] - deep, room[1] + s, room[2], room[1] + s + length)
            if not any(_overlaps(r, o) for o in blocked + placed):
                lay.add((r[0], r[1], z), (r[2], r[3], z + min(high, lay.size[2] - 0.3)))
                placed.append(_grow(r, 0.05))
        middle = _grow(room, -_WALL_DEPTH - _TABLE_RING)
        if room in storey.halls or rng.random() < 0.4:
            continue
        tw, td = round(float(rng.uniform(1.2, 2.4)), 2), round(float(rng.uniform(0.8, 1.2)), 2)
        if middle[2] - middle[0] >= tw and middle[3] - middle[1] >= td:
            cx = float(rng.uniform(middle[0] + tw / 2, middle[2] - tw / 2))
            cy = float(rng.uniform(middle[1] + td / 2, middle[3] - td / 2))
            r = (round(cx - tw / 2, 2), round(cy - td / 2, 2), round(cx + tw / 2, 2), round(cy + td / 2, 2))
            if not any(_overlaps(r, o) for o in blocked + placed):
                lay.add((r[0], r[1], z), (r[2], r[3], z + 0.75))
