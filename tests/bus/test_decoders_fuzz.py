"""Every decoder of network input under attack (issue 7): arbitrary bytes, well-formed envelopes with hostile
contents, and valid messages with bytes flipped, inserted or cut. The only outcomes allowed are a valid model
(whose invariants hold and which re-encodes to itself) or the decoder's documented error. Also: allocation stays
bounded for inputs that claim huge sizes, every size limit accepts the limit and rejects one past it, and the
fuzzing entry point `swarm.fuzz` runs.

The generic codec, decode_patch and the digest wire dicts have example-based tests of their own
(tests/bus/test_codec.py, tests/patches/test_wire.py, tests/patches/test_digest.py); this file covers every
decoder the same way, with structure-aware mutations that reach past the envelope checks.
"""

from __future__ import annotations

import functools
import math
import random
import re
import subprocess
import sys
import time
import tracemalloc
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import pytest
import zstandard
from hypothesis import HealthCheck, event, given, reject, settings, target
from hypothesis import strategies as st
from hypothesis.control import currently_in_test_context

from swarm import fuzz
from swarm.bus.codec import (
    DEFAULT_MAX_BYTES,
    MAX_CONTAINER_LEN,
    SCHEMA_VERSION,
    DecodeError,
    WireMessage,
    decode,
    encode,
)
from swarm.bus.holdings import MAX_EPOCHS_PER_PRODUCER, MAX_PRODUCERS, MAX_RANGES, DigestWire
from swarm.bus.keys import MAX_AGENT_ID, MIN_AGENT_ID
from swarm.bus.messages import AgentState
from swarm.bus.phase import Phase
from swarm.patches import wire
from swarm.patches.digest import DigestMessage, PatchDigest
from swarm.patches.lattice import Lattice
from swarm.patches.patch import TSDF_SCALE, Patch, PatchId, is_rigid, packed_size
from swarm.patches.wire import (
    MAX_EXPANSION,
    MAX_EXTENT_M,
    PatchDecodeError,
    decode_expected,
    decode_patch,
    encode_patch,
)
from swarm.roles.messages import MAX_CANDIDATES, MAX_MEMBERS, MAX_VISITED, FrontierReport, TargetAssignment
from swarm.sync.chunks import MAX_CHUNKS, PatchChunk, Reassembler, split_patch
from swarm.sync.requests import MAX_IDS_PER_REQUEST, parse_request, request_parameters
from tests.bus.fuzz_inputs import (
    BOUNDARY_INTS,
    HOSTILE_HEADERS,
    LATTICES,
    MAX_COUNTER,
    agent_ids,
    agent_states,
    digest_messages,
    digest_wires,
    frontier_reports,
    mutated,
    mutated_bytes,
    nudged,
    patch_chunks,
    patches,
    structures,
    target_assignments,
)

pytestmark = pytest.mark.fuzz  # pure, but thousands of generated inputs: a minute of CPU

FUZZ = settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
FEW = settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
REASONS = {"too_large", "not_msgpack", "bad_envelope", "version", "kind", "invalid"}
PATCH_REASONS = {
    "too_large",
    "not_msgpack",
    "version",
    "invalid",
    "lattice",
    "bounds",
    "empty",
    "too_many_blocks",
    "outside_volume",
    "checksum",
    "decompress",
    "shape",
    "id_mismatch",
}
PATCH_MAX_BYTES = fuzz.PATCH_MAX_BYTES
CHUNK_MAX_BYTES = fuzz.CHUNK_MAX_BYTES  # the sync service's bound for default settings
SMALL_PEAK = 2 << 20  # "a few MB": what decoding a hostile claim may allocate at most
REPO_ROOT = Path(__file__).resolve().parents[2]
SEEDS = {decoder.name: decoder.seed for decoder in fuzz.DECODERS}  # one valid input of every decoder


def pack(obj: Any) -> bytes:
    return msgpack.packb(obj, use_bin_type=True)


def envelope(fields: Any, kind: Any, version: Any = SCHEMA_VERSION) -> bytes:
    """The message as a sender would put it on the wire; in a property test, a generated input msgpack cannot
    encode (an integer beyond 64 bits) is rejected: no decoder can ever receive it."""
    try:
        return pack({"v": version, "k": kind, "d": fields})
    except OverflowError:
        reject()
        raise


def outcome_event(text: str) -> None:
    """Count an outcome in hypothesis's statistics (--hypothesis-show-statistics); no-op outside @given."""
    if currently_in_test_context():
        event(text)


def peak_bytes(action: Callable[[], object]) -> int:
    """Peak traced allocation while `action` runs."""
    tracemalloc.start()
    try:
        action()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


# --- invariants of accepted messages ----------------------------------------------------------------------


def check_digest(digest: DigestWire) -> None:
    keys = [(e.producer, e.epoch) for e in digest.entries]
    assert keys == sorted(set(keys))
    assert len({p for p, _ in keys}) <= MAX_PRODUCERS
    assert all(sum(1 for p, _ in keys if p == producer) <= MAX_EPOCHS_PER_PRODUCER for producer, _ in keys)
    assert sum(len(e.ranges) for e in digest.entries) <= MAX_RANGES
    for entry in digest.entries:
        assert MIN_AGENT_ID <= entry.producer <= MAX_AGENT_ID and 0 <= entry.epoch <= MAX_COUNTER
        previous_hi = -2
        for lo, hi in entry.ranges:
            assert previous_hi + 1 < lo <= hi <= MAX_COUNTER
            previous_hi = hi
    as_set = PatchDigest.from_wire_model(digest)
    assert PatchDigest.from_wire(as_set.to_wire()) == as_set


def check_state(msg: AgentState) -> None:
    assert MIN_AGENT_ID <= msg.id <= MAX_AGENT_ID and MIN_AGENT_ID <= msg.leader <= MAX_AGENT_ID
    floats = [*msg.position, *msg.velocity, *(msg.heading_to or ()), msg.t, msg.yaw_deg]
    assert all(math.isfinite(x) for x in floats) and msg.t >= 0 and abs(msg.yaw_deg) <= 360
    assert len(msg.flight_mode) <= 32 and msg.flight_mode.isascii() and msg.flight_mode.isprintable()
    assert msg.phase in Phase
    check_digest(msg.holdings)


def check_digest_message(msg: DigestMessage) -> None:
    check_digest(msg.digest)


