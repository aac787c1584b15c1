from __future__ import annotations

import math
from typing import Annotated, Any

import msgpack
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from swarm.bus.codec import (
    ALLOWED_DTYPES,
    MAX_CONTAINER_LEN,
    SCHEMA_VERSION,
    ArraySpec,
    DecodeError,
    NDArray,
    WireMessage,
    decode,
    encode,
)
from swarm.bus.messages import AgentState
from swarm.bus.phase import Phase
from tests.bus.fuzz_inputs import structures
from tests.bus.helpers import make_state


class ArrayMessage(WireMessage):
    KIND = "arrays"

    name: str
    values: NDArray
    small: Annotated[np.ndarray, ArraySpec(max_bytes=16, dtypes=frozenset({"uint8"}), ndim=1)]


def pack(obj: Any) -> bytes:
    return msgpack.packb(obj, use_bin_type=True)


def envelope(fields: dict[str, Any], kind: str = "state", version: Any = SCHEMA_VERSION) -> bytes:
    return pack({"v": version, "k": kind, "d": fields})


def state_fields(**changes: Any) -> dict[str, Any]:
    fields = make_state(2, 7).model_dump(mode="python")
    fields.update(changes)
    return fields


def wire_array(dtype: str, shape: list[int], data: bytes) -> dict[str, Any]:
    return {"dtype": dtype, "shape": shape, "data": data}


def array_envelope(values: Any, small: Any = None) -> bytes:
    small = small if small is not None else wire_array("uint8", [2], b"\x01\x02")
    return envelope({"name": "x", "values": values, "small": small}, kind="arrays")


def reason_of(data: Any, model: type[WireMessage] = AgentState, **kwargs: Any) -> str:
    with pytest.raises(DecodeError) as info:
        decode(data, model, **kwargs)
    return info.value.reason


# --- round trips -----------------------------------------------------------------------------------------


def test_agent_state_round_trip() -> None:
    msg = make_state(3, 12, epoch=2)
    data = encode(msg)
    assert decode(data, AgentState) == msg
    assert msgpack.unpackb(data)["v"] == SCHEMA_VERSION
    assert msgpack.unpackb(data)["k"] == "state"
    assert len(data) < 256  # a heartbeat stays small


def test_envelope_from_python_fields() -> None:
    assert decode(envelope(state_fields()), AgentState) == make_state(2, 7)


SHAPES = [(), (0,), (5,), (2, 3), (2, 0, 4), (1, 1, 1, 1), (3, 2, 2)]


@pytest.mark.parametrize("dtype", sorted(ALLOWED_DTYPES))
@pytest.mark.parametrize("shape", SHAPES, ids=str)
def test_ndarray_round_trip(dtype: str, shape: tuple[int, ...]) -> None:
    rng = np.random.default_rng(7)
    if dtype == "bool":
        values = rng.integers(0, 2, size=shape).astype(bool)
    elif dtype.startswith("float"):
        values = rng.normal(size=shape).astype(dtype)
    else:
        info = np.iinfo(dtype)
        values = rng.integers(info.min, info.max, size=shape, dtype=dtype, endpoint=True)
    msg = ArrayMessage(name="a", values=values, small=np.arange(3, dtype=np.uint8))
    out = decode(encode(msg), ArrayMessage)
    assert out == msg
    assert out.values.dtype == np.dtype(dtype)
    assert out.values.shape == shape
    np.testing.assert_array_equal(out.values, values)


def test_ndarray_big_endian_and_non_contiguous_inputs() -> None:
    big_endian = np.arange(6, dtype=">i4").reshape(2, 3)
    transposed = np.arange(6, dtype=np.float64).reshape(2, 3).T
    for values in (big_endian, transposed):
        out = decode(encode(ArrayMessage(name="a", values=values, small=np.zeros(1, np.uint8))), ArrayMessage)
        np.testing.assert_array_equal(out.values, values)
        assert out.values.dtype.isnative


def test_ndarray_wire_layout_is_little_endian_c_order() -> None:
    values = np.array([[1, 2], [3, 4]], dtype=np.uint16)
    wire = msgpack.unpackb(encode(ArrayMessage(name="a", values=values, small=np.zeros(0, np.uint8))))
    assert wire["d"]["values"] == {"dtype": "uint16", "shape": [2, 2], "data": b"\x01\x00\x02\x00\x03\x00\x04\x00"}


def test_messages_are_frozen_and_strict_on_construction() -> None:
    msg = make_state(1, 1)
    with pytest.raises(ValidationError):
        msg.seq = 3  # type: ignore[misc]
    with pytest.raises(ValidationError):
        AgentState(**{**state_fields(), "extra": 1})
    with pytest.raises(ValidationError):
        AgentState(**state_fields(velocity=(0.0, math.inf, 0.0)))
    with pytest.raises(ValidationError):
        ArrayMessage(name="a", values=np.zeros(2, dtype=object), small=np.zeros(1, np.uint8))
    with pytest.raises(ValidationError):
        ArrayMessage(name="a", values=[1, 2], small=np.zeros(1, np.uint8))


