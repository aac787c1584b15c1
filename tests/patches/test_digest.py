"""PatchDigest: ranges of held patch ids, set operations, and the (hostile) wire form."""

from __future__ import annotations

from collections import Counter

import msgpack
import pytest
from hypothesis import given
from hypothesis import strategies as st

from swarm.bus.codec import DecodeError, decode, encode
from swarm.patches.digest import (
    MAX_ENTRIES,
    MAX_EPOCHS_PER_PRODUCER,
    MAX_PRODUCERS,
    MAX_RANGES,
    DigestMessage,
    PatchDigest,
    fair_order,
)
from swarm.patches.patch import PatchId


def ids(producer: int, epoch: int, *seqs: int) -> list[PatchId]:
    return [PatchId(producer, epoch, s) for s in seqs]


def test_consecutive_seqs_compress_into_ranges() -> None:
    digest = PatchDigest.of(ids(3, 7, 5, 0, 1, 2, 2, 9, 8) + ids(1, 0, 4))
    assert digest.ranges == {(1, 0): ((4, 4),), (3, 7): ((0, 2), (5, 5), (8, 9))}
    assert digest.count == len(digest) == 7
    assert digest.range_count == 4
    assert PatchId(3, 7, 1) in digest and PatchId(3, 7, 3) not in digest and PatchId(2, 7, 1) not in digest
    assert list(digest.ids()) == sorted(set(ids(3, 7, 5, 0, 1, 2, 9, 8) + ids(1, 0, 4)))
    assert PatchDigest.of([]).count == 0 and not PatchDigest.of([])


def test_constructor_merges_overlapping_and_adjacent_ranges() -> None:
    assert PatchDigest({(2, 1): [(5, 9), (0, 3), (4, 4), (8, 12)]}).ranges == {(2, 1): ((0, 12),)}
    with pytest.raises(ValueError):
        PatchDigest({(2, 1): [(5, 4)]})
    with pytest.raises(ValueError):
        PatchDigest({(2, 1): [(-1, 4)]})


def test_missing_from_digest_and_set() -> None:
    peer = PatchDigest({(3, 1): [(0, 9)], (4, 0): [(0, 1)]})
    mine = PatchDigest({(3, 1): [(2, 3), (5, 5), (9, 20)]})
    expected = ids(3, 1, 0, 1, 4, 6, 7, 8) + ids(4, 0, 0, 1)
    assert peer.missing_from(mine) == expected
    assert peer.missing_from(set(mine.ids())) == expected
    assert peer.missing_from(mine, limit=3) == expected[:3]
    assert peer.missing_from(peer) == []
    assert PatchDigest.of([]).missing_from(mine) == []


def test_missing_from_a_huge_range_is_bounded_by_limit() -> None:
    hostile = PatchDigest({(5, 0): [(0, 2**62)]})
    assert hostile.missing_from(PatchDigest.of(ids(5, 0, 0, 2)), limit=3) == ids(5, 0, 1, 3, 4)
    assert hostile.count == 2**62 + 1


def test_union() -> None:
    a = PatchDigest.of(ids(1, 0, 0, 1, 5))
    b = PatchDigest.of(ids(1, 0, 2, 3) + ids(2, 4, 7))
    u = a.union(b)
    assert u.ranges == {(1, 0): ((0, 3), (5, 5)), (2, 4): ((7, 7),)}
    assert u == b | a == a.union(list(b.ids()))
    assert hash(u) == hash(b.union(a))


def test_wire_round_trip_through_the_codec() -> None:
    digest = PatchDigest.of(ids(3, 1795340000000, 0, 1, 2, 40) + ids(250, 0, 7) + ids(1, 5, 0))
    assert PatchDigest.from_wire(digest.to_wire()) == digest
    msg = DigestMessage.of(4, 12, digest)
    data = encode(msg)
    back = decode(data, DigestMessage)
    assert back == msg
    assert back.patch_digest() == digest
    assert list(back.patch_digest().ids()) == list(digest.ids())
    empty = DigestMessage.of(4, 0, PatchDigest.of([]))
    assert decode(encode(empty), DigestMessage).patch_digest() == PatchDigest.of([])