def check_chunk(msg: PatchChunk) -> None:
    assert 0 <= msg.index < msg.count <= MAX_CHUNKS
    assert 1 <= len(msg.data) <= msg.total_bytes <= 1 << 30
    assert len(msg.data) < CHUNK_MAX_BYTES


def check_points(points: np.ndarray, limit: int) -> None:
    assert points.dtype == np.float32 and points.ndim == 2 and points.shape[1] == 3
    assert len(points) <= limit and np.isfinite(points).all()


def check_frontiers(msg: FrontierReport) -> None:
    check_points(msg.viewpoints, MAX_CANDIDATES)
    check_points(msg.points, MAX_CANDIDATES)
    check_points(msg.visited, MAX_VISITED)
    assert msg.gains.dtype == np.float32 and msg.gains.shape == (len(msg.viewpoints),) == (len(msg.points),)
    assert np.isfinite(msg.gains).all() and (msg.gains >= 0).all()


def check_targets(msg: TargetAssignment) -> None:
    assert 1 <= len(msg.members) <= MAX_MEMBERS and msg.leader in msg.members
    assert len(set(msg.drones)) == len(msg.drones) and set(msg.drones) <= set(msg.members)
    check_points(msg.viewpoints, MAX_MEMBERS)
    check_points(msg.points, MAX_MEMBERS)
    assert len(msg.viewpoints) == len(msg.points) == len(msg.drones)


@dataclass(frozen=True)
class CodecCase:
    model: type[WireMessage]
    valid: st.SearchStrategy[Any]
    check: Callable[[Any], None]
    max_bytes: int = DEFAULT_MAX_BYTES


CASES = {
    "state": CodecCase(AgentState, agent_states, check_state),
    "digest": CodecCase(DigestMessage, digest_messages, check_digest_message),
    "chunk": CodecCase(PatchChunk, patch_chunks(), check_chunk, CHUNK_MAX_BYTES),
    "frontiers": CodecCase(FrontierReport, frontier_reports(), check_frontiers),
    "targets": CodecCase(TargetAssignment, target_assignments(), check_targets),
}
KINDS = sorted({case.model.KIND for case in CASES.values()} | {"patch"})


def decoded_or_none(case: CodecCase, data: bytes) -> Any:
    """The decoded message (invariants checked, re-encoding round-trips) or None if DecodeError said why."""
    try:
        msg = decode(data, case.model, case.max_bytes)
    except DecodeError as exc:
        assert exc.reason in REASONS, exc
        outcome_event(f"rejected: {exc.reason}")
        return None
    outcome_event("accepted")
    assert type(msg) is case.model and len(data) <= case.max_bytes
    case.check(msg)
    again = encode(msg)
    assert decode(again, case.model, len(again)) == msg
    assert encode(decode(again, case.model, len(again))) == again
    return msg


# --- codec decoders: heartbeat, digest, chunk, frontier report, target assignment ---------------------------


@pytest.mark.parametrize("name", sorted(CASES))
@FUZZ
@given(data=st.binary(max_size=600))
def test_arbitrary_bytes(name: str, data: bytes) -> None:
    decoded_or_none(CASES[name], data)


@pytest.mark.parametrize("name", sorted(CASES))
@FUZZ
@given(data=st.data())
def test_envelopes_with_hostile_contents(name: str, data: st.DataObject) -> None:
    case = CASES[name]
    fields = data.draw(case.valid).model_dump(mode="python")
    version = data.draw(st.sampled_from([SCHEMA_VERSION] * 4 + [0, 2, True, 1.0, "1", 2**64 - 1]))
    kind = data.draw(st.sampled_from([case.model.KIND] * 4 + KINDS + ["", "STATE", 5]))
    contents = data.draw(mutated(fields) | structures)
    decoded_or_none(case, envelope(contents, kind, version))


@pytest.mark.parametrize("name", sorted(CASES))
@FUZZ
@given(data=st.data())
def test_valid_messages_round_trip(name: str, data: st.DataObject) -> None:
    case = CASES[name]
    msg = data.draw(case.valid)
    assert decoded_or_none(case, encode(msg)) == msg


@pytest.mark.parametrize("name", sorted(CASES))
@FUZZ
@given(data=st.data())
def test_valid_messages_with_bytes_flipped_or_cut(name: str, data: st.DataObject) -> None:
    case = CASES[name]
    decoded_or_none(case, data.draw(mutated_bytes(encode(data.draw(case.valid)))))


ranges = st.lists(st.integers(-2, 40) | st.sampled_from(BOUNDARY_INTS), min_size=2, max_size=2) | structures
hostile_entries = st.fixed_dictionaries(
    {
        "producer": agent_ids | st.sampled_from(BOUNDARY_INTS),
        "epoch": st.integers(0, 3) | st.sampled_from(BOUNDARY_INTS),
        "ranges": st.lists(ranges, max_size=8),
    }
)
hostile_holdings = st.fixed_dictionaries({"entries": st.lists(hostile_entries, max_size=6)}) | digest_wires.map(
    lambda d: PatchDigest.from_wire_model(d).to_wire()
).flatmap(mutated)


@FUZZ
@given(state=agent_states, holdings=hostile_holdings)
def test_hostile_holdings_in_heartbeats(state: AgentState, holdings: Any) -> None:
    """A heartbeat carrying a hostile digest decodes exactly when the digest alone is valid, and then canonical."""
    fields = {**state.model_dump(mode="python"), "holdings": holdings}
    decoded = decoded_or_none(CASES["state"], envelope(fields, AgentState.KIND))
    try:
        alone = PatchDigest.from_wire(msgpack.unpackb(pack(holdings)))
    except ValueError:
        alone = None
    assert (decoded is None) == (alone is None)
    if decoded is not None:
        assert PatchDigest.from_wire_model(decoded.holdings) == alone


# --- patches: decode_patch and decode_expected ------------------------------------------------------------


def check_patch(patch: Patch, lattice: Lattice) -> None:
    blocks = patch.blocks
    m, n = blocks.block_count, lattice.voxels_per_block
    assert patch.lattice == lattice and blocks.weight.dtype == lattice.weight_dtype
    assert blocks.keys.shape == (m, 3) and blocks.tsdf.shape == blocks.weight.shape == (m, n)
    assert len(np.unique(blocks.keys, axis=0)) == m and np.abs(blocks.keys).max(initial=0) <= 2**15
    assert blocks.tsdf.min(initial=0) >= -TSDF_SCALE and not blocks.tsdf[blocks.weight == 0].any()
    lo, hi = patch.bounds
    assert np.all(lo <= hi) and np.all(hi - lo <= MAX_EXTENT_M)
    if m:
        klo, khi = lattice.block_bounds(blocks.keys)
        assert np.all(klo >= lo - 1e-3) and np.all(khi <= hi + 1e-3)
    assert is_rigid(patch.anchor_pose) and patch.span.first <= patch.span.last
    again = encode_patch(patch)
    assert decode_patch(again, lattice, max(len(again), PATCH_MAX_BYTES)) == patch


