"""`check_structure`, the codec's walk over msgpack headers before anything is unpacked (issue 25): a message
nested too deep or declaring more items than the bounds (or than its own bytes) is refused before msgpack
allocates for it, and every document within the bounds passes exactly when msgpack can read it."""

from __future__ import annotations

import time
from typing import Any

import msgpack
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from swarm import fuzz
from swarm.bus import codec
from swarm.bus.codec import MAX_CONTAINER_LEN, MAX_DEPTH, MAX_ITEMS, DecodeError, check_structure, decode, encode
from swarm.bus.holdings import DigestWire
from swarm.bus.messages import AgentState

NESTED_3KB = (b"\xdc" + MAX_CONTAINER_LEN.to_bytes(2, "big")) * 1000  # the review's heartbeat: 70-80 ms before


def refusal(data: bytes, **bounds: int) -> str | None:
    try:
        check_structure(data, **bounds)
    except DecodeError as exc:
        assert exc.reason == "not_msgpack"
        return exc.detail
    return None


def nested(depth: int) -> bytes:
    value: Any = 0
    for _ in range(depth):
        value = [value]
    return msgpack.packb(value)


def items_of(obj: Any) -> int:
    if isinstance(obj, list):
        return len(obj) + sum(items_of(x) for x in obj)
    if isinstance(obj, dict):
        return 2 * len(obj) + sum(items_of(k) + items_of(v) for k, v in obj.items())
    return 0


def depth_of(obj: Any) -> int:
    if isinstance(obj, list) and obj:
        return 1 + max(depth_of(x) for x in obj)
    if isinstance(obj, dict) and obj:
        return 1 + max(max(depth_of(k), depth_of(v)) for k, v in obj.items())
    return 0


def max_heartbeat() -> bytes:
    """A heartbeat whose holdings are at every bound: 64 producers x 16 epochs, 4096 ranges."""
    entries = [
        {"producer": p, "epoch": e, "ranges": [[10 * i, 10 * i + 5] for i in range(4)]}
        for p in range(1, 65)
        for e in range(16)
    ]
    base = msgpack.unpackb(fuzz._seed_state(), raw=False)["d"]
    return encode(AgentState.model_validate({**base, "holdings": DigestWire.model_validate({"entries": entries})}))


def test_the_nested_3kb_heartbeat_is_refused_before_msgpack_sees_it(monkeypatch: pytest.MonkeyPatch) -> None:
    def unpack_not_allowed(*args: Any) -> Any:
        raise AssertionError("msgpack ran on a message the structure check should have refused")

    monkeypatch.setattr(codec, "_unpack", unpack_not_allowed)
    with pytest.raises(DecodeError) as info:
        decode(NESTED_3KB, AgentState)
    assert info.value.reason == "not_msgpack"
    assert "items declared" in info.value.detail


def test_the_nested_3kb_heartbeat_costs_well_under_a_millisecond_of_cpu() -> None:
    start = time.thread_time()
    for _ in range(100):
        with pytest.raises(DecodeError):
            decode(NESTED_3KB, AgentState)
    per_decode = (time.thread_time() - start) / 100
    assert per_decode < 1e-3, f"{per_decode * 1e3:.2f} ms a decode (70-80 ms before the structure check)"


def test_the_largest_legitimate_heartbeat_passes_and_is_within_the_bounds() -> None:
    data = max_heartbeat()
    obj = msgpack.unpackb(data, raw=False)
    assert items_of(obj) <= MAX_ITEMS and depth_of(obj) <= MAX_DEPTH
    assert refusal(data) is None
    assert decode(data, AgentState).holdings.entries[-1].producer == 64


def test_depth_at_the_bound_passes_and_one_more_is_refused() -> None:
    assert refusal(nested(MAX_DEPTH)) is None
    assert "nested more than 16 deep" in (refusal(nested(MAX_DEPTH + 1)) or "")
    assert refusal(nested(3), max_depth=3) is None and refusal(nested(4), max_depth=3) is not None


