"""Travel distances through the safe cells: how far a drone flies to a viewpoint, not how far away it is.

The leader ranks (member, candidate) pairs by distance (`swarm.roles.assignment`). Through a wall or a floor a
straight line says that the room next door or the storey above is 2 m away when the way round is 20 m.

Dijkstra (scipy's csgraph, from every start at once) runs on the safe cells merged 2x2x2: a coarse cell is
passable when any of its cells is safe; coarse cells are 26-connected, each edge as long as the distance between
their centres. That is 8 times fewer nodes than the planning grid, and the merge does not open an axis-aligned
wall: cells of two neighbouring coarse cells are at most 3 cells apart along an axis, 0.6 m on the 0.2 m grid,
while safe cells on the two sides of a wall are at least twice (clearance + half a cell) plus its thickness apart
(0.8 m with the 0.25 m clearance). Across a slanted wall it may, and the distance is then too short, never
shorter than the straight line.

Distances are at least the straight line (a path inside one coarse cell counts as straight), and a pair the
graph does not connect (a start or goal outside the safe space of this map, or in another component) gets the
straight line too: the map holding the candidate may know a way this one does not.

The search stops at `limit_m` (`SEARCH_LIMIT_M` from the grid): a goal farther than that by the graph gets the
straight line, and no less than the limit, plus BEYOND_TIE of the straight line, so that of two goals (or two
starts) beyond the search the nearer by the line ranks first rather than whichever comes first (the leader sent
itself 20 m down a stairwell to a leftover that another drone, 3 m nearer by the line, was as "far" from). But
the line misleads between storeys: a drone upstairs, 12 m from a leftover by the line and 50 m by the
stairwell, was sent to it over two drones downstairs. So a goal that no start reaches within the limit, with two
or more starts beyond it, is searched all the way from the goal, for at most FAR_GOALS such goals (the nearest
by the line) a call: those come in a mission's tail, when every drone is far from the few leftovers.

scipy's Dijkstra holds the GIL, so the agent's event loop waits for it: in a 48 x 32 m hall, five starts over the
whole graph took 0.2 s on an idle core (the leader's assignment 0.6 s at the median, 1.5 s at worst, in a 5-drone
mission on a slow day); to 15 m it is 0.06 s idle. Past 15 m the utility's distance factor is under exp(-0.2 * 15) =
0.05 (`explore.utility_lambda`), where the way round matters less.

A graph is one map's, and the same searches come back while it lives: a leader's round asks from its members and
again from their current targets, the far goals of both calls are mostly the same, a round on the last view asks
again, and the planner's guide searches from its goal. So each search's row is kept (`ROWS_KEPT`, the most
recently used, about 0.3 MB each in the hall) keyed by its source node and limit. The graph holds each edge in
both directions, so that a search runs directed: scipy transposes an undirected graph on every call.
"""

from __future__ import annotations

from collections import OrderedDict
from functools import cached_property
from threading import Lock

import cc3d
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

MERGE = 2  # planning cells per coarse cell edge
SEARCH_LIMIT_M = 15.0  # how far the search goes (module docstring)
BEYOND_TIE = 1e-3  # beyond the search, this much of the straight line is added: it orders, it does not weigh
FAR_GOALS = 3  # goals beyond the search from every start that are searched all the way (module docstring)
ROWS_KEPT = 24  # searches kept per graph (module docstring)

# the 13 neighbour offsets with a positive first nonzero component: each undirected edge once
_HALF_NEIGHBOURS = np.array(
    [(dx, dy, dz) for dx in (-1, 0, 1) for dy in (-1, 0, 1) for dz in (-1, 0, 1) if (dx, dy, dz) > (0, 0, 0)]
)