def patch_or_reason(
    data: bytes, lattice: Lattice, pid: PatchId | None = None, max_bytes: int = PATCH_MAX_BYTES
) -> Patch | str:
    """The decoded patch (invariants checked) or the PatchDecodeError reason."""
    try:
        if pid is None:
            patch = decode_patch(data, lattice, max_bytes)
        else:
            patch = decode_expected(data, pid, lattice, max_bytes)
    except PatchDecodeError as exc:
        assert exc.reason in PATCH_REASONS, exc
        outcome_event(f"rejected: {exc.reason}")
        return exc.reason
    outcome_event("accepted")
    check_patch(patch, lattice)
    assert pid is None or patch.id == pid
    return patch


def with_checksum(fields: dict[str, Any]) -> dict[str, Any]:
    """`fields` with the CRC-32 a sender would compute (when the fields allow one), so lies reach the later checks."""
    try:
        return {**fields, "checksum": wire._checksum(fields, fields["payload"])}
    except Exception:
        return fields


@FUZZ
@given(
    data=st.binary(max_size=2000),
    lattice=st.sampled_from(LATTICES),
    pid=st.builds(PatchId, agent_ids, st.just(0), st.just(0)),
)
def test_decode_expected_on_arbitrary_bytes(data: bytes, lattice: Lattice, pid: PatchId) -> None:
    assert isinstance(patch_or_reason(data, lattice, pid), str)


@FUZZ
@given(patch=patches(), other=st.builds(PatchId, agent_ids, st.integers(0, 5), st.integers(0, 5)))
def test_valid_patches_round_trip(patch: Patch, other: PatchId) -> None:
    data = encode_patch(patch)
    assert patch_or_reason(data, patch.lattice) == patch
    assert patch_or_reason(data, patch.lattice, patch.id) == patch
    if other != patch.id:
        assert patch_or_reason(data, patch.lattice, other) == "id_mismatch"


@FUZZ
@given(patch=patches(), data=st.data())
def test_patches_with_bytes_flipped_or_cut(patch: Patch, data: st.DataObject) -> None:
    mutated_wire = data.draw(mutated_bytes(encode_patch(patch)))
    for pid in (None, patch.id):
        outcome = patch_or_reason(mutated_wire, patch.lattice, pid)
        assert isinstance(outcome, str) or outcome.id == patch.id or pid is None


@FUZZ
@given(patch=patches(), data=st.data())
def test_patch_header_lies_with_a_valid_checksum(patch: Patch, data: st.DataObject) -> None:
    """Header fields changed and the CRC-32 recomputed (or not): every later check must still hold the line."""
    env = msgpack.unpackb(encode_patch(patch), raw=False)
    fields = data.draw(mutated(env["d"]))
    if isinstance(fields, dict) and data.draw(st.booleans()):
        fields = with_checksum(fields)
    patch_or_reason(envelope(fields, wire.KIND), patch.lattice)


@dataclass(frozen=True)
class RawArrays:
    keys: np.ndarray
    tsdf: np.ndarray
    weight: np.ndarray

    observed: np.ndarray  # the bits sent: weight > 0, or arbitrary (then observed voxels of weight 0 are likely)

    def payload(self, lattice: Lattice, extra: bytes) -> bytes:
        """Laid out as `pack_blocks` does, but with these observed bits and whatever values they select."""
        n = lattice.voxels_per_block
        weights = self.weight.reshape(-1, n)[self.observed].astype(lattice.weight_dtype)
        planes = [weights.astype(np.uint8)] if weights.dtype.itemsize == 1 else [weights & 0xFF, weights >> 8]
        parts = [self.keys.astype("<i2"), np.packbits(self.observed, axis=1)]
        parts += [self.tsdf.reshape(-1, n)[self.observed].astype(np.int8)] + [p.astype(np.uint8) for p in planes]
        raw = b"".join(part.tobytes() for part in parts)
        return zstandard.ZstdCompressor(level=1).compress(raw + extra)


@st.composite
def raw_arrays(draw: st.DrawFn, lattice: Lattice, blocks: int) -> RawArrays:
    """Arbitrary keys (duplicates likely), tsdf (-128 possible), weights (0 on observed voxels possible) and
    observed bits (blocks with none possible)."""
    size = blocks * lattice.voxels_per_block
    keys = np.array(draw(st.lists(st.integers(-3, 3), min_size=3 * blocks, max_size=3 * blocks))).reshape(-1, 3)
    weight = np.array(draw(st.lists(st.sampled_from([0, 0, 1, 2, 255]), min_size=size, max_size=size)))
    tsdf = np.array(draw(st.lists(st.integers(-128, 127), min_size=size, max_size=size)))
    if draw(st.booleans()):
        tsdf = np.clip(tsdf, -TSDF_SCALE, TSDF_SCALE) * (weight > 0)
    n = lattice.voxels_per_block
    if draw(st.booleans()):
        observed = weight.reshape(blocks, n) > 0
    else:
        observed = np.array(draw(st.lists(st.booleans(), min_size=size, max_size=size)), dtype=bool).reshape(-1, n)
    return RawArrays(keys, tsdf, weight, observed)


@FEW
@given(patch=patches(), data=st.data())
def test_payloads_with_arbitrary_arrays(patch: Patch, data: st.DataObject) -> None:
    """A sender that computes the checksum, the box and the counts right, but lies in the arrays."""
    lattice = patch.lattice
    arrays = data.draw(raw_arrays(lattice, patch.block_count))
    fields = msgpack.unpackb(encode_patch(patch), raw=False)["d"]
    fields["payload"] = arrays.payload(lattice, data.draw(st.sampled_from([b"", b"", b"\x00"])))
    if data.draw(st.booleans()):
        fields["voxel_count"] = int(np.count_nonzero(arrays.observed))
    if patch.block_count and data.draw(st.booleans()):
        lo, hi = lattice.block_bounds(arrays.keys)
        fields["bbox_min"], fields["bbox_max"] = lo.tolist(), hi.tolist()
    outcome = patch_or_reason(envelope(with_checksum(fields), wire.KIND), lattice)
    assert isinstance(outcome, str) or outcome.block_count == patch.block_count


