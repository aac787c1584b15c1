"""Patch stores (the agent's private one for its own patches, the public one for received ones), keyed by id.

A store keeps each patch in its wire form, which is what peers are served, and a little metadata: a decoded
patch at 0.1 m is about 13 times larger than its compressed bytes, and its arrays are only needed once, when it
is fused. `get` decodes again when the arrays are wanted. Adding a patch already held changes nothing.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from swarm.patches.lattice import Lattice
from swarm.patches.patch import FrameSpan, Patch, PatchId
from swarm.patches.wire import decode_patch, encode_patch


@dataclass(frozen=True, eq=False)
class StoredPatch:
    id: PatchId
    data: bytes  # wire form
    span: FrameSpan
    bounds: tuple[np.ndarray, np.ndarray]
    voxel_count: int
    block_count: int


class PatchStore:
    def __init__(self, lattice: Lattice, max_bytes: int = 4 << 20) -> None:
        """`max_bytes`: the largest patch the mission accepts (`mapping.max_patch_bytes`); held bytes, already
        validated, decode again within its bounds however well they compressed."""
        self.lattice = lattice
        self.max_bytes = max_bytes
        self._patches: dict[PatchId, StoredPatch] = {}

    def add(self, patch: Patch, data: bytes | None = None) -> bool:
        """Store a patch with its wire bytes (encoded here when not given); False, no change, if already held."""
        if patch.id in self._patches:
            return False
        if patch.lattice != self.lattice:
            raise ValueError(f"patch {patch.id} is on another lattice")
        wire = bytes(data) if data is not None else encode_patch(patch)
        self._patches[patch.id] = StoredPatch(
            patch.id, wire, patch.span, patch.bounds, patch.voxel_count, patch.block_count
        )
        return True

    def data(self, pid: PatchId) -> bytes | None:
        """The wire bytes of a held patch (what a peer asking for it is sent)."""
        stored = self._patches.get(pid)
        return stored.data if stored else None

    def info(self, pid: PatchId) -> StoredPatch | None:
        return self._patches.get(pid)

    def get(self, pid: PatchId) -> Patch | None:
        """A held patch, decoded again from its wire bytes."""
        stored = self._patches.get(pid)
        if stored is None:
            return None
        return decode_patch(stored.data, self.lattice, max(len(stored.data), self.max_bytes))

    @property
    def data_bytes(self) -> int:
        """The wire bytes held, all patches together."""
        return sum(len(stored.data) for stored in self._patches.values())

    def ids(self) -> list[PatchId]:
        return sorted(self._patches)

    def __contains__(self, pid: object) -> bool:
        return pid in self._patches

    def __len__(self) -> int:
        return len(self._patches)

    def __iter__(self) -> Iterator[StoredPatch]:
        return iter([self._patches[pid] for pid in sorted(self._patches)])

    @property
    def nbytes(self) -> int:
        """Wire bytes held."""
        return sum(len(p.data) for p in self._patches.values())