def test_kind_must_be_well_formed() -> None:
    with pytest.raises(TypeError):

        class BadKind(WireMessage):
            KIND = "Bad Kind"


@pytest.mark.parametrize("phase", list(Phase))
def test_a_heartbeats_phase_goes_on_the_wire_as_its_plain_string(phase: Phase) -> None:
    state = make_state(2, 7).model_copy(update={"phase": phase})
    fields = state.model_dump(mode="python") | {"phase": phase.value}
    assert type(fields["phase"]) is str
    assert encode(state) == pack({"v": SCHEMA_VERSION, "k": AgentState.KIND, "d": fields})
    assert decode(pack({"v": SCHEMA_VERSION, "k": AgentState.KIND, "d": fields}), AgentState).phase is phase


# --- rejections ------------------------------------------------------------------------------------------


def test_every_truncation_is_not_msgpack() -> None:
    data = encode(make_state(5, 1))
    for end in range(len(data)):
        assert reason_of(data[:end]) == "not_msgpack"


@pytest.mark.parametrize(
    "data",
    [
        b"\xc1",  # never-used msgpack byte
        b'{"v": 1, "k": "state"}',  # JSON
        encode(make_state(1, 1)) + b"\x00",  # trailing bytes
        b"\xdd\xff\xff\xff\xff",  # array header claiming 4 G elements
        b"\xdf\xff\xff\xff\xff",  # map header claiming 4 G entries
        b"\xc6\xff\xff\xff\xffabc",  # bin header claiming 4 GB
        b"\xdb\xff\xff\xff\xffabc",  # str header claiming 4 GB
        b"\x91" * 100_000 + b"\xc0",  # nested 100 000 deep
        pack({"v": 1, "k": "state", "d": msgpack.ExtType(5, b"x")}),
        pack({"v": 1, "k": "state", "d": msgpack.Timestamp(1, 0)}),
        pack({1: 2}),  # non-string map key
        b"\x81\xa1v\xa2\xff\xfe",  # invalid UTF-8
    ],
)
def test_not_msgpack(data: bytes) -> None:
    assert reason_of(data) == "not_msgpack"


@pytest.mark.parametrize("data", [None, "text", 12, [1, 2]])
def test_non_bytes_input(data: Any) -> None:
    assert reason_of(data) == "not_msgpack"


def test_bytes_like_inputs_are_accepted() -> None:
    data = encode(make_state(1, 1))
    assert decode(bytearray(data), AgentState) == make_state(1, 1)
    assert decode(memoryview(data), AgentState) == make_state(1, 1)


@pytest.mark.parametrize(
    "obj",
    [
        [1, 2, 3],
        "state",
        None,
        {"v": 1, "k": "state"},
        {"v": 1, "k": "state", "d": {}, "x": 0},
        {"v": "1", "k": "state", "d": {}},
        {"v": True, "k": "state", "d": {}},
        {"v": 1, "k": 5, "d": {}},
        {"v": 1, "k": "state", "d": [1]},
    ],
)
def test_bad_envelope(obj: Any) -> None:
    assert reason_of(pack(obj)) == "bad_envelope"


@pytest.mark.parametrize("version", [0, 2, -1, 2**64 - 1])
def test_wrong_version(version: int) -> None:
    assert reason_of(envelope(state_fields(), version=version)) == "version"


def test_wrong_kind() -> None:
    assert reason_of(envelope(state_fields(), kind="patch")) == "kind"
    assert reason_of(encode(make_state(1, 1)), ArrayMessage) == "kind"


@pytest.mark.parametrize(
    "fields",
    [
        {**state_fields(), "extra": 1},
        {k: v for k, v in state_fields().items() if k != "leader"},
        state_fields(position=[math.nan, 0.0, 0.0]),
        state_fields(velocity=[0.0, math.inf, 0.0]),
        state_fields(t=-math.inf),
        state_fields(yaw_deg=math.nan),
        state_fields(position=[0.0, 0.0]),
        state_fields(position=[0.0, 0.0, 0.0, 0.0]),
        state_fields(id=0),
        state_fields(id=251),
        state_fields(leader=2**64 - 1),
        state_fields(seq=-1),
        state_fields(role="king"),
        state_fields(flight_mode="x" * 33),
        state_fields(flight_mode="x" * 100_000),
        state_fields(phase="cruising"),
        state_fields(phase="Flying"),
        state_fields(phase=""),
        state_fields(phase=3),
        state_fields(flight_mode="caf\u00e9"),
        state_fields(flight_mode=b"\xff\xfe"),
        state_fields(position="abc"),
    ],
)
def test_invalid_fields(fields: dict[str, Any]) -> None:
    assert reason_of(envelope(fields)) == "invalid"


