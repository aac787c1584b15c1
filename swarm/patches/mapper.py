"""One agent's map: its own frames sealed into patches, the private and public stores, and the fused map.

`integrate` feeds a depth frame to the open patch and returns the patch it sealed, if any; own sealed patches go
to the private store (encoded there: `private.data(pid)` is what to push) and into the fused map at once.
`receive` stores and fuses a peer's patch once, keeping the bytes it came in. `current_map` is the fused map
with the open patch included, for queries and export. Not thread-safe: call it from one thread.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np

from swarm.config import MappingSettings, Vec3
from swarm.patches.backend import TsdfBackend, VoxelBlockGridBackend
from swarm.patches.fused import Bounds, FusedMap
from swarm.patches.lattice import Lattice
from swarm.patches.patch import Patch, PatchId, VoxelBlocks
from swarm.patches.sealer import PatchSealer
from swarm.patches.signing import Signing
from swarm.patches.store import PatchStore
from swarm.patches.unshared import UnsharedObservations
from swarm.patches.wire import decode_expected, encode_patch


class Mapper:
    def __init__(
        self,
        settings: MappingSettings,
        producer: int,
        epoch: int,
        bounds: Bounds,
        origin: Vec3 = (0.0, 0.0, 0.0),
        known_weight: float = 1.0,
        backend: TsdfBackend | None = None,
        max_blocks: int | None = None,
        signing: Signing | None = None,
    ) -> None:
        """`bounds`: the mission volume (the fused map's extent; patches with no block in it are neither sealed nor
        accepted); `max_blocks`: the most blocks a patch may have (`swarm.patches.sealer.patch_block_limit`), None
        for no bound; `signing`: own patches are signed with its signer, received ones must pass its verifier."""
        self.lattice = Lattice.from_settings(settings, origin)
        backend = backend or VoxelBlockGridBackend(self.lattice)
        if backend.lattice != self.lattice:
            raise ValueError("the backend's lattice differs from the mission's")
        self.producer = producer
        self.epoch = epoch
        self.max_blocks = max_blocks
        if signing is not None and signing.signer is not None and signing.signer.producer != producer:
            raise ValueError(f"the signing key is drone {signing.signer.producer}'s, not {producer}'s")
        self.signer = signing.signer if signing is not None else None
        self.verifier = signing.verifier if signing is not None else None
        self.fused = FusedMap(self.lattice, bounds, known_weight)
        self.sealer = PatchSealer(
            backend,
            producer,
            epoch,
            settings.patch_frames,
            settings.patch_distance_m,
            max_blocks=max_blocks,
            volume=bounds,
            stretch=settings.patch_stretch,
            novelty=self.fused.novelty,
            novel_fraction=settings.novel_block_fraction,
            share=self._share if settings.patch_changes_only else None,
        )
        self.unshared = UnsharedObservations(self.lattice, bounds, max_blocks)
        self.private = PatchStore(self.lattice, settings.max_patch_bytes)
        self.public = PatchStore(self.lattice, settings.max_patch_bytes)

    def _share(self, blocks: VoxelBlocks) -> VoxelBlocks:
        return self.unshared.share(blocks, self.fused)

    def integrate(
        self, depth: np.ndarray, K: np.ndarray, T_world_cam: np.ndarray, t: float, max_range: float
    ) -> Patch | None:
        """Integrate one frame; the patch it sealed (already stored and fused), or None."""
        return self._keep(self.sealer.add_frame(depth, K, T_world_cam, t, max_range))

    def seal(self) -> Patch | None:
        """Seal the open patch now (e.g. before landing)."""
        return self._keep(self.sealer.seal())

    def _keep(self, patch: Patch | None) -> Patch | None:
        if patch is not None:
            self.private.add(patch, encode_patch(patch, signer=self.signer))
            self.fused.add(patch)
        return patch

    def receive(self, patch: Patch, data: bytes | None = None) -> bool:
        """Store and fuse a received patch (`data`: the bytes it was decoded from, kept to serve peers); False,
        and no change, if already held. Raises ValueError on another lattice (decode_patch rejects those)."""
        if self.holds(patch.id):
            return False
        self.public.add(patch, data)
        self.fused.add(patch)
        if self.sealer.share is not None:
            self.unshared.recheck(patch.blocks.keys, self.fused)
        return True

    def receive_wire(self, data: bytes, pid: PatchId, max_bytes: int) -> bool:
        """Decode and validate a peer's patch bytes, which must hold patch `pid`, then `receive` it; raises
        PatchDecodeError (nothing changes) if they are unusable, or hold more than `max_blocks` blocks or none in
        the mission volume, or are not signed by their producer when this mapper verifies."""
        patch = decode_expected(data, pid, self.lattice, max_bytes, self.max_blocks, self.fused.bounds, self.verifier)
        return self.receive(patch, data)

    def data(self, pid: PatchId) -> bytes | None:
        """Wire bytes of a held patch, own or received."""
        return self.private.data(pid) or self.public.data(pid)

    def holds(self, pid: PatchId) -> bool:
        return pid in self.private or pid in self.public

    def get(self, pid: PatchId) -> Patch | None:
        """A held patch, decoded from the store."""
        return self.private.get(pid) or self.public.get(pid)

    def held_ids(self) -> list[PatchId]:
        return sorted(self.private.ids() + self.public.ids())

    @contextmanager
    def current_map(self) -> Iterator[FusedMap]:
        """The fused map including the open patch, for the duration of the `with` block."""
        with self.fused.including(self.sealer.open_blocks()) as fused:
            yield fused