class TravelGraph:
    """The coarse graph of one grid's safe cells; `distances` runs Dijkstra on it."""

    def __init__(self, safe: np.ndarray, origin: np.ndarray, resolution: float) -> None:
        """`safe`: bool (nx, ny, nz) over the grid whose cell (0, 0, 0) has its corner at `origin`."""
        self.origin = np.asarray(origin, dtype=float).reshape(3)
        self.cell = resolution * MERGE
        shape = np.array(safe.shape)
        padded = np.zeros(tuple(-(-shape // MERGE) * MERGE), dtype=bool)
        padded[: shape[0], : shape[1], : shape[2]] = safe
        cx, cy, cz = (s // MERGE for s in padded.shape)
        coarse = np.zeros((cx, cy, cz), dtype=bool)
        for i, j, k in np.ndindex(MERGE, MERGE, MERGE):  # strided ORs: several times cheaper than any() over axes
            coarse |= padded[i::MERGE, j::MERGE, k::MERGE]
        self._coarse = coarse
        self._node = np.full(coarse.shape, -1, dtype=np.int64)
        self.nodes = int(coarse.sum())
        self._node[coarse] = np.arange(self.nodes)
        rows, cols, lengths = [], [], []
        for offset in _HALF_NEIGHBOURS:
            a = self._node[tuple(slice(max(0, -d), n - max(0, d)) for d, n in zip(offset, coarse.shape))]
            b = self._node[tuple(slice(max(0, d), n - max(0, -d)) for d, n in zip(offset, coarse.shape))]
            both = (a >= 0) & (b >= 0)
            rows.append(a[both])
            cols.append(b[both])
            lengths.append(np.full(int(both.sum()), float(np.linalg.norm(offset))))
        half = coo_matrix(
            (np.concatenate(lengths), (np.concatenate(rows), np.concatenate(cols))), shape=(self.nodes, self.nodes)
        ).tocsr()
        self._graph = (half + half.T).tocsr()  # each edge both ways (each is in `half` once), searched directed
        self._rows: OrderedDict[tuple[int, float], np.ndarray] = OrderedDict()
        self._rows_lock = Lock()  # the protocol core and the planner may search one grid's graph at once

    def node_of(self, points: np.ndarray) -> np.ndarray:
        """(N,) the node of each point's coarse cell, -1 where that cell is not passable or off the grid."""
        idx = np.floor((np.asarray(points, dtype=float).reshape(-1, 3) - self.origin) / self.cell).astype(np.int64)
        inside = np.all((idx >= 0) & (idx < np.array(self._node.shape)), axis=1)
        out = np.full(len(idx), -1, dtype=np.int64)
        out[inside] = self._node[idx[inside, 0], idx[inside, 1], idx[inside, 2]]
        return out

    def distances(
        self, starts: np.ndarray, goals: np.ndarray, start_nodes: np.ndarray | None = None, limit_m: float = np.inf
    ) -> np.ndarray:
        """(S, G) metres from each start to each goal through the graph, at least the straight line; the straight
        line where the graph does not connect them, and where it does only beyond `limit_m` the straight line but
        at least `limit_m` (plus BEYOND_TIE of the straight line). `start_nodes` overrides the starts' own nodes (a
        drone beside a wall is in a blocked cell: the caller gives the node of the safe cell it would start from)."""
        starts = np.asarray(starts, dtype=float).reshape(-1, 3)
        goals = np.asarray(goals, dtype=float).reshape(-1, 3)
        straight: np.ndarray = np.linalg.norm(starts[:, None, :] - goals[None, :, :], axis=2)
        sources = self.node_of(starts) if start_nodes is None else np.asarray(start_nodes, dtype=np.int64)
        targets = self.node_of(goals)
        rows = np.flatnonzero(sources >= 0)
        cols = np.flatnonzero(targets >= 0)
        if len(rows) == 0 or len(cols) == 0:
            return straight
        unique, inverse = np.unique(sources[rows], return_inverse=True)
        reached = self._search(unique, limit_m / self.cell)
        through = reached[inverse][:, targets[cols]] * self.cell
        block = straight[np.ix_(rows, cols)]
        connected = self._component[sources[rows]][:, None] == self._component[targets[cols]][None, :]
        # Goals no start reached within the limit, two or more connected starts beyond it: the whole way, searched
        # from the goal (the nearest FAR_GOALS of them by the line), so that those starts rank by it.
        beyond = connected & ~np.isfinite(through)
        alone = np.flatnonzero(~np.isfinite(through).any(axis=0) & (beyond.sum(axis=0) >= 2))
        if len(alone):
            alone = alone[np.argsort(block[:, alone].min(axis=0), kind="stable")][:FAR_GOALS]
            back = self._search(targets[cols[alone]], np.inf)
            through[:, alone] = back[:, sources[rows]].T * self.cell
        # Not reached: beyond the limit if both ends are in one component (then at least the limit), else no way.
        far = np.where(connected, np.maximum(block, limit_m) + BEYOND_TIE * block, block)
        straight[np.ix_(rows, cols)] = np.where(np.isfinite(through), np.maximum(through, block), far)
        return straight

    def distance_field(self, goal: np.ndarray, shape: tuple[int, int, int]) -> np.ndarray:
        """(shape) metres from each cell of the grid this graph was made from (`shape`, its shape) to `goal`
        through the graph, between coarse cells' centres (all of a coarse cell's cells get its distance); inf
        where the graph does not reach, everywhere when the goal's coarse cell is not passable. The planner's
        A* heuristic (`swarm.explore.planner`): one search from the goal, all the way."""
        out = np.full(shape, np.inf)
        node = int(self.node_of(np.asarray(goal, dtype=float))[0])
        if node < 0:
            return out
        reached = self._search(np.array([node]), np.inf)[0] * self.cell
        coarse = np.where(self._node >= 0, reached[np.maximum(self._node, 0)], np.inf)
        fine = coarse.repeat(MERGE, 0).repeat(MERGE, 1).repeat(MERGE, 2)
        out[...] = fine[: shape[0], : shape[1], : shape[2]]
        return out

    def _search(self, sources: np.ndarray, limit: float) -> np.ndarray:
        """(len(sources), nodes) graph distances in coarse-cell units from each source node, searched to `limit`
        (inf beyond it); rows kept from earlier calls are not searched again (the module docstring). The result is
        the caller's (a new array)."""
        rows: dict[int, np.ndarray] = {}
        with self._rows_lock:
            for n in map(int, sources):
                row = self._rows.get((n, limit))
                if row is not None:
                    rows[n] = row
                    self._rows.move_to_end((n, limit))
        missing = sorted({int(n) for n in sources} - rows.keys())
        if missing:
            found = dijkstra(self._graph, directed=True, indices=missing, limit=limit)
            with self._rows_lock:
                for n, row in zip(missing, found):
                    rows[n] = self._rows[(n, limit)] = row
                    while len(self._rows) > ROWS_KEPT:
                        self._rows.popitem(last=False)
        return np.stack([rows[int(n)] for n in sources])

    @cached_property
    def _component(self) -> np.ndarray:
        """The connected component of each node: the 26-connected components of the coarse cells, which are the
        graph's (cc3d: a fifth of the time of scipy's on the graph)."""
        labels = cc3d.connected_components(self._coarse, connectivity=26)
        component: np.ndarray = labels[self._coarse]  # node order: the coarse cells in C order
        return component