def test_too_large() -> None:
    data = encode(make_state(1, 1))
    assert reason_of(data, max_bytes=len(data) - 1) == "too_large"
    assert decode(data, AgentState, max_bytes=len(data)) == make_state(1, 1)
    assert reason_of(b"\x00" * ((1 << 20) + 1)) == "too_large"


def test_oversized_array_is_rejected() -> None:
    small = ArrayMessage(name="a", values=np.zeros(1), small=np.zeros(16, np.uint8))
    assert decode(encode(small), ArrayMessage) == small
    with pytest.raises(ValidationError):
        ArrayMessage(name="a", values=np.zeros(1), small=np.zeros(17, np.uint8))
    too_big = array_envelope(wire_array("float64", [1], bytes(8)), small=wire_array("uint8", [17], bytes(17)))
    assert reason_of(too_big, ArrayMessage) == "invalid"


@pytest.mark.parametrize(
    "values",
    [
        wire_array("float32", [2, 3], bytes(23)),  # byte length does not match the shape
        wire_array("float32", [2, 3], bytes(25)),
        wire_array("int8", [], b""),  # a 0-d array holds one element
        wire_array("object", [1], bytes(8)),
        wire_array("float16", [1], bytes(2)),
        wire_array("<f4", [1], bytes(4)),
        wire_array("complex64", [1], bytes(8)),
        wire_array("float32", [-1], b""),
        wire_array("float32", [True], bytes(4)),
        wire_array("float32", [1.0], bytes(4)),
        wire_array("float32", "1", bytes(4)),
        wire_array("uint8", [1] * 33, b"\x00"),
        wire_array("uint8", [2**62, 2**62], b""),
        wire_array("uint8", [1], "a"),
        wire_array("bool", [2], b"\x01\x02"),
        {"dtype": "uint8", "shape": [1]},
        {"dtype": "uint8", "shape": [1], "data": b"\x00", "extra": 0},
        [1, 2, 3],
    ],
)
def test_invalid_arrays(values: Any) -> None:
    assert reason_of(array_envelope(values), ArrayMessage) == "invalid"


def test_array_ndim_is_enforced() -> None:
    two_d = array_envelope(wire_array("float32", [1], bytes(4)), small=wire_array("uint8", [1, 1], b"\x00"))
    assert reason_of(two_d, ArrayMessage) == "invalid"


# --- properties ------------------------------------------------------------------------------------------

state_like = st.dictionaries(st.sampled_from([*AgentState.model_fields, "extra"]), structures, max_size=12)
array_like = st.fixed_dictionaries(
    {
        "dtype": st.sampled_from([*ALLOWED_DTYPES, "object", "float16", "<U4", "V8", ""]),
        "shape": st.lists(st.integers(min_value=-2, max_value=6), max_size=4) | structures,
        "data": st.binary(max_size=64) | structures,
    }
)
envelopes = st.fixed_dictionaries(
    {
        "v": st.sampled_from([SCHEMA_VERSION, 0, 2]) | structures,
        "k": st.sampled_from(["state", "arrays", "patch"]) | structures,
        "d": state_like
        | st.fixed_dictionaries({"name": structures, "values": array_like, "small": array_like})
        | structures,
    }
)
FUZZ = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def decodes_or_rejects(data: Any) -> None:
    for model in (AgentState, ArrayMessage):
        try:
            msg = decode(data, model)
        except DecodeError as exc:
            assert exc.reason in {"too_large", "not_msgpack", "bad_envelope", "version", "kind", "invalid"}
        else:
            assert isinstance(msg, model)


@FUZZ
@given(st.binary(max_size=300))
@pytest.mark.fuzz
def test_random_bytes_only_raise_decode_error(data: bytes) -> None:
    decodes_or_rejects(data)


@FUZZ
@given(structures)
@pytest.mark.fuzz
def test_random_msgpack_only_raises_decode_error(obj: Any) -> None:
    decodes_or_rejects(pack(obj))


@FUZZ
@given(envelopes)
@pytest.mark.fuzz
def test_random_envelopes_only_raise_decode_error(obj: Any) -> None:
    decodes_or_rejects(pack(obj))


@FUZZ
@given(st.data())
def test_corrupted_messages_only_raise_decode_error(data: st.DataObject) -> None:
    wire = bytearray(encode(make_state(data.draw(st.integers(1, 250)), data.draw(st.integers(0, 2**40)))))
    for _ in range(data.draw(st.integers(1, 4))):
        wire[data.draw(st.integers(0, len(wire) - 1))] = data.draw(st.integers(0, 255))
    decodes_or_rejects(bytes(wire))


def test_nested_length_claims_stay_bounded() -> None:
    """Each nested array header claims the most elements allowed, and none of them arrive."""
    hostile = (b"\xdd" + MAX_CONTAINER_LEN.to_bytes(4, "big")) * 2000
    assert reason_of(hostile) == "not_msgpack"
    assert reason_of(b"\xdd" + (MAX_CONTAINER_LEN + 1).to_bytes(4, "big") + b"\xc0" * 10) == "not_msgpack"
