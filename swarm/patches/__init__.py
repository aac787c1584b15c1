"""TSDF mapping and patches: lattice, Open3D integration with free-space carving, patch sealing and stores,
the wire format, and the fused map. Nothing here knows of Zenoh or MAVSDK.

Names are exported lazily so that importing the wire format does not import Open3D.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "Lattice": "lattice",
    "TsdfBackend": "backend",
    "VoxelBlockGridBackend": "backend",
    "frame_blocks": "carving",
    "PatchId": "patch",
    "FrameSpan": "patch",
    "VoxelBlocks": "patch",
    "TsdfArrays": "patch",
    "Patch": "patch",
    "PatchStore": "store",
    "StoredPatch": "store",
    "quantise": "patch",
    "PatchSealer": "sealer",
    "Mapper": "mapper",
    "FusedMap": "fused",
    "UNKNOWN": "fused",
    "FREE": "fused",
    "OCCUPIED": "fused",
    "encode_patch": "wire",
    "decode_patch": "wire",
    "PatchDecodeError": "wire",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name not in _EXPORTS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{_EXPORTS[name]}"), name)