# --- pull requests: parse_request -------------------------------------------------------------------------


def check_request(params: dict[str, str], ids: list[PatchId], requester: int | None) -> None:
    """Accepted only if every id is canonical, at most MAX_IDS_PER_REQUEST of them, the requester a drone id."""
    parts = params["ids"].split(",")
    assert 1 <= len(parts) <= MAX_IDS_PER_REQUEST and len(ids) == len(set(ids)) == len(set(parts))
    assert [str(pid) for pid in ids] == list(dict.fromkeys(parts))
    assert all(MIN_AGENT_ID <= pid.producer <= MAX_AGENT_ID for pid in ids)
    assert all(max(pid.epoch, pid.seq) <= MAX_COUNTER for pid in ids)
    if requester is None:
        assert "from" not in params
    else:
        assert MIN_AGENT_ID <= requester <= MAX_AGENT_ID and params["from"] == str(requester)
        text = request_parameters(ids, requester)
        assert parse_request(dict(p.split("=", 1) for p in text.split(";"))) == (ids, requester)


def request_outcome(params: dict[str, str]) -> bool:
    try:
        ids, requester = parse_request(params)
    except ValueError:
        outcome_event("rejected")
        return False
    outcome_event("accepted")
    check_request(params, ids, requester)
    return True


number_text = (
    st.integers(0, 300).map(str)
    | st.sampled_from([str(n) for n in BOUNDARY_INTS])
    | st.sampled_from(["", "01", "+1", "-1", " 1", "1 ", "1\n", "\u0661", "1_0", "0x1", "1e3", "9" * 20])
)
valid_id_text = st.builds(lambda p, e, s: f"{p}.{e}.{s}", agent_ids, st.integers(0, 9), st.integers(0, 9))
id_text = st.builds(lambda p, e, s: f"{p}.{e}.{s}", number_text, number_text, number_text) | st.text(max_size=12)
near_valid_ids = st.tuples(
    st.lists(valid_id_text, max_size=8), st.lists(valid_id_text.flatmap(nudged) | id_text, max_size=2)
).map(lambda parts: parts[0] + parts[1]) | st.lists(valid_id_text | id_text, max_size=MAX_IDS_PER_REQUEST + 2)
near_valid_parameters = st.fixed_dictionaries(
    {"ids": near_valid_ids.map(",".join)}, optional={"from": number_text, "x": st.text(max_size=5)}
)


@FUZZ
@given(params=st.dictionaries(st.sampled_from(["ids", "from"]) | st.text(max_size=5), st.text(max_size=80)))
def test_arbitrary_request_parameters(params: dict[str, str]) -> None:
    request_outcome(params)


@FUZZ
@given(params=near_valid_parameters)
def test_near_valid_request_parameters(params: dict[str, str]) -> None:
    request_outcome(params)


request_ids = st.builds(PatchId, agent_ids, st.integers(0, MAX_COUNTER), st.integers(0, MAX_COUNTER))


@FUZZ
@given(ids=st.lists(request_ids, min_size=1, max_size=MAX_IDS_PER_REQUEST), requester=agent_ids)
def test_valid_requests_round_trip(ids: list[PatchId], requester: int) -> None:
    params = dict(p.split("=", 1) for p in request_parameters(ids, requester).split(";"))
    assert parse_request(params) == (list(dict.fromkeys(ids)), requester)


def test_a_trailing_newline_is_not_a_canonical_id() -> None:
    """Regression: the id pattern ended in `$`, which also matches before a final newline."""
    for text in ("1.2.3\n", "1.2.3\n,4.5.6"):
        with pytest.raises(ValueError):
            parse_request({"ids": text})


# --- reassembly: Reassembler.add with arbitrary chunk sequences --------------------------------------------


class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


@st.composite
def colliding_chunks(draw: st.DrawFn) -> PatchChunk:
    """Chunks of three patch ids with small counts and sizes, so assemblies collide, contradict and complete."""
    count = draw(st.integers(1, 4))
    data = draw(st.binary(min_size=1, max_size=400))
    total = draw(st.just(len(data)) | st.integers(len(data), 1000))
    crc = zlib.crc32(data) if draw(st.booleans()) else draw(st.sampled_from([0, 1, 0xFFFFFFFF]))
    return PatchChunk(
        sender=draw(agent_ids),
        producer=1,
        epoch=0,
        seq=draw(st.integers(0, 2)),
        index=draw(st.integers(0, count - 1)),
        count=count,
        total_bytes=total,
        crc32=crc,
        data=data,
    )


REAL_PID = PatchId(1, 0, 3)
chunk_headers = st.tuples(
    st.integers(0, 3),
    st.sampled_from([1, 2, 3, 4, 4]),
    st.sampled_from([300, 400, 500, 501]) | st.integers(1, 600),  # around the 500-byte patch limit
    st.sampled_from([0, 1, 0xFFFFFFFF]),
)


@st.composite
def chunk_sequences(draw: st.DrawFn) -> tuple[bytes, list[PatchChunk | float]]:
    """A real patch's bytes, and a sequence of its chunks (duplicates too), lies sharing a few made-up headers
    (seq 3 is the real patch's), and pauses of the clock."""
    real = draw(st.binary(min_size=1, max_size=500))
    honest = split_patch(1, REAL_PID, real, draw(st.integers(100, 400)))
    headers = draw(st.lists(chunk_headers, min_size=1, max_size=2))
    steps: list[PatchChunk | float] = []
    for kind in draw(st.lists(st.sampled_from(["honest", "lie", "lie", "pause"]), max_size=25)):
        if kind == "pause":
            steps.append(draw(st.floats(0.0, 10.0)))
        elif kind == "honest":
            steps.append(draw(st.sampled_from(honest)))
        else:
            seq, count, total, crc = draw(st.sampled_from(headers))
            size = draw(st.sampled_from([min(total, 400)]) | st.integers(1, min(total, 400)))  # big ones often
            steps.append(
                PatchChunk(
                    sender=draw(agent_ids),
                    producer=1,
                    epoch=0,
                    seq=seq,
                    index=draw(st.integers(0, count - 1)),
                    count=count,
                    total_bytes=total,
                    crc32=crc,
                    data=draw(st.binary(min_size=size, max_size=size)),
                )
            )
    return real, steps


