"""The wire form of a sealed patch, and its hostile-input decoder.

Bytes: the bus envelope of `swarm.bus.codec` (``{"v", "k": "patch", "d"}``, msgpack) around a `PatchMessage`:
header fields (format version, patch id, lattice, frame span, anchor pose, bounding box, voxel and block counts,
CRC-32), the producer's signing certificate and signature (`swarm.patches.signing`; both empty in a swarm
without signing) and `payload`, one zstd frame (level 3) holding the blocks as `swarm.patches.patch.pack_blocks`
lays them out: keys int16 (M,3) little-endian, a bit per voxel saying which are observed, then only the observed
voxels' tsdf (int8) and weight (in the lattice's weight dtype, one plane per byte, low bytes first). A patch that
changes a few voxels of a block costs those voxels, not the block (`swarm.patches.unshared`).

The CRC-32 covers the header fields and the compressed payload, so corruption is caught before decompression
(it guards against damage). The content hash, SHA-256 of the same header fields and the payload, is what the
producer signs: with a verifier, a patch is bound to its producer. `decode_patch` checks, in this order, and
raises `PatchDecodeError(reason)` only:

- "too_large": input over max_bytes; a block count whose arrays would exceed MAX_EXPANSION * max_bytes; a frame
  that decompresses beyond the size the block count implies (a zip bomb without a declared size);
- "not_msgpack": not bytes, or not a bounded msgpack document (the bus codec's limits, no extension types);
- "version": envelope version or patch format version;
- "invalid": not a patch envelope, a field missing, unknown, out of range or not finite (pydantic), a pose that
  is not rigid, an unordered frame span, duplicate keys, tsdf -128, an observed voxel of weight 0, a voxel count
  the observed bits do not add up to, a block with no observed voxel (a sealer drops those);
- "lattice": voxel size, block resolution, truncation, origin or weight law differ from ours;
- "bounds": a bounding box that is inverted or larger than MAX_EXTENT_M, or blocks outside it;
- "empty": no observed voxel (a sealer never seals such a patch: `PatchSealer.seal`);
- "too_many_blocks": more blocks than `max_blocks`, when given: more than a camera can see in one seal window
  (`swarm.patches.sealer.patch_block_limit`, which also makes the sealer seal before it gets there);
- "checksum": CRC-32 mismatch;
- "unsigned", "signer", "signature": with a verifier, no signature, a certificate that is not the producer's
  signing certificate from the swarm's authority, or a signature that does not hold (`PatchVerifier.check`);
- "decompress": zstd rejects the payload;
- "shape": the payload's declared or actual size does not match the block count;
- "outside_volume": when the mission volume is given, no block in it (the fused map ignores
  blocks outside the volume, so such a patch adds nothing but would be held and served; a sealer does not seal one).

A patch rejected for any reason is never fused, held or served (`swarm.sync.service` holds only what its sink,
the mapper, accepted, and counts the rest by reason).

Decompression writes into a buffer of the expected size plus one byte, so it never allocates more than that.
"""

from __future__ import annotations

import hashlib
import zlib
from typing import Annotated, Any

import msgpack
import numpy as np
import zstandard
from pydantic import Field

from swarm.bus import codec
from swarm.bus.codec import WireMessage
from swarm.bus.messages import AgentId, Counter
from swarm.config import Vec3, WeightLaw
from swarm.patches.fused import Bounds
from swarm.patches.lattice import Lattice
from swarm.patches.patch import TSDF_SCALE, FrameSpan, Patch, PatchId, VoxelBlocks, is_rigid, pack_blocks, packed_size
from swarm.patches.signing import MAX_SIGNER_BYTES, SIGNATURE_BYTES, PatchSigner, PatchVerifier

PATCH_FORMAT = 3  # 2: signer and signature; 3: values of observed voxels only
KIND = "patch"
ZSTD_LEVEL = 3
MAX_EXPANSION = 16  # decompressed payload <= this many times max_bytes
MAX_EXTENT_M = 4000.0  # a bounding box larger than this is not a patch
_KEY_LIMIT = np.iinfo(np.int16).max


class PatchDecodeError(Exception):
    """A received patch that must not be used; `reason` is short and machine-usable (see the module doc)."""

    def __init__(self, reason: str, detail: str = "") -> None:
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason = reason
        self.detail = detail


Pose16 = Annotated[tuple[float, ...], Field(min_length=16, max_length=16)]