def test_digest_of_many_ranges_fits_the_codec() -> None:
    digest = PatchDigest.of(PatchId(p, e, s) for p in range(1, 17) for e in range(16) for s in range(0, 32, 2))
    assert digest.range_count == MAX_RANGES
    msg = DigestMessage.of(1, 0, digest)
    assert decode(encode(msg), DigestMessage).patch_digest() == digest


def entry(producer: int = 3, epoch: int = 1, ranges: object = None) -> dict:
    return {"producer": producer, "epoch": epoch, "ranges": [[0, 4]] if ranges is None else ranges}


HOSTILE = {
    "not a dict": [entry()],
    "no entries": {},
    "extra key": {"entries": [], "x": 1},
    "entry extra key": {"entries": [{**entry(), "x": 1}]},
    "unsorted ranges": {"entries": [entry(ranges=[[5, 6], [0, 2]])]},
    "overlapping ranges": {"entries": [entry(ranges=[[0, 5], [3, 8]])]},
    "adjacent ranges": {"entries": [entry(ranges=[[0, 5], [6, 8]])]},
    "empty range": {"entries": [entry(ranges=[[5, 4]])]},
    "no ranges": {"entries": [entry(ranges=[])]},
    "range of three": {"entries": [entry(ranges=[[0, 1, 2]])]},
    "negative seq": {"entries": [entry(ranges=[[-1, 4]])]},
    "huge seq": {"entries": [entry(ranges=[[0, 2**64 - 1]])]},
    "huge epoch 2": {"entries": [entry(epoch=2**64 - 1)]},
    "float seq": {"entries": [entry(ranges=[[0.0, 4]])]},
    "bool seq": {"entries": [entry(ranges=[[True, 4]])]},
    "string seq": {"entries": [entry(ranges=[["0", 4]])]},
    "negative epoch": {"entries": [entry(epoch=-1)]},
    "huge epoch": {"entries": [entry(epoch=2**63)]},
    "producer 0": {"entries": [entry(producer=0)]},
    "producer 251": {"entries": [entry(producer=251)]},
    "duplicate entries": {"entries": [entry(), entry()]},
    "unsorted entries": {"entries": [entry(producer=4), entry(producer=3)]},
    "too many producers": {"entries": [entry(producer=p) for p in range(1, 66)]},
    "too many epochs": {"entries": [entry(epoch=e) for e in range(MAX_EPOCHS_PER_PRODUCER + 1)]},
    "too many entries": {"entries": [entry(producer=p, epoch=e) for p in range(1, 18) for e in range(61)]},
    "too many ranges": {"entries": [entry(ranges=[[2 * i, 2 * i] for i in range(MAX_RANGES + 1)])]},
    "too many ranges in all": {
        "entries": [entry(producer=p, ranges=[[2 * i, 2 * i] for i in range(1000)]) for p in range(1, 6)]
    },
}


@pytest.mark.parametrize("name", sorted(HOSTILE))
def test_hostile_wire_dicts_raise_value_error(name: str) -> None:
    with pytest.raises(ValueError):
        PatchDigest.from_wire(HOSTILE[name])


def test_ints_beyond_msgpack_raise_value_error() -> None:
    with pytest.raises(ValueError):
        PatchDigest.from_wire({"entries": [entry(ranges=[[0, 10**30]])]})


@pytest.mark.parametrize("name", sorted(n for n in HOSTILE if isinstance(HOSTILE[n], dict)))
def test_hostile_digest_messages_raise_decode_error(name: str) -> None:
    fields = {"id": 2, "epoch": 1, "digest": HOSTILE[name]}
    data = msgpack.packb({"v": 1, "k": "digest", "d": fields}, use_bin_type=True)
    with pytest.raises(DecodeError) as info:
        decode(data, DigestMessage)
    assert info.value.reason == "invalid"


def test_to_wire_refuses_a_digest_beyond_the_bounds() -> None:
    too_many = PatchDigest.of(PatchId(p, 0, 0) for p in range(1, 66))
    with pytest.raises(ValueError):
        too_many.to_wire()
    with pytest.raises(ValueError):
        DigestMessage.of(1, 0, too_many)


