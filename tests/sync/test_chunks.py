"""Chunking and reassembly of patch bytes, and the pull request selector."""

from __future__ import annotations

import random

import msgpack
import pytest

from swarm.bus.codec import DecodeError, decode, encode
from swarm.patches.patch import PatchId
from swarm.sync.chunks import PatchChunk, Reassembler, split_patch
from swarm.sync.requests import MAX_IDS_PER_REQUEST, parse_request, request_parameters

PID = PatchId(2, 17, 5)


class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def _data(n: int, seed: int = 0) -> bytes:
    return random.Random(seed).randbytes(n)


def test_split_then_reassemble_in_any_order_gives_the_bytes_back() -> None:
    data = _data(10_000)
    chunks = split_patch(3, PID, data, 1024)
    assert len(chunks) == 10 and all(len(c.data) <= 1024 for c in chunks)
    assert {c.sender for c in chunks} == {3} and chunks[0].patch_id == PID
    random.Random(1).shuffle(chunks)
    r = Reassembler(1 << 20, 10.0, 1 << 20)
    results = [r.add(decode(encode(c), PatchChunk)) for c in chunks]
    assert results[:-1] == [None] * 9 and results[-1] == data
    assert len(r) == 0 and r.pending_bytes == 0


def test_chunks_from_two_senders_of_the_same_bytes_complete_one_patch() -> None:
    data = _data(5000)
    r = Reassembler(1 << 20, 10.0, 1 << 20)
    first, second = split_patch(1, PID, data, 1000), split_patch(4, PID, data, 1000)
    for chunk in first[:3]:
        assert r.add(chunk) is None
    assert r.add(first[1]) is None  # a duplicate changes nothing
    assert r.partial(PID) == (3, 5)
    assert r.add(second[3]) is None
    assert r.add(second[4]) == data


def test_a_contradicting_chunk_restarts_the_assembly() -> None:
    r = Reassembler(1 << 20, 10.0, 1 << 20)
    r.add(split_patch(1, PID, _data(3000, 1), 1000)[0])
    other = split_patch(1, PID, _data(3000, 2), 1000)
    for chunk in other:
        result = r.add(chunk)
    assert result == _data(3000, 2)
    assert r.dropped == {"mismatch": 1}


def test_corrupt_bytes_with_a_wrong_crc_are_dropped() -> None:
    data = _data(2000)
    chunks = split_patch(1, PID, data, 1000)
    bad = chunks[1].model_copy(update={"data": b"\x00" * 1000})
    r = Reassembler(1 << 20, 10.0, 1 << 20)
    assert r.add(chunks[0]) is None and r.add(bad) is None
    assert r.dropped == {"corrupt": 1} and len(r) == 0


def test_assemblies_are_bounded_in_bytes_and_time() -> None:
    clock = Clock()
    r = Reassembler(2500, 5.0, 1 << 20, clock=clock)
    for seq in range(3):
        clock.now += 1
        r.add(split_patch(1, PatchId(1, 1, seq), _data(3000, seq), 1000)[0])
    assert r.pending_bytes <= 2500 and r.dropped.get("overflow") == 1
    clock.now += 10
    r.expire()
    assert len(r) == 0 and r.dropped.get("expired") == 2
    assert (
        r.add(
            PatchChunk(sender=1, producer=1, epoch=1, seq=9, index=0, count=1, total_bytes=1 << 21, crc32=0, data=b"x")
        )
        is None
    )
    assert r.dropped.get("oversize") == 1 and len(r) == 0


@pytest.mark.parametrize(
    "fields",
    [
        {"index": 3, "count": 3},
        {"count": 0},
        {"data": b""},
        {"total_bytes": 2, "data": b"abc"},
        {"sender": 0},
        {"crc32": -1},
    ],
)
def test_invalid_chunks_do_not_decode(fields: dict) -> None:
    good = split_patch(1, PID, b"abc", 1000)[0].model_dump()
    good.update(fields)
    envelope = encode(split_patch(1, PID, b"abc", 1000)[0])
    assert decode(envelope, PatchChunk).data == b"abc"
    with pytest.raises(DecodeError):
        decode(msgpack.packb({"v": 1, "k": "patch_chunk", "d": good}, use_bin_type=True), PatchChunk)


def test_request_parameters_round_trip() -> None:
    ids = [PatchId(1, 2, 3), PatchId(250, 0, 2**63 - 1)]
    text = request_parameters(ids, 7)
    params = dict(p.split("=", 1) for p in text.split(";"))
    assert parse_request(params) == (ids, 7)


@pytest.mark.parametrize(
    "params",
    [
        {},
        {"ids": ""},
        {"ids": "1.2"},
        {"ids": "01.2.3"},
        {"ids": "0.2.3"},
        {"ids": "251.2.3"},
        {"ids": "1.2.-3"},
        {"ids": "1.2.99999999999999999999"},
        {"ids": ",".join(["1.1.1"] * (MAX_IDS_PER_REQUEST + 1))},
        {"ids": "1.1.1", "from": "0"},
        {"ids": "1.1.1", "from": "x"},
    ],
)
def test_malformed_requests_are_refused(params: dict) -> None:
    with pytest.raises(ValueError):
        parse_request(params)


def test_a_flood_of_one_byte_chunks_of_new_patches_is_bounded_in_count_per_sender_and_in_total() -> None:
    clock = Clock()
    r = Reassembler(64 << 20, 30.0, 1 << 20, clock=clock, max_assemblies=300, max_per_sender=100)
    honest = split_patch(2, PatchId(2, 1, 0), _data(3000), 1000)
    assert r.add(honest[0]) is None
    flood = PatchChunk(sender=7, producer=3, epoch=1, seq=0, index=0, count=2, total_bytes=2, crc32=0, data=b"x")
    for seq in range(100_000):  # each the first of two one-byte chunks of a patch that never completes
        clock.now += 1e-6
        r.add(flood.model_copy(update={"seq": seq}))  # (a valid chunk, only its seq differs)
    assert len(r) == 101 and r.per_sender() == {7: 100, 2: 1}
    assert r.dropped == {"sender_limit": 99_900}
    assert r.add(honest[1]) is None and r.add(honest[2]) == _data(3000)  # the honest patch still completes
    for sender in (4, 5, 6, 8):  # many senders: the total holds, the one that started the most gives way
        for seq in range(100):
            r.add(flood.model_copy(update={"sender": sender, "producer": sender, "epoch": 2, "seq": seq}))
    assert len(r) == 300 and r.dropped["count_limit"] == 200
    assert r.per_sender() == {7: 60, 4: 60, 5: 60, 6: 60, 8: 60}