class PatchMessage(WireMessage):
    KIND = KIND

    patch_format: int
    producer: AgentId
    epoch: Counter
    seq: Counter
    voxel_size: float = Field(gt=0.0)
    block_resolution: int = Field(ge=2, le=64)
    truncation_voxels: float = Field(gt=0.0)
    origin: Vec3
    weight_law: WeightLaw
    first_frame: Counter
    last_frame: Counter
    t_first: float
    t_last: float
    anchor_pose: Pose16 = Field(description="4x4 camera-to-world of the first frame, row-major")
    bbox_min: Vec3
    bbox_max: Vec3
    voxel_count: Counter
    block_count: Counter
    checksum: int = Field(ge=0, le=0xFFFFFFFF, description="CRC-32 of the header fields and the payload")
    signer: bytes = Field(max_length=MAX_SIGNER_BYTES, description="the producer's signing certificate, DER")
    signature: bytes = Field(max_length=SIGNATURE_BYTES, description="Ed25519 over CONTEXT + content hash")
    payload: bytes = Field(description="zstd frame: keys, observed bits, tsdf and weight of observed voxels")


_UNHASHED = ("checksum", "signer", "signature", "payload")
_HEADER_FIELDS = tuple(name for name in PatchMessage.model_fields if name not in _UNHASHED)


def _header(fields: dict[str, Any]) -> bytes:
    return msgpack.packb([fields[name] for name in _HEADER_FIELDS], use_bin_type=True)


def _checksum(fields: dict[str, Any], payload: bytes) -> int:
    return zlib.crc32(payload, zlib.crc32(_header(fields)))


def _content_hash(fields: dict[str, Any], payload: bytes) -> bytes:
    return hashlib.sha256(_header(fields) + payload).digest()


def encode_patch(patch: Patch, level: int = ZSTD_LEVEL, signer: PatchSigner | None = None) -> bytes:
    """The wire bytes of a sealed patch, signed by `signer` (its producer) when given."""
    blocks, lattice = patch.blocks, patch.lattice
    if blocks.block_count and int(np.abs(blocks.keys).max()) > _KEY_LIMIT:
        raise ValueError("block keys beyond the int16 range cannot be encoded")
    raw = pack_blocks(blocks.keys, blocks.tsdf, blocks.weight)
    payload = zstandard.ZstdCompressor(level=level).compress(raw)
    fields: dict[str, Any] = {
        "patch_format": PATCH_FORMAT,
        "producer": patch.id.producer,
        "epoch": patch.id.epoch,
        "seq": patch.id.seq,
        "voxel_size": lattice.voxel_size,
        "block_resolution": lattice.block_resolution,
        "truncation_voxels": lattice.truncation_voxels,
        "origin": lattice.origin,
        "weight_law": lattice.weight_law,
        "first_frame": patch.span.first,
        "last_frame": patch.span.last,
        "t_first": patch.span.t_first,
        "t_last": patch.span.t_last,
        "anchor_pose": tuple(float(x) for x in patch.anchor_pose.ravel()),
        "bbox_min": tuple(float(x) for x in patch.bounds[0]),
        "bbox_max": tuple(float(x) for x in patch.bounds[1]),
        "voxel_count": blocks.voxel_count,
        "block_count": blocks.block_count,
    }
    if signer is not None and signer.producer != patch.id.producer:
        raise ValueError(f"drone {signer.producer} cannot sign patch {patch.id}")
    draft = PatchMessage(**fields, checksum=0, signer=b"", signature=b"", payload=payload)
    header = draft.model_dump(include=set(_HEADER_FIELDS))  # the validated values, as a receiver sees them
    update: dict[str, Any] = {"checksum": _checksum(header, payload)}
    if signer is not None:
        update |= {"signer": signer.cert_der, "signature": signer.sign(_content_hash(header, payload))}
    return codec.encode(draft.model_copy(update=update))


def decode_patch(
    data: bytes,
    lattice: Lattice,
    max_bytes: int,
    max_blocks: int | None = None,
    volume: Bounds | None = None,
    verifier: PatchVerifier | None = None,
) -> Patch:
    """A validated patch on `lattice` from wire bytes; raise PatchDecodeError (only) otherwise. `max_blocks` and
    the mission `volume`, when given, bound what a real patch can be ("too_many_blocks", "outside_volume"); with
    a `verifier`, the patch must be signed by its producer."""
    try:
        return _decode(data, lattice, max_bytes, max_blocks, volume, verifier)
    except PatchDecodeError:
        raise
    except Exception as exc:  # a gap in the checks below must still not crash the receiver
        raise PatchDecodeError("invalid", f"{type(exc).__name__}: {exc}"[:200]) from None