patch_ids = st.builds(
    PatchId,
    st.integers(1, 4),
    st.sampled_from([0, 1, 1795340000000]),
    st.one_of(st.integers(0, 40), st.integers(0, 2**63 - 1)),
)


@given(st.lists(patch_ids, max_size=80))
def test_ids_of_digest_are_the_sorted_set(values: list[PatchId]) -> None:
    digest = PatchDigest.of(values)
    assert list(digest.ids()) == sorted(set(values))
    assert digest.count == len(set(values))
    assert PatchDigest.from_wire(digest.to_wire()) == digest


@given(st.lists(patch_ids, max_size=40), st.lists(patch_ids, max_size=40))
def test_missing_from_and_union_match_set_algebra(a: list[PatchId], b: list[PatchId]) -> None:
    da, db = PatchDigest.of(a), PatchDigest.of(b)
    assert da.missing_from(db) == sorted(set(a) - set(b))
    assert da.missing_from(set(b)) == sorted(set(a) - set(b))
    assert list(da.union(db).ids()) == sorted(set(a) | set(b))
    assert all((x in da) == (x in set(a)) for x in a + b)


@given(st.lists(patch_ids, max_size=40), st.lists(patch_ids, max_size=40), st.integers(0, 90))
def test_missing_fairly_is_a_fair_prefix_of_the_missing_set(a: list[PatchId], b: list[PatchId], limit: int) -> None:
    da, db = PatchDigest.of(a), PatchDigest.of(b)
    fair = da.missing_fairly(db, limit)
    missing = set(a) - set(b)
    assert len(fair) == min(limit, len(missing)) and len(set(fair)) == len(fair) and set(fair) <= missing
    assert fair == fair_order(missing)[:limit]  # the same order as fair_order of the whole set
    per_producer = Counter(p.producer for p in fair)  # no producer with ids left got two fewer than another
    left = {p.producer for p in missing - set(fair)}
    assert all(per_producer[q] >= max(per_producer.values(), default=0) - 1 for q in left)


def test_announced_is_the_whole_digest_within_the_bounds() -> None:
    digest = PatchDigest({(p, e): [(0, 9), (20, 29)] for p in range(1, 5) for e in range(MAX_EPOCHS_PER_PRODUCER)})
    assert digest.announced() is digest


def test_announced_keeps_the_newest_epochs_the_largest_producers_and_fits_the_wire() -> None:
    epochs = PatchDigest({(3, e): [(0, 0)] for e in range(100)})
    assert sorted(e for _, e in epochs.announced().ranges) == list(range(100 - MAX_EPOCHS_PER_PRODUCER, 100))
    producers = PatchDigest({(p, 0): [(0, p)] for p in range(1, 100)})  # producer p holds p + 1 ids
    assert sorted(p for p, _ in producers.announced().ranges) == list(range(100 - MAX_PRODUCERS, 100))
    entries = PatchDigest({(p, e): [(0, 0)] for p in range(1, 41) for e in range(40)})  # 1600 entries
    kept = entries.announced().ranges
    assert len(kept) == MAX_ENTRIES and {p for p, _ in kept} == set(range(1, 41))  # 25 or 26 each
    assert all(sum(1 for q, _ in kept if q == p) in (25, 26) for p in range(1, 41))
    fragmented = PatchDigest({(2, 0): [(2 * i, 2 * i) for i in range(MAX_RANGES)], (1, 5): [(0, 3)]})
    cut = fragmented.announced()
    assert cut.range_count == MAX_RANGES and (1, 5) in cut.ranges  # the round robin takes producer 1 first
    for big in (epochs, producers, entries, fragmented):
        small = big.announced()
        assert PatchDigest.from_wire(small.to_wire()) == small  # fits
        assert small.missing_from(big) == []  # a subset: nothing announced that is not held


def test_announced_depends_only_on_the_content() -> None:
    a = PatchDigest({(1, e): [(0, 1)] for e in range(80)})
    b = PatchDigest.of(reversed(list(a.ids())))
    assert a.announced() == b.announced()
