"""The wire format: round trip, and every kind of bad input rejected with its reason before any fusion."""

import tracemalloc

import msgpack
import numpy as np
import pytest
import zstandard
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from swarm.config import MappingSettings
from swarm.patches import wire
from swarm.patches.fused import FusedMap
from swarm.patches.lattice import Lattice
from swarm.patches.mapper import Mapper
from swarm.patches.patch import Patch, pack_blocks, packed_size
from swarm.patches.wire import PatchDecodeError, decode_patch, encode_patch
from tests.patches.scene import MAX_RANGE, ROOM_HI, ROOM_LO, rotate_in_place

BOUNDS = (ROOM_LO - 1.0, ROOM_HI + 1.0)
MAX_BYTES = 4 << 20


def sealed_patch(voxel: float, frames: int) -> Patch:
    settings = MappingSettings(voxel_size_m=voxel, patch_frames=frames)
    mapper = Mapper(settings, producer=3, epoch=1795340000000, bounds=BOUNDS)
    for f in rotate_in_place()[:frames]:
        patch = mapper.integrate(f.depth, f.K, f.T, f.t, MAX_RANGE)
    assert patch is not None
    return patch


@pytest.fixture(scope="module")
def patch() -> Patch:
    return sealed_patch(0.1, 6)


@pytest.fixture(scope="module")
def small() -> bytes:
    return encode_patch(sealed_patch(0.2, 1))


def tamper(data: bytes, fix_checksum: bool = True, envelope: dict | None = None, **fields) -> bytes:
    env = msgpack.unpackb(data, raw=False)
    env["d"].update(fields)
    env.update(envelope or {})
    if fix_checksum:
        env["d"]["checksum"] = wire._checksum(env["d"], env["d"]["payload"])
    return msgpack.packb(env, use_bin_type=True)


def rejected(data, lattice: Lattice, max_bytes: int = MAX_BYTES) -> str:
    """Feed bytes to a receiver (decode, then fuse); return the rejection reason and check nothing was fused."""
    fused = FusedMap(lattice, BOUNDS)
    empty = fused.digest()
    try:
        fused.add(decode_patch(data, lattice, max_bytes))
    except PatchDecodeError as exc:
        assert fused.digest() == empty and not fused.ids and fused.block_count == 0
        return exc.reason
    raise AssertionError("bad input was accepted")


def test_round_trip_keeps_every_field(patch: Patch) -> None:
    data = encode_patch(patch)
    back = decode_patch(data, patch.lattice, MAX_BYTES)
    assert back == patch
    assert back.id == patch.id and back.span == patch.span and back.lattice == patch.lattice
    assert np.array_equal(back.anchor_pose, patch.anchor_pose)
    assert all(np.array_equal(a, b) for a, b in zip(back.bounds, patch.bounds))
    assert back.blocks.same_as(patch.blocks)
    assert back.voxel_count == patch.voxel_count and back.block_count == patch.block_count
    assert encode_patch(back) == data  # deterministic


def test_inverse_square_patches_round_trip() -> None:
    mapper = Mapper(MappingSettings(weight_law="inverse_square", patch_frames=2), producer=1, epoch=0, bounds=BOUNDS)
    for f in rotate_in_place()[:2]:
        patch = mapper.integrate(f.depth, f.K, f.T, f.t, MAX_RANGE)
    assert patch.blocks.weight.dtype == np.uint16
    assert decode_patch(encode_patch(patch), patch.lattice, MAX_BYTES) == patch
    assert rejected(encode_patch(patch), Lattice(0.1, 8, 4.0)) == "lattice"  # same geometry, other weight law