@FUZZ
@given(sequence=chunk_sequences())
def test_arbitrary_chunk_sequences(sequence: tuple[bytes, list[PatchChunk | float]]) -> None:
    """Completed bytes always match the chunk's size and CRC (and are the real patch's, for its id); held bytes
    never exceed the bounds (two lying chunks of 400 bytes would, were an assembly not held to its total_bytes)."""
    real, steps = sequence
    clock = Clock()
    reassembler = Reassembler(600, 5.0, 500, clock=clock)
    most = 0
    for step in steps:
        if isinstance(step, float):
            clock.now += step
            reassembler.expire()
            continue
        out = reassembler.add(step)
        assert out is None or (len(out) == step.total_bytes and zlib.crc32(out) == step.crc32)
        assert out is None or step.patch_id != REAL_PID or out == real
        most = max(most, reassembler.pending_bytes)
        assert 0 <= reassembler.pending_bytes <= max(reassembler.max_bytes, reassembler.max_patch_bytes)
        partial = reassembler.partial(step.patch_id)
        if step.total_bytes <= reassembler.max_patch_bytes:  # (an oversize chunk leaves its assembly alone)
            assert partial is None or partial[0] <= partial[1] == step.count
    assert set(reassembler.dropped) <= {"mismatch", "overflow", "expired", "corrupt", "oversize"}
    target(most, label="most bytes held")  # steer the search toward full reassemblers


@FUZZ
@given(data=st.data(), patch_bytes=st.binary(min_size=1, max_size=3000), chunk_bytes=st.integers(64, 1024))
def test_an_honest_patch_completes_among_hostile_chunks(
    data: st.DataObject, patch_bytes: bytes, chunk_bytes: int
) -> None:
    pid = PatchId(1, 0, 9)
    honest = split_patch(2, pid, patch_bytes, chunk_bytes)
    honest = honest + data.draw(st.lists(st.sampled_from(honest), max_size=3))  # duplicates from other pulls
    hostile = data.draw(st.lists(colliding_chunks(), max_size=20))  # other patch ids (seq 0-2)
    steps = data.draw(st.permutations(honest + hostile))
    reassembler = Reassembler(1 << 20, 5.0, 1 << 20)
    seen: set[int] = set()
    for chunk in steps:
        out = reassembler.add(chunk)
        if chunk.patch_id != pid:
            continue
        completes = chunk.index not in seen and len(seen) == chunk.count - 1
        seen.add(chunk.index)
        assert out == (patch_bytes if completes else None)
        if completes:
            seen = set()  # a late duplicate starts a new assembly (the sync service drops those first)


# --- bounded allocation -----------------------------------------------------------------------------------


def claim_in_field(kind: str, field: str, claim: bytes) -> bytes:
    """A well-formed envelope prefix whose field `field` starts with the hostile header `claim`."""
    head = b"\x83" + pack("v") + pack(SCHEMA_VERSION) + pack("k") + pack(kind) + pack("d")
    return head + b"\x81" + pack(field) + claim + bytes(16)


FIELD_OF = {"state": "holdings", "digest": "digest", "chunk": "data", "frontiers": "viewpoints", "targets": "members"}


@pytest.mark.parametrize("claim", HOSTILE_HEADERS[:5], ids=["array32", "map32", "bin32", "str32", "ext32"])
@pytest.mark.parametrize("name", sorted(CASES))
def test_huge_claims_allocate_little(name: str, claim: bytes) -> None:
    case = CASES[name]
    for data in (claim + bytes(16), claim_in_field(case.model.KIND, FIELD_OF[name], claim)):
        peak = peak_bytes(functools.partial(decoded_or_none, case, data))
        assert decoded_or_none(case, data) is None
        assert peak < SMALL_PEAK, f"{peak} bytes for {data[:24].hex()}"


@pytest.mark.parametrize("claim", HOSTILE_HEADERS[:5], ids=["array32", "map32", "bin32", "str32", "ext32"])
def test_huge_claims_in_patches_allocate_little(claim: bytes) -> None:
    lattice = LATTICES[0]
    for data in (claim + bytes(16), claim_in_field(wire.KIND, "payload", claim)):
        peak = peak_bytes(functools.partial(patch_or_reason, data, lattice, max_bytes=4 << 20))
        assert patch_or_reason(data, lattice) == "not_msgpack"
        assert peak < SMALL_PEAK


def seed_fields(name: str) -> dict[str, Any]:
    return msgpack.unpackb(SEEDS[name](), raw=False)["d"]


def seed_patch_fields() -> dict[str, Any]:
    return seed_fields("patch")


def most_blocks(raw_bytes: int) -> int:
    """The most blocks a header with the seed's voxel count may claim within `raw_bytes` of packed arrays."""
    voxels = seed_patch_fields()["voxel_count"]
    return (raw_bytes - packed_size(fuzz.LATTICE, 0, voxels)) // packed_size(fuzz.LATTICE, 1, 0)


def test_patch_header_claiming_a_huge_raw_size_allocates_little() -> None:
    data = envelope(with_checksum(seed_patch_fields() | {"block_count": 10**15}), wire.KIND)
    peak = peak_bytes(lambda: patch_or_reason(data, fuzz.LATTICE, max_bytes=4 << 20))
    assert patch_or_reason(data, fuzz.LATTICE, max_bytes=4 << 20) == "too_large"
    assert peak < SMALL_PEAK


def test_zstd_frame_declaring_a_huge_size_allocates_little() -> None:
    # magic, single-segment frame with an 8-byte content size of 2**60, then a last raw block of one byte
    frame = b"\x28\xb5\x2f\xfd" + b"\xe0" + (2**60).to_bytes(8, "little") + b"\x09\x00\x00" + b"x"
    assert zstandard.frame_content_size(frame) == 2**60
    data = envelope(with_checksum(seed_patch_fields() | {"payload": frame}), wire.KIND)
    peak = peak_bytes(lambda: patch_or_reason(data, fuzz.LATTICE))
    assert patch_or_reason(data, fuzz.LATTICE) == "shape"
    assert peak < SMALL_PEAK


def test_a_patch_at_the_expansion_cap_allocates_at_most_the_cap() -> None:
    """A frame without a declared size, under a header claiming the most blocks allowed: the decoder allocates
    the size those blocks need (MAX_EXPANSION * max_bytes at most), never more."""
    cap = MAX_EXPANSION * PATCH_MAX_BYTES
    blocks = most_blocks(cap)
    stream = zstandard.ZstdCompressor().compressobj()
    frame = stream.compress(b"x" * 100) + stream.flush()
    assert zstandard.frame_content_size(frame) == -1
    data = envelope(with_checksum(seed_patch_fields() | {"block_count": blocks, "payload": frame}), wire.KIND)
    peak = peak_bytes(lambda: patch_or_reason(data, fuzz.LATTICE))
    assert patch_or_reason(data, fuzz.LATTICE) == "shape"
    assert peak < cap + SMALL_PEAK