_CODEC_REASONS = {"bad_envelope": "invalid", "kind": "invalid"}  # the rest keep their name


def _decode(
    data: bytes,
    lattice: Lattice,
    max_bytes: int,
    max_blocks: int | None,
    volume: Bounds | None,
    verifier: PatchVerifier | None,
) -> Patch:
    try:
        msg = codec.decode(data, PatchMessage, max_bytes)
    except codec.DecodeError as exc:
        raise PatchDecodeError(_CODEC_REASONS.get(exc.reason, exc.reason), exc.detail) from None
    if msg.patch_format != PATCH_FORMAT:
        raise PatchDecodeError("version", f"patch format {msg.patch_format!r} is not {PATCH_FORMAT}")

    try:
        theirs = Lattice(msg.voxel_size, msg.block_resolution, msg.truncation_voxels, msg.origin, msg.weight_law)
    except ValueError as exc:
        raise PatchDecodeError("lattice", str(exc)) from None
    if theirs != lattice:
        raise PatchDecodeError("lattice", f"patch lattice ({theirs.describe()}) is not ours ({lattice.describe()})")

    lo, hi = np.array(msg.bbox_min), np.array(msg.bbox_max)
    if np.any(lo > hi) or np.any(hi - lo > MAX_EXTENT_M):
        raise PatchDecodeError("bounds", f"bounding box {lo} - {hi}")
    if msg.voxel_count == 0:
        raise PatchDecodeError("empty", f"patch {msg.producer}.{msg.epoch}.{msg.seq} has no observed voxel")
    if max_blocks is not None and msg.block_count > max_blocks:
        raise PatchDecodeError("too_many_blocks", f"{msg.block_count} blocks, a patch has at most {max_blocks}")
    if msg.voxel_count > msg.block_count * lattice.voxels_per_block:
        raise PatchDecodeError("invalid", f"{msg.voxel_count} observed voxels in {msg.block_count} blocks")
    expected = packed_size(lattice, msg.block_count, msg.voxel_count)
    if expected > MAX_EXPANSION * max_bytes:
        raise PatchDecodeError("too_large", f"{msg.block_count} blocks need {expected} bytes")
    header = msg.model_dump(include=set(_HEADER_FIELDS))
    if _checksum(header, msg.payload) != msg.checksum:
        raise PatchDecodeError("checksum", f"CRC-32 mismatch for patch {msg.producer}.{msg.epoch}.{msg.seq}")
    if verifier is not None:
        refused = verifier.check(msg.producer, msg.signer, msg.signature, _content_hash(header, msg.payload))
        if refused is not None:
            raise PatchDecodeError(refused, f"patch {msg.producer}.{msg.epoch}.{msg.seq} is not its producer's")
    raw = _decompress(msg.payload, expected)

    keys, tsdf, weight = _unpack(raw, lattice, msg.block_count, msg.voxel_count)
    _check_arrays(lattice, keys, lo, hi)
    if volume is not None and outside_volume(lattice, keys, volume):
        box = lattice.block_bounds(keys)
        raise PatchDecodeError("outside_volume", f"no block of {box[0]} - {box[1]} is in the mission volume")

    pose = np.array(msg.anchor_pose, dtype=np.float64).reshape(4, 4)
    if not is_rigid(pose):
        raise PatchDecodeError("invalid", "anchor pose is not a rigid transform")
    if msg.first_frame > msg.last_frame or msg.t_first > msg.t_last:
        raise PatchDecodeError("invalid", "frame span is not ordered")
    return Patch(
        PatchId(msg.producer, msg.epoch, msg.seq),
        lattice,
        FrameSpan(msg.first_frame, msg.last_frame, msg.t_first, msg.t_last),
        pose,
        (lo, hi),
        VoxelBlocks(keys, tsdf, weight),
    )


