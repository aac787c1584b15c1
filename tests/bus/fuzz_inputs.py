"""Hypothesis strategies for the decoder fuzz tests: valid messages of every network model, hostile values,
structure-aware mutations of decoded fields, and byte-level mutations of wire bytes."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from swarm.bus.holdings import DigestWire
from swarm.bus.keys import MAX_AGENT_ID, MIN_AGENT_ID
from swarm.bus.messages import AgentState
from swarm.bus.phase import Phase
from swarm.patches.digest import DigestMessage, PatchDigest
from swarm.patches.lattice import Lattice
from swarm.patches.patch import FrameSpan, Patch, PatchId, VoxelBlocks
from swarm.roles.messages import MAX_MEMBERS, FrontierReport, TargetAssignment
from swarm.sync.chunks import MAX_CHUNKS, PatchChunk

MAX_COUNTER = 2**63 - 1
MIN_INT, MAX_INT = -(2**63), 2**64 - 1  # what msgpack can carry
LATTICES = (Lattice(0.2, 4, 4.0), Lattice(0.2, 4, 4.0, weight_law="inverse_square"))

BOUNDARY_INTS = (
    0,
    1,
    -1,
    2,
    MAX_AGENT_ID,
    MAX_AGENT_ID + 1,
    4095,
    4096,
    4097,
    16384,
    16385,
    1 << 30,
    (1 << 30) + 1,
    2**32 - 1,
    2**32,
    MAX_COUNTER,
    MAX_COUNTER + 1,
    MAX_INT,
    MIN_INT,
)
SPECIAL_FLOATS = (math.nan, math.inf, -math.inf, -0.0, 1e308, -1e308, 5e-324, 4000.0, 360.0, -360.0)
HOSTILE_HEADERS = (
    b"\xdd\xff\xff\xff\xff",  # array32 claiming 4 G items
    b"\xdf\xff\xff\xff\xff",  # map32 claiming 4 G entries
    b"\xc6\x7f\xff\xff\xff",  # bin32 claiming 2 GB
    b"\xdb\xff\xff\xff\xff",  # str32 claiming 4 GB
    b"\xc9\xff\xff\xff\xff\x05",  # ext32 claiming 4 GB
    b"\xd6\xff\x00\x00\x00\x00",  # timestamp extension
    b"\xc1",  # never used
)

agent_ids = st.integers(MIN_AGENT_ID, MAX_AGENT_ID)
counters = st.integers(0, MAX_COUNTER) | st.sampled_from([0, 1, MAX_COUNTER])
finite = st.floats(allow_nan=False, allow_infinity=False)
vec3 = st.tuples(finite, finite, finite)
short_text = st.text(st.characters(min_codepoint=0x20, max_codepoint=0x7E), max_size=32)

scalars = (
    st.none()
    | st.booleans()
    | st.integers(MIN_INT, MAX_INT)
    | st.sampled_from(BOUNDARY_INTS)
    | st.floats()
    | st.sampled_from(SPECIAL_FLOATS)
    | st.text(max_size=40)
    | st.binary(max_size=80)
)
structures = st.recursive(
    scalars,
    lambda children: st.lists(children, max_size=5) | st.dictionaries(st.text(max_size=8), children, max_size=5),
    max_leaves=12,
)


# --- valid messages ------------------------------------------------------------------------------------------

patch_ids = st.builds(PatchId, agent_ids, st.sampled_from([0, 1, 1_795_340_000_000, MAX_COUNTER]), counters)
digest_wires: st.SearchStrategy[DigestWire] = st.lists(patch_ids, max_size=30).map(
    lambda ids: PatchDigest.of(ids).to_wire_model()
)

agent_states = st.builds(
    AgentState,
    id=agent_ids,
    epoch=counters,
    seq=counters,
    t=st.floats(0.0, 1e12),
    position=vec3,
    velocity=vec3,
    heading_to=st.none() | vec3,
    yaw_deg=st.floats(-360.0, 360.0),
    flight_mode=short_text,
    phase=st.sampled_from(Phase),
    role=st.sampled_from(["leader", "explorer"]),
    leader=agent_ids,
    finished=st.booleans(),
    holdings=digest_wires,
)
digest_messages = st.builds(DigestMessage, id=agent_ids, epoch=counters, digest=digest_wires)


@st.composite
def patch_chunks(draw: st.DrawFn, max_data: int = 512) -> PatchChunk:
    count = draw(st.integers(1, MAX_CHUNKS))
    data = draw(st.binary(min_size=1, max_size=max_data))
    return PatchChunk(
        sender=draw(agent_ids),
        producer=draw(agent_ids),
        epoch=draw(counters),
        seq=draw(counters),
        index=draw(st.integers(0, count - 1)),
        count=count,
        total_bytes=draw(st.integers(len(data), 1 << 30)),
        crc32=draw(st.integers(0, 2**32 - 1)),
        data=data,
    )


def points(n: int) -> st.SearchStrategy[np.ndarray]:
    return arrays(np.float32, (n, 3), elements=st.floats(-1e6, 1e6, width=32))


@st.composite
def frontier_reports(draw: st.DrawFn) -> FrontierReport:
    n = draw(st.integers(0, 12))
    return FrontierReport(
        id=draw(agent_ids),
        epoch=draw(counters),
        seq=draw(counters),
        position=draw(vec3),
        viewpoints=draw(points(n)),
        points=draw(points(n)),
        gains=draw(arrays(np.float32, (n,), elements=st.floats(0.0, 1e6, width=32))),
        visited=draw(points(draw(st.integers(0, 12)))),
        arrived=draw(st.booleans()),
    )


@st.composite
def target_assignments(draw: st.DrawFn) -> TargetAssignment:
    members = draw(st.lists(agent_ids, min_size=1, max_size=MAX_MEMBERS))
    drones = draw(st.lists(st.sampled_from(members), unique=True, max_size=len(members)))
    return TargetAssignment(
        leader=draw(st.sampled_from(members)),
        epoch=draw(counters),
        round=draw(counters),
        members=members,
        done=draw(st.booleans()),
        drones=drones,
        viewpoints=draw(points(len(drones))),
        points=draw(points(len(drones))),
    )


def _rotation_z(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@st.composite
def patches(draw: st.DrawFn, lattice: Lattice | None = None) -> Patch:
    """A small sealed patch (1-5 blocks of 64 voxels, each with an observed voxel, as a sealer makes them) on one
    of `LATTICES`."""
    lattice = lattice or draw(st.sampled_from(LATTICES))
    m = draw(st.integers(1, 5))
    keys = draw(st.lists(st.tuples(*[st.integers(-40, 40)] * 3), min_size=m, max_size=m, unique=True))
    n = lattice.voxels_per_block
    weight = draw(arrays(lattice.weight_dtype, (m, n), elements=st.integers(0, 3) | st.just(255)))
    weight[~weight.any(axis=1), draw(st.integers(0, n - 1))] = 1
    tsdf = draw(arrays(np.int8, (m, n), elements=st.integers(-127, 127))) * (weight > 0)
    pose = np.eye(4)
    pose[:3, :3] = _rotation_z(draw(st.floats(-math.pi, math.pi)))
    pose[:3, 3] = draw(st.tuples(*[st.floats(-100.0, 100.0)] * 3))
    first = draw(st.integers(0, 10**6))
    t_first = draw(st.floats(0.0, 2e9))
    span = FrameSpan(first, first + draw(st.integers(0, 100)), t_first, t_first + draw(st.floats(0.0, 60.0)))
    blocks = VoxelBlocks(np.array(keys, dtype=np.int32).reshape(m, 3), tsdf.astype(np.int8), weight)
    return Patch.seal(draw(patch_ids), lattice, span, pose, blocks)


# --- mutations -----------------------------------------------------------------------------------------------


def _clamp(value: int) -> int:
    return min(max(value, MIN_INT), MAX_INT)


@st.composite
def nudged(draw: st.DrawFn, value: Any, depth: int = 0) -> Any:
    """`value` changed a little, keeping most of its structure: near-miss ints and floats, other types, one
    element of a list or map changed, dropped or added (recursively)."""
    if depth > 6 or value is None or isinstance(value, bool):
        return draw(structures)
    if isinstance(value, int):
        near = [_clamp(value - 1), _clamp(value + 1), _clamp(-value), float(value), str(value), True]
        return draw(st.sampled_from(near) | st.sampled_from(BOUNDARY_INTS) | structures)
    if isinstance(value, float):
        near = [value * 2, -value, int(value) if math.isfinite(value) else 0, str(value)]
        return draw(st.sampled_from(near) | st.sampled_from(SPECIAL_FLOATS) | st.floats())
    if isinstance(value, str):
        return draw(st.sampled_from([value[:-1], value + "x", value * 40, value + "\n", "é" + value]) | st.text())
    if isinstance(value, bytes):
        return draw(st.sampled_from([value[:-1], value + b"\x00", value[: len(value) // 2]]) | st.binary())
    if isinstance(value, (list, tuple)):
        return draw(_nudged_list(list(value), depth))
    if isinstance(value, dict):
        return draw(_nudged_dict(dict(value), depth))
    return draw(structures)


@st.composite
def _nudged_list(draw: st.DrawFn, items: list[Any], depth: int) -> list[Any]:
    op = draw(st.sampled_from(["change", "change", "drop", "append", "duplicate"]))
    if not items or op == "append":
        return [*items, draw(structures)]
    at = draw(st.integers(0, len(items) - 1))
    if op == "change":
        items[at] = draw(nudged(items[at], depth + 1))
    elif op == "drop":
        del items[at]
    else:
        items.insert(at, items[at])
    return items


@st.composite
def _nudged_dict(draw: st.DrawFn, fields: dict[str, Any], depth: int) -> dict[str, Any]:
    op = draw(st.sampled_from(["change", "change", "change", "drop", "add"]))
    if not fields or op == "add":
        fields[draw(st.text(max_size=8))] = draw(structures)
        return fields
    name = draw(st.sampled_from(sorted(fields)))
    if op == "change":
        fields[name] = draw(nudged(fields[name], depth + 1))
    else:
        del fields[name]
    return fields


@st.composite
def mutated(draw: st.DrawFn, value: Any, max_rounds: int = 3) -> Any:
    """`value` nudged 1 to `max_rounds` times."""
    for _ in range(draw(st.integers(1, max_rounds))):
        value = draw(nudged(value))
    return value


@st.composite
def mutated_bytes(draw: st.DrawFn, data: bytes) -> bytes:
    """`data` with 1-4 bit flips, byte changes, insertions (random or hostile msgpack headers), deletions or a
    truncation."""
    out = bytearray(data)
    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.sampled_from(["flip", "set", "insert", "header", "delete", "truncate"]))
        at = draw(st.integers(0, len(out)))
        if op == "flip" and at < len(out):
            out[at] ^= 1 << draw(st.integers(0, 7))
        elif op == "set" and at < len(out):
            out[at] = draw(st.integers(0, 255))
        elif op == "insert":
            out[at:at] = draw(st.binary(min_size=1, max_size=8))
        elif op == "header":
            out[at:at] = draw(st.sampled_from(HOSTILE_HEADERS))
        elif op == "delete":
            del out[at : at + draw(st.integers(1, 8))]
        else:
            del out[at:]
    return bytes(out)