def test_truncated_corrupted_and_garbage_inputs(patch: Patch) -> None:
    data = encode_patch(patch)
    lattice = patch.lattice
    for cut in (1, 10, len(data) // 2, len(data) - 1):
        assert rejected(data[:cut], lattice) == "not_msgpack"
    flipped = bytearray(data)
    flipped[-100] ^= 0x10  # inside the compressed payload
    assert rejected(bytes(flipped), lattice) == "checksum"
    for garbage in (b"", b"\x00", b"\xc1", b"{}", np.random.default_rng(0).bytes(5000), msgpack.packb([1, 2, 3])):
        assert rejected(garbage, lattice) in ("not_msgpack", "invalid")
    assert rejected("not bytes", lattice) == "not_msgpack"
    assert rejected(tamper(data, envelope={"k": "state"}), lattice) == "invalid"


def test_header_changes_without_a_matching_checksum_are_caught(patch: Patch) -> None:
    data = encode_patch(patch)
    assert rejected(tamper(data, fix_checksum=False, seq=patch.id.seq + 1), patch.lattice) == "checksum"
    assert rejected(tamper(data, fix_checksum=False, t_last=patch.span.t_last + 1.0), patch.lattice) == "checksum"


def test_wrong_lattice_and_version(patch: Patch) -> None:
    data = encode_patch(patch)
    assert rejected(data, Lattice(0.2, 8, 4.0)) == "lattice"
    assert rejected(data, Lattice(0.1, 8, 4.0, origin=(0.0, 0.0, 0.05))) == "lattice"
    assert rejected(tamper(data, voxel_size=0.1000001), patch.lattice) == "lattice"
    assert rejected(tamper(data, truncation_voxels=3.0), patch.lattice) == "lattice"
    assert rejected(tamper(data, patch_format=1), patch.lattice) == "version"
    assert rejected(tamper(data, envelope={"v": 99}), patch.lattice) == "version"


def test_oversized_inputs_and_declared_sizes(patch: Patch) -> None:
    data = encode_patch(patch)
    assert rejected(data, patch.lattice, max_bytes=len(data) - 1) == "too_large"
    assert rejected(tamper(data, block_count=10**9), patch.lattice) == "too_large"
    assert rejected(tamper(data, block_count=patch.block_count + 1), patch.lattice) == "shape"
    assert rejected(tamper(data, block_count=patch.block_count - 1), patch.lattice) == "shape"


def test_zip_bombs_are_cut_at_the_declared_size(patch: Patch) -> None:
    compressor = zstandard.ZstdCompressor(level=1)
    stream = compressor.compressobj()  # no content size in the frame header: only the bounded reader stops it
    zeros = bytes(1 << 20)
    bomb = b"".join([stream.compress(zeros) for _ in range(256)] + [stream.flush()])  # 256 MiB of zeros
    declared = compressor.compress(bytes(64 << 20))  # 64 MiB, declared in the frame header
    data = encode_patch(patch)
    tracemalloc.start()
    try:
        assert rejected(tamper(data, payload=bomb), patch.lattice) == "too_large"
        assert rejected(tamper(data, payload=declared), patch.lattice) == "shape"
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 16 << 20
    b = patch.blocks
    raw = pack_blocks(b.keys, b.tsdf, b.weight)
    broken = bytearray(zstandard.ZstdCompressor(level=1, write_checksum=True).compress(raw))
    broken[-1] ^= 0xFF  # zstd's own frame checksum now fails
    assert rejected(tamper(data, payload=bytes(broken)), patch.lattice) == "decompress"


def test_bounds_and_contents_are_validated(patch: Patch) -> None:
    data = encode_patch(patch)
    lo, hi = patch.bounds
    assert rejected(tamper(data, bbox_max=list(hi - 1.0)), patch.lattice) == "bounds"
    assert rejected(tamper(data, bbox_min=list(lo + 0.5)), patch.lattice) == "bounds"
    assert rejected(tamper(data, bbox_min=[-1e4, 0.0, 0.0]), patch.lattice) == "bounds"
    assert rejected(tamper(data, voxel_count=patch.voxel_count + 1), patch.lattice) == "shape"  # values missing
    too_many = patch.block_count * patch.lattice.voxels_per_block + 1
    assert rejected(tamper(data, voxel_count=too_many), patch.lattice) == "invalid"
    scaled = (2.0 * patch.anchor_pose).ravel().tolist()
    assert rejected(tamper(data, anchor_pose=scaled), patch.lattice) == "invalid"
    assert rejected(tamper(data, anchor_pose=[float("nan")] * 16), patch.lattice) == "invalid"
    assert rejected(tamper(data, first_frame=10, last_frame=2), patch.lattice) == "invalid"
    assert rejected(tamper(data, producer=0), patch.lattice) == "invalid"
    assert rejected(tamper(data, extra=1), patch.lattice) == "invalid"


def test_array_contents_are_validated(patch: Patch) -> None:
    m, n, v = patch.block_count, patch.lattice.voxels_per_block, patch.voxel_count
    mask_at, values_at = 6 * m, m * (6 + n // 8)  # where the observed bits, then the tsdf values, start

    def with_raw(raw: bytes | bytearray) -> bytes:
        payload = zstandard.ZstdCompressor(level=1).compress(bytes(raw))
        return tamper(encode_patch(patch), payload=payload)

    b = patch.blocks
    assert decode_patch(with_raw(pack_blocks(b.keys, b.tsdf, b.weight)), patch.lattice, MAX_BYTES) == patch
    duplicate = b.keys.copy()
    duplicate[1] = duplicate[0]
    assert rejected(with_raw(pack_blocks(duplicate, b.tsdf, b.weight)), patch.lattice) == "invalid"
    tsdf = b.tsdf.copy()
    tsdf[b.weight > 0] = -128
    assert rejected(with_raw(pack_blocks(b.keys, tsdf, b.weight)), patch.lattice) == "invalid"
    raw = bytearray(pack_blocks(b.keys, b.tsdf, b.weight))
    raw[values_at + v] = raw[values_at + 2 * v] = 0  # the first observed voxel's weight, both bytes
    assert rejected(with_raw(raw), patch.lattice) == "invalid"
    raw = bytearray(pack_blocks(b.keys, b.tsdf, b.weight))
    unobserved = int(np.flatnonzero(b.weight[0] == 0)[0])
    raw[mask_at + unobserved // 8] |= 0x80 >> (unobserved % 8)  # one more observed bit than values and header say
    assert rejected(with_raw(raw), patch.lattice) == "invalid"
    raw = bytearray(pack_blocks(b.keys, b.tsdf, b.weight))
    raw[mask_at : mask_at + n // 8] = bytes(n // 8)  # a block with nothing observed
    assert rejected(with_raw(raw), patch.lattice) == "invalid"
    assert m > 1 and n == 512 and b.weight.dtype == np.uint16


def test_only_observed_voxels_carry_values(patch: Patch) -> None:
    b = patch.blocks
    raw = pack_blocks(b.keys, b.tsdf, b.weight)
    assert len(raw) == packed_size(patch.lattice, patch.block_count, patch.voxel_count)
    assert len(raw) < 6 * patch.block_count + 3 * b.weight.size  # less than the dense arrays
    decoded = decode_patch(encode_patch(patch), patch.lattice, MAX_BYTES)
    assert decoded.blocks.same_as(b)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.binary(max_size=4096))
def test_random_bytes_raise_only_patch_decode_errors(data: bytes) -> None:
    with pytest.raises(PatchDecodeError):
        decode_patch(data, Lattice(0.2, 8, 4.0), MAX_BYTES)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.data())
def test_mutated_patches_raise_only_patch_decode_errors(small: bytes, data: st.DataObject) -> None:
    mutated = bytearray(small)
    for _ in range(data.draw(st.integers(1, 4))):
        kind = data.draw(st.sampled_from(["flip", "set", "insert", "delete", "truncate"]))
        at = data.draw(st.integers(0, max(len(mutated) - 1, 0)))
        if kind == "flip" and mutated:
            mutated[at] ^= 1 << data.draw(st.integers(0, 7))
        elif kind == "set" and mutated:
            mutated[at] = data.draw(st.integers(0, 255))
        elif kind == "insert":
            mutated[at:at] = data.draw(st.binary(min_size=1, max_size=8))
        elif kind == "delete":
            del mutated[at : at + data.draw(st.integers(1, 8))]
        else:
            del mutated[at:]
    try:
        decoded = decode_patch(bytes(mutated), Lattice(0.2, 8, 4.0), MAX_BYTES)
    except PatchDecodeError:
        return
    assert isinstance(decoded, Patch)  # a mutation that kept the message intact