def test_nested_length_claims_stay_within_the_codecs_documented_bound() -> None:
    """Each nested array claims MAX_CONTAINER_LEN items and none arrive. msgpack would allocate every claimed
    list up front, at each of its 1024 nesting levels (128 MiB); the codec's structure check refuses a document
    declaring more items than it has bytes before msgpack runs, so nothing of the sort is allocated."""
    data = (b"\xdc" + MAX_CONTAINER_LEN.to_bytes(2, "big")) * 2000
    peak = peak_bytes(lambda: decoded_or_none(CASES["state"], data))
    assert decoded_or_none(CASES["state"], data) is None
    assert peak < SMALL_PEAK


def test_a_chunk_claiming_a_huge_patch_is_not_stored() -> None:
    chunk = PatchChunk(
        sender=1, producer=1, epoch=0, seq=0, index=0, count=MAX_CHUNKS, total_bytes=1 << 30, crc32=0, data=b"x"
    )
    reassembler = Reassembler(1 << 20, 5.0, 4 << 20)
    peak = peak_bytes(lambda: reassembler.add(chunk))
    assert reassembler.pending_bytes == 0 and reassembler.dropped == {"oversize": 1}
    assert peak < SMALL_PEAK


# --- every size limit: accepted at the limit, rejected one past it -------------------------------------------


def reason(data: bytes, model: type[WireMessage], max_bytes: int = DEFAULT_MAX_BYTES) -> str:
    try:
        decode(data, model, max_bytes)
    except DecodeError as exc:
        return exc.reason
    return "accepted"


@pytest.mark.parametrize("name", sorted(CASES))
def test_message_size_limit(name: str) -> None:
    data, model = SEEDS[name](), CASES[name].model
    assert reason(data, model, len(data)) == "accepted"
    assert reason(data, model, len(data) - 1) == "too_large"


def test_patch_size_and_expansion_limits() -> None:
    data = SEEDS["patch"]()
    assert isinstance(patch_or_reason(data, fuzz.LATTICE, max_bytes=len(data)), Patch)
    assert patch_or_reason(data, fuzz.LATTICE, max_bytes=len(data) - 1) == "too_large"
    most = most_blocks(MAX_EXPANSION * PATCH_MAX_BYTES)
    assert packed_size(fuzz.LATTICE, most + 1, seed_patch_fields()["voxel_count"]) > MAX_EXPANSION * PATCH_MAX_BYTES
    for blocks, expected in ((most, "shape"), (most + 1, "too_large")):
        lie = envelope(with_checksum(seed_patch_fields() | {"block_count": blocks}), wire.KIND)
        assert patch_or_reason(lie, fuzz.LATTICE) == expected


def test_patch_extent_limit() -> None:
    fields = seed_patch_fields()
    assert fields["bbox_min"][0] == 0.0  # the seed's blocks start at x = 0: the box may grow from there
    outcomes = []
    for extent in (MAX_EXTENT_M, float(np.nextafter(MAX_EXTENT_M, np.inf))):
        box = {"bbox_max": [extent, *fields["bbox_max"][1:]]}
        outcomes.append(patch_or_reason(envelope(with_checksum(fields | box), wire.KIND), fuzz.LATTICE))
    assert isinstance(outcomes[0], Patch) and outcomes[0].bounds[1][0] == MAX_EXTENT_M
    assert outcomes[1] == "bounds"


def test_container_length_limit() -> None:
    fields = seed_fields("targets")
    for n, expected in ((MAX_CONTAINER_LEN, "invalid"), (MAX_CONTAINER_LEN + 1, "not_msgpack")):
        assert reason(envelope(fields | {"members": [1] * n}, "targets"), TargetAssignment) == expected


def test_member_limit() -> None:
    members = list(range(1, MAX_MEMBERS + 2))
    for n, expected in ((MAX_MEMBERS, "accepted"), (MAX_MEMBERS + 1, "invalid")):
        fields = {"leader": 1, "epoch": 0, "round": 0, "members": members[:n]}
        assert reason(envelope(fields, "targets"), TargetAssignment) == expected


def wire_points(n: int) -> dict[str, Any]:
    return {"dtype": "float32", "shape": [n, 3], "data": bytes(12 * n)}


def test_candidate_and_visited_limits() -> None:
    base = {"id": 2, "epoch": 0, "seq": 0, "position": [0.0, 0.0, 1.0]}
    for n, expected in ((MAX_CANDIDATES, "accepted"), (MAX_CANDIDATES + 1, "invalid")):
        gains = {"dtype": "float32", "shape": [n], "data": bytes(4 * n)}
        fields = base | {"viewpoints": wire_points(n), "points": wire_points(n), "gains": gains}
        assert reason(envelope(fields, "frontiers"), FrontierReport) == expected
    for n, expected in ((MAX_VISITED, "accepted"), (MAX_VISITED + 1, "invalid")):
        assert reason(envelope(base | {"visited": wire_points(n)}, "frontiers"), FrontierReport) == expected


def heartbeat_with(entries: list[dict[str, Any]]) -> bytes:
    fields = seed_fields("state") | {"holdings": {"entries": entries}}
    return envelope(fields, AgentState.KIND)


def entries_of(producers: int, epochs: int, *ranges: int) -> list[dict[str, Any]]:
    """Entries of `producers` x `epochs`, the k-th holding ranges[k] ranges (the last count repeats)."""
    keys = [(p, e) for p in range(1, producers + 1) for e in range(epochs)]
    counts = [ranges[min(k, len(ranges) - 1)] for k in range(len(keys))]
    return [
        {"producer": p, "epoch": e, "ranges": [[2 * i, 2 * i] for i in range(n)]} for (p, e), n in zip(keys, counts)
    ]