def test_items_at_the_bound_pass_and_one_more_is_refused() -> None:
    at = msgpack.packb([[0] * 9, {"a": 0}])  # 2 + 9 + 2 items
    assert items_of(msgpack.unpackb(at)) == 13
    assert refusal(at, max_items=13) is None
    assert "more than 12 items declared" in (refusal(at, max_items=12) or "")


def test_a_document_declaring_more_items_than_it_has_bytes_is_refused() -> None:
    assert refusal(b"\x92\x01\x02") is None
    assert "more than 4 items" in (refusal(b"\xdc\x00\x05" + b"\x01") or "")  # 5 items claimed, 4 bytes in all


@pytest.mark.parametrize(
    "data",
    [
        b"",
        b"\x92\x01",  # an array missing an item
        b"\xa5abc",  # a string cut short
        b"\xc4\x10" + bytes(4),  # bin cut short
        b"\xcb\x00\x00",  # a float64 cut short
        b"\xdd\x00\x00",  # a length field cut short
    ],
)
def test_truncated_documents_are_refused(data: bytes) -> None:
    assert refusal(data) == "truncated"


@pytest.mark.parametrize("first", [0xC1, 0xC7, 0xC8, 0xC9, 0xD4, 0xD5, 0xD6, 0xD7, 0xD8])
def test_the_never_used_byte_and_every_extension_type_are_refused(first: int) -> None:
    assert "starts no allowed msgpack value" in (refusal(bytes([first]) + bytes(20)) or "")


def test_bytes_after_the_document_are_refused() -> None:
    assert refusal(b"\x01\x02") == "1 bytes after the message"


@pytest.mark.parametrize(
    "obj",
    [
        None,
        True,
        -1,
        -33,
        2**63,
        -(2**63),
        1.5,
        "",
        "x" * 31,
        "x" * 32,
        "y" * 70000,
        b"",
        b"z" * 300,
        b"z" * 70000,
        [],
        {},
        [[], {}],
        {"a": [1, {"b": None}]},
        list(range(20)),
        {str(i): i for i in range(20)},
    ],
    ids=repr,
)
def test_every_msgpack_type_and_length_form_passes(obj: Any) -> None:
    data = msgpack.packb(obj, use_bin_type=True)
    assert refusal(data) is None
    assert refusal(msgpack.packb(obj, use_bin_type=True, use_single_float=True)) is None


values = st.recursive(
    st.none() | st.booleans() | st.integers(-(2**63), 2**64 - 1) | st.floats() | st.text(max_size=40) | st.binary(),
    lambda inner: st.lists(inner, max_size=20) | st.dictionaries(st.text(max_size=8), inner, max_size=6),
    max_leaves=60,
)
SETTINGS = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@SETTINGS
@given(values)
def test_any_document_within_the_bounds_passes(obj: Any) -> None:
    data = msgpack.packb(obj, use_bin_type=True)
    within = depth_of(obj) <= 8 and items_of(obj) <= 200
    assert within and refusal(data, max_depth=8, max_items=200) is None or not within


@SETTINGS
@given(st.binary(max_size=200), st.integers(1, 6))
def test_whatever_msgpack_reads_within_the_bounds_passes_and_nothing_else_does(data: bytes, depth: int) -> None:
    obj: Any = None
    try:  # raw: the structure check leaves UTF-8 and map keys to msgpack
        obj = msgpack.unpackb(data, raw=True, strict_map_key=False, ext_hook=lambda code, raw: None)
        read = True
    except Exception:
        read = False
    refused = refusal(data, max_depth=depth)
    if read and depth_of(obj) <= depth and refused is not None:
        # only an extension type msgpack read (the codec refuses them) may be refused
        assert "starts no allowed msgpack value" in refused, (data.hex(), refused)
    if refused is None:
        assert read, f"{data.hex()} passed the structure check but msgpack cannot read it"