def _decompress(payload: bytes, expected: int) -> bytearray:
    """Exactly `expected` bytes out of one zstd frame, never allocating more than expected + 1."""
    try:
        declared = zstandard.frame_content_size(payload)
    except zstandard.ZstdError as exc:
        raise PatchDecodeError("decompress", str(exc)[:200]) from None
    if declared >= 0 and declared != expected:
        raise PatchDecodeError("shape", f"frame holds {declared} bytes, the block count needs {expected}")
    out = bytearray(expected + 1)
    view = memoryview(out)
    filled = 0
    try:
        with zstandard.ZstdDecompressor().stream_reader(payload, read_across_frames=False) as reader:
            while filled <= expected:
                got = reader.readinto(view[filled:])
                if not got:
                    break
                filled += got
    except zstandard.ZstdError as exc:
        raise PatchDecodeError("decompress", str(exc)[:200]) from None
    if filled > expected:
        raise PatchDecodeError("too_large", f"payload decompresses beyond the declared {expected} bytes")
    if filled < expected:
        raise PatchDecodeError("shape", f"payload holds {filled} bytes, header says {expected}")
    del view
    del out[expected:]
    return out


def _unpack(raw: bytearray, lattice: Lattice, m: int, voxels: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Dense (keys int32, tsdf, weight) of `pack_blocks` bytes, whose size `packed_size(m, voxels)` was checked."""
    n = lattice.voxels_per_block
    mask_bytes = -(-n // 8)
    keys = np.frombuffer(raw, dtype="<i2", count=3 * m).reshape(m, 3).astype(np.int32)
    bits = np.frombuffer(raw, dtype=np.uint8, count=m * mask_bytes, offset=6 * m).reshape(m, mask_bytes)
    observed = np.unpackbits(bits, axis=1, count=n).astype(bool)
    if m and not observed.any(axis=1).all():
        raise PatchDecodeError("invalid", "a block with no observed voxel")
    if int(np.count_nonzero(observed)) != voxels:
        raise PatchDecodeError("invalid", f"{np.count_nonzero(observed)} observed voxels, header says {voxels}")
    at = packed_size(lattice, m, 0)  # where the values start
    values = np.frombuffer(raw, dtype=np.int8, count=voxels, offset=at)
    if voxels and int(values.min()) < -TSDF_SCALE:
        raise PatchDecodeError("invalid", "tsdf value -128 is outside [-127, 127]")
    dtype = lattice.weight_dtype
    planes = [
        np.frombuffer(raw, dtype=np.uint8, count=voxels, offset=at + voxels * (1 + i)) for i in range(dtype.itemsize)
    ]
    weights = planes[0].astype(dtype) if dtype.itemsize == 1 else planes[0] | (planes[1].astype(dtype) << 8)
    if voxels and int(weights.min()) == 0:
        raise PatchDecodeError("invalid", "an observed voxel with weight 0")
    tsdf = np.zeros((m, n), dtype=np.int8)
    weight = np.zeros((m, n), dtype=dtype)
    tsdf[observed], weight[observed] = values, weights
    return keys, tsdf, weight


def _check_arrays(lattice: Lattice, keys: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> None:
    if len(keys):
        klo, khi = lattice.block_bounds(keys)
        slack = 1e-6 * max(1.0, float(np.max(np.abs(np.concatenate([lo, hi])))))
        if np.any(klo < lo - slack) or np.any(khi > hi + slack):
            raise PatchDecodeError("bounds", f"blocks span {klo} - {khi}, outside the declared box {lo} - {hi}")
        codes = (keys[:, 0].astype(np.int64) << 32) + (keys[:, 1].astype(np.int64) << 16) + keys[:, 2]
        if len(np.unique(codes)) != len(codes):
            raise PatchDecodeError("invalid", "duplicate block keys")


def outside_volume(lattice: Lattice, keys: np.ndarray, volume: Bounds) -> bool:
    """Whether no block at `keys` shares a point with the volume (a block's sample points span its box; touching
    counts as sharing)."""
    r = lattice.block_resolution
    lo = lattice.voxel_to_point(np.asarray(keys, dtype=np.int64) * r)
    hi = lo + (r - 1) * lattice.voxel_size
    vlo, vhi = np.asarray(volume[0], dtype=np.float64), np.asarray(volume[1], dtype=np.float64)
    return not bool(np.any(np.all((hi >= vlo) & (lo <= vhi), axis=1)))


def decode_expected(
    data: bytes,
    pid: PatchId,
    lattice: Lattice,
    max_bytes: int,
    max_blocks: int | None = None,
    volume: Bounds | None = None,
    verifier: PatchVerifier | None = None,
) -> Patch:
    """`decode_patch`, and the bytes must hold patch `pid` (a chunk or request named it): else "id_mismatch"."""
    patch = decode_patch(data, lattice, max_bytes, max_blocks, volume, verifier)
    if patch.id != pid:
        raise PatchDecodeError("id_mismatch", f"bytes hold patch {patch.id}, expected {pid}")
    return patch