@pytest.mark.parametrize(
    "at, past",
    [
        (entries_of(MAX_PRODUCERS, 1, 1), entries_of(MAX_PRODUCERS + 1, 1, 1)),
        (entries_of(1, MAX_EPOCHS_PER_PRODUCER, 1), entries_of(1, MAX_EPOCHS_PER_PRODUCER + 1, 1)),
        (entries_of(1, 1, MAX_RANGES), entries_of(1, 1, MAX_RANGES + 1)),
        (entries_of(2, 1, MAX_RANGES // 2), entries_of(2, 1, MAX_RANGES // 2, MAX_RANGES // 2 + 1)),
    ],
    ids=["producers", "epochs", "ranges in an entry", "ranges in all"],
)
def test_digest_limits_in_heartbeats(at: list[dict[str, Any]], past: list[dict[str, Any]]) -> None:
    assert reason(heartbeat_with(at), AgentState) == "accepted"
    assert reason(heartbeat_with(past), AgentState) == "invalid"


def test_short_text_limit() -> None:
    fields = seed_fields("state")
    assert reason(envelope(fields | {"flight_mode": "x" * 32}, AgentState.KIND), AgentState) == "accepted"
    assert reason(envelope(fields | {"flight_mode": "x" * 33}, AgentState.KIND), AgentState) == "invalid"


@pytest.mark.parametrize(
    "at, past",
    [
        ({"count": MAX_CHUNKS, "index": MAX_CHUNKS - 1}, {"count": MAX_CHUNKS + 1, "index": 0}),
        ({"count": MAX_CHUNKS, "index": MAX_CHUNKS - 1}, {"count": MAX_CHUNKS, "index": MAX_CHUNKS}),
        ({"total_bytes": 1 << 30}, {"total_bytes": (1 << 30) + 1}),
        ({"total_bytes": 3, "data": b"abc"}, {"total_bytes": 3, "data": b"abcd"}),
        ({"epoch": MAX_COUNTER, "seq": MAX_COUNTER}, {"epoch": MAX_COUNTER + 1}),
        ({"sender": MAX_AGENT_ID, "producer": MAX_AGENT_ID}, {"producer": MAX_AGENT_ID + 1}),
    ],
)
def test_chunk_field_limits(at: dict[str, Any], past: dict[str, Any]) -> None:
    fields = seed_fields("chunk")
    assert reason(envelope(fields | at, PatchChunk.KIND), PatchChunk, CHUNK_MAX_BYTES) == "accepted"
    assert reason(envelope(fields | past, PatchChunk.KIND), PatchChunk, CHUNK_MAX_BYTES) == "invalid"


def test_chunk_of_the_full_chunk_size_fits_the_service_bound() -> None:
    chunk = split_patch(MAX_AGENT_ID, PatchId(MAX_AGENT_ID, MAX_COUNTER, MAX_COUNTER), bytes(8192), 8192)[0]
    assert len(encode(chunk)) <= CHUNK_MAX_BYTES
    assert reason(encode(chunk), PatchChunk, CHUNK_MAX_BYTES) == "accepted"


@pytest.mark.parametrize(
    "at, past",
    [
        (
            {"ids": ",".join(f"1.0.{s}" for s in range(MAX_IDS_PER_REQUEST))},
            {"ids": ",".join(f"1.0.{s}" for s in range(MAX_IDS_PER_REQUEST + 1))},
        ),
        ({"ids": f"{MAX_AGENT_ID}.0.0"}, {"ids": f"{MAX_AGENT_ID + 1}.0.0"}),
        ({"ids": f"1.{MAX_COUNTER}.{MAX_COUNTER}"}, {"ids": f"1.{MAX_COUNTER + 1}.0"}),
        ({"ids": "1.0.0", "from": str(MAX_AGENT_ID)}, {"ids": "1.0.0", "from": str(MAX_AGENT_ID + 1)}),
    ],
)
def test_request_limits(at: dict[str, str], past: dict[str, str]) -> None:
    assert request_outcome(at) is True
    assert request_outcome(past) is False


def chunks_of(seq: int, data: bytes, chunk_bytes: int) -> list[PatchChunk]:
    return split_patch(1, PatchId(1, 0, seq), data, chunk_bytes)


def test_reassembly_memory_limit() -> None:
    clock = Clock()
    reassembler = Reassembler(3000, 5.0, 1 << 20, clock=clock)
    for seq in (0, 1):
        clock.now += 1
        assert reassembler.add(chunks_of(seq, random.Random(seq).randbytes(3000), 1500)[0]) is None
    assert reassembler.pending_bytes == 3000 and len(reassembler) == 2 and not reassembler.dropped  # at the limit
    clock.now += 1
    assert reassembler.add(chunks_of(2, b"xy", 1)[0]) is None  # one byte past it
    assert reassembler.dropped == {"overflow": 1} and reassembler.partial(PatchId(1, 0, 0)) is None
    assert reassembler.pending_bytes == 1501


def test_reassembly_patch_size_limit() -> None:
    reassembler = Reassembler(1 << 20, 5.0, 1000)
    assert reassembler.add(chunks_of(0, bytes(1000), 1000)[0]) == bytes(1000)
    assert reassembler.add(chunks_of(1, bytes(1001), 1001)[0]) is None
    assert reassembler.dropped == {"oversize": 1} and reassembler.pending_bytes == 0


def test_an_assembly_never_holds_more_than_its_patch_size() -> None:
    """Regression: chunks of distinct indices could fill one assembly far past its total_bytes (4096 chunks of
    any size up to total_bytes each), beyond both max_bytes and max_patch_bytes."""
    data = random.Random(1).randbytes(1000)
    honest = chunks_of(0, data, 400)  # 400 + 400 + 200
    reassembler = Reassembler(1 << 20, 5.0, 1 << 20)
    assert reassembler.add(honest[0]) is None and reassembler.add(honest[1]) is None
    overfill = honest[2].model_copy(update={"data": bytes(201)})  # 1001 bytes of a 1000-byte patch
    assert reassembler.add(overfill) is None
    assert reassembler.dropped == {"mismatch": 1} and reassembler.pending_bytes == 201  # restarted with it
    assert reassembler.add(honest[0]) is None and reassembler.pending_bytes == 601
    assert reassembler.add(honest[1]) is None  # 1001 again: restarted with this one
    assert reassembler.dropped == {"mismatch": 2} and reassembler.pending_bytes == 400
    assert reassembler.add(honest[0]) is None and reassembler.pending_bytes == 800
    assert reassembler.add(honest[2]) == data  # exactly total_bytes: accepted
    assert reassembler.pending_bytes == 0

    hostile = Reassembler(1 << 20, 5.0, 1 << 20)
    for index in range(MAX_CHUNKS - 1):
        chunk = PatchChunk(
            sender=1,
            producer=1,
            epoch=0,
            seq=0,
            index=index,
            count=MAX_CHUNKS,
            total_bytes=8192,
            crc32=0,
            data=bytes(8192),
        )
        hostile.add(chunk)
        assert hostile.pending_bytes <= 8192


# --- the fuzzing entry point --------------------------------------------------------------------------------


@pytest.mark.bus
def test_fuzz_main_runs_2000_iterations() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "swarm.fuzz", "--iterations", "2000", "--seed", "7"],
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert lines[0] == "iterations: 2000 (seed 7)"
    assert re.fullmatch(r"throughput: \d+ inputs/s \(2000 in [0-9.]+ s\)", lines[-3]), lines[-3]
    assert re.fullmatch(r"slowest: [0-9.]+ ms of CPU a decode in \w+ \(limit 5 ms\)", lines[-2]), lines[-2]
    assert lines[-1].startswith("slowest input: "), lines[-1]
    counts = {line.split()[0]: (int(line.split()[1]), int(line.split()[2])) for line in lines[2:-3]}
    assert list(counts) == [d.name for d in fuzz.DECODERS]
    assert sum(a + r for a, r in counts.values()) == 2000
    assert all(accepted > 0 and rejected > 0 for accepted, rejected in counts.values()), counts


def test_fuzz_main_stops_on_an_unexpected_exception(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    def crash(data: bytes) -> bool:
        raise KeyError("boom")

    broken = tuple(fuzz.Decoder(d.name, crash if d.name == "request" else d.run, d.seed) for d in fuzz.DECODERS)
    monkeypatch.setattr(fuzz, "DECODERS", broken)
    assert fuzz.main(["--iterations", "500", "--seed", "3"]) == 1
    err = capsys.readouterr().err
    assert "KeyError: 'boom'" in err and "unexpected exception in request" in err
    hex_input = err.strip().rsplit("input: ", 1)[1]
    assert fuzz.route(bytes.fromhex(hex_input))[0].name == "request"


def burn(seconds: float) -> None:
    end = time.thread_time() + seconds
    while time.thread_time() < end:
        pass


def slow_decoders(slow: Callable[[bytes], bool]) -> tuple[fuzz.Decoder, ...]:
    return tuple(fuzz.Decoder(d.name, slow if d.name == "request" else d.run, d.seed) for d in fuzz.DECODERS)


def test_an_input_over_the_time_limit_is_a_failure_naming_it(monkeypatch: pytest.MonkeyPatch) -> None:
    def slow(data: bytes) -> bool:
        burn(0.008)
        return False

    monkeypatch.setattr(fuzz, "DECODERS", slow_decoders(slow))
    index = [d.name for d in fuzz.DECODERS].index("request")
    with pytest.raises(
        fuzz.FuzzFailure, match=rf"request took [0-9.]+ ms of CPU a decode, over 5 ms, on input {index:02x}ab"
    ):
        fuzz.run_one(bytes([index, 0xAB]))
    assert fuzz.run_one(bytes([index, 0xAB]), time_limit_s=None) == ("request", False)
    with pytest.raises(fuzz.FuzzFailure):
        fuzz.fuzz_one(bytes([index, 0xAB]))


def test_an_input_slow_only_once_is_measured_again_and_passes(monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[int] = []

    def slow_once(data: bytes) -> bool:
        calls.append(1)
        burn(0.008 if len(calls) == 1 else 0.0)
        return False

    monkeypatch.setattr(fuzz, "DECODERS", slow_decoders(slow_once))
    index = [d.name for d in fuzz.DECODERS].index("request")
    assert fuzz.run_one(bytes([index, 0xAB])) == ("request", False) and len(calls) == 2


def test_the_reassembly_route_has_the_limit_per_chunk() -> None:
    reassembly = next(d for d in fuzz.DECODERS if d.name == "reassembly")
    assert reassembly.decodes(bytes(300)) == 100 and reassembly.decodes(b"") == 1
    assert all(d.decodes(bytes(300)) == 1 for d in fuzz.DECODERS if d is not reassembly)


def test_fuzz_main_stops_on_a_slow_input(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    def slow(data: bytes) -> bool:
        burn(0.003)
        return False

    monkeypatch.setattr(fuzz, "DECODERS", slow_decoders(slow))
    assert fuzz.main(["--iterations", "200", "--seed", "3", "--time-limit-ms", "1"]) == 1
    err = capsys.readouterr().err
    assert "FuzzFailure: request took" in err and "over 1 ms" in err


def test_every_seed_is_accepted() -> None:
    for index, decoder in enumerate(fuzz.DECODERS):
        assert fuzz.run_one(bytes([index]) + decoder.seed()) == (decoder.name, True)
        assert fuzz.run_one(bytes([index + len(fuzz.DECODERS)]) + b"\xc1") == (decoder.name, False)


def test_fuzz_one_swallows_only_documented_errors(monkeypatch: pytest.MonkeyPatch) -> None:
    seed = bytes([0]) + SEEDS[fuzz.DECODERS[0].name]()

    def raising(error: Exception) -> Callable[..., Any]:
        def decode_stub(*args: Any) -> Any:
            raise error

        return decode_stub

    monkeypatch.setattr(fuzz, "decode", raising(DecodeError("invalid")))
    assert fuzz.fuzz_one(seed) is None
    monkeypatch.setattr(fuzz, "decode", raising(TypeError("not documented")))
    with pytest.raises(TypeError):
        fuzz.fuzz_one(seed)


@settings(max_examples=500, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.binary(max_size=1500))
def test_fuzz_one_on_arbitrary_bytes(data: bytes) -> None:
    assert fuzz.fuzz_one(data) is None


@FUZZ
@given(data=st.data())
def test_fuzz_one_on_mutated_seeds(data: st.DataObject) -> None:
    index = data.draw(st.integers(0, len(fuzz.DECODERS) - 1))
    body = data.draw(mutated_bytes(fuzz.DECODERS[index].seed()))
    name, accepted = fuzz.run_one(bytes([index]) + body)
    assert name == fuzz.DECODERS[index].name and isinstance(accepted, bool)


def test_the_signed_patch_route_takes_only_patches_its_producer_signed() -> None:
    index = [d.name for d in fuzz.DECODERS].index("signed_patch")
    assert fuzz.timed_run(bytes([index]) + SEEDS["signed_patch"]())[1]
    assert not fuzz.timed_run(bytes([index]) + SEEDS["patch"]())[1]  # unsigned
