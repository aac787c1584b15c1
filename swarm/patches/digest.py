"""Patch digests: the compact list of every patch id an agent holds, for the sync protocol.

A producer numbers its patches 0, 1, 2, ... within an epoch, so what an agent holds is a few ranges per
(producer, epoch). A `PatchDigest` keeps, per producer and epoch, the sorted, disjoint, non-adjacent ranges
of seq ``[(lo, hi), ...]``, both ends inclusive. Comparing a peer's digest with one's own (`missing_from`)
says which patches to request from it.

On the wire (`to_wire` / `from_wire`, and `DigestMessage` for the bus) a digest is
``{"entries": [{"producer": p, "epoch": e, "ranges": [[lo, hi], ...]}, ...]}``, entries sorted by
(producer, epoch) and unique, ranges in the canonical form above. Received digests are hostile: both are
validated by `swarm.bus.holdings.DigestWire` (the heartbeat carries it too), bounded (`MAX_PRODUCERS`
producers, `MAX_EPOCHS_PER_PRODUCER` epochs each, `MAX_ENTRIES` entries and `MAX_RANGES` ranges in all, ints in
range) and anything else raises ValueError (DecodeError via the codec). `to_wire` refuses a digest beyond the
bounds; `announced` is the part of a digest that fits them, which is what an agent puts in its heartbeat.
"""

from __future__ import annotations

from bisect import bisect_right
from collections.abc import Iterable, Iterator, Mapping
from itertools import groupby, islice
from typing import Any

from pydantic import Field, ValidationError

from swarm.bus.codec import WireMessage
from swarm.bus.holdings import (  # noqa: F401  (the wire model and its bounds, re-exported)
    MAX_COUNTER,
    MAX_ENTRIES,
    MAX_EPOCHS_PER_PRODUCER,
    MAX_PRODUCERS,
    MAX_RANGES,
    DigestEntry,
    DigestWire,
    Range,
    _Counter,
    _Key,
    _Producer,
)
from swarm.errors import validation_problem
from swarm.patches.patch import PatchId


def _normalise(ranges: Iterable[Range]) -> tuple[Range, ...]:
    """Sorted, merged (overlapping and adjacent ranges joined) copy of `ranges`."""
    merged: list[list[int]] = []
    for lo, hi in sorted(ranges):
        if merged and lo <= merged[-1][1] + 1:
            merged[-1][1] = max(merged[-1][1], hi)
        else:
            merged.append([lo, hi])
    return tuple((lo, hi) for lo, hi in merged)


def interleave(streams: Iterable[Iterable[PatchId]]) -> Iterator[PatchId]:
    """Round robin: the first of every stream, then the second of every stream, ...; lazy, so a stream may be
    endless (a hostile digest's range of 2**63 seqs). The streams are taken at the call, the items lazily."""
    return _round_robin([iter(stream) for stream in streams])


def _round_robin(active: list[Iterator[PatchId]]) -> Iterator[PatchId]:
    while active:
        still = []
        for stream in active:
            item = next(stream, None)
            if item is not None:
                yield item
                still.append(stream)
        active = still


def fair_order(ids: Iterable[PatchId]) -> list[PatchId]:
    """`ids` round robin across producers, and within a producer across its epochs, each epoch's seqs in order:
    the order in which to ask for them so that no producer's or epoch's backlog holds the others back."""
    by_key = sorted(set(ids))
    per_producer = [
        interleave(list(g) for _, g in groupby(group, key=lambda p: p.epoch))
        for _, group in groupby(by_key, key=lambda p: p.producer)
    ]
    return list(interleave(per_producer))


def _round_robin_keys(lists: list[list[_Key]]) -> Iterator[_Key]:
    for depth in range(max((len(keys) for keys in lists), default=0)):
        for keys in lists:
            if depth < len(keys):
                yield keys[depth]


def _subtract(ranges: tuple[Range, ...], holes: tuple[Range, ...]) -> Iterator[Range]:
    """The parts of `ranges` not covered by `holes` (both canonical)."""
    j = 0
    for lo, hi in ranges:
        while j < len(holes) and holes[j][1] < lo:
            j += 1
        k = j
        while lo <= hi:
            if k >= len(holes) or holes[k][0] > hi:
                yield lo, hi
                break
            h_lo, h_hi = holes[k]
            if h_lo > lo:
                yield lo, h_lo - 1
            lo = max(lo, h_hi + 1)
            k += 1


class PatchDigest:
    """An immutable set of patch ids, kept as seq ranges per (producer, epoch). Compare with ==."""

    __slots__ = ("_ranges",)

    def __init__(self, ranges: Mapping[_Key, Iterable[Range]] | None = None) -> None:
        """`ranges`: {(producer, epoch): [(lo, hi), ...]} in any order; overlaps and neighbours are merged."""
        table: dict[_Key, tuple[Range, ...]] = {}
        for (producer, epoch), seqs in sorted((ranges or {}).items()):
            checked = []
            for lo, hi in seqs:
                PatchId(producer, epoch, lo)  # validates non-negative ints
                PatchId(producer, epoch, hi)
                if lo > hi:
                    raise ValueError(f"range [{lo}, {hi}] is empty")
                checked.append((lo, hi))
            if checked:
                table[(producer, epoch)] = _normalise(checked)
        self._ranges = table

    @classmethod
    def of(cls, ids: Iterable[PatchId]) -> PatchDigest:
        """The digest of a set of ids (duplicates are fine)."""
        seqs: dict[_Key, set[int]] = {}
        for pid in ids:
            seqs.setdefault((pid.producer, pid.epoch), set()).add(pid.seq)
        table: dict[_Key, list[Range]] = {}
        for key, values in seqs.items():
            ranges: list[Range] = []
            for seq in sorted(values):
                if ranges and seq == ranges[-1][1] + 1:
                    ranges[-1] = (ranges[-1][0], seq)
                else:
                    ranges.append((seq, seq))
            table[key] = ranges
        return cls(table)

    @property
    def ranges(self) -> dict[_Key, tuple[Range, ...]]:
        """{(producer, epoch): ((lo, hi), ...)}, keys sorted; a copy."""
        return dict(self._ranges)

    @property
    def count(self) -> int:
        """How many patch ids the digest lists."""
        return sum(hi - lo + 1 for seqs in self._ranges.values() for lo, hi in seqs)

    @property
    def range_count(self) -> int:
        return sum(len(seqs) for seqs in self._ranges.values())

    def ids(self) -> Iterator[PatchId]:
        """Every listed id, in PatchId order (lazily: a hostile digest may list 2**63 ids)."""
        for (producer, epoch), seqs in self._ranges.items():
            for lo, hi in seqs:
                for seq in range(lo, hi + 1):
                    yield PatchId(producer, epoch, seq)

    def __contains__(self, pid: object) -> bool:
        if not isinstance(pid, PatchId):
            return False
        seqs = self._ranges.get((pid.producer, pid.epoch), ())
        i = bisect_right(seqs, (pid.seq, MAX_COUNTER + 1)) - 1  # the last range starting at or below seq
        return i >= 0 and seqs[i][1] >= pid.seq

    def __len__(self) -> int:
        return self.count

    def __bool__(self) -> bool:
        return bool(self._ranges)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, PatchDigest):
            return NotImplemented
        return self._ranges == other._ranges

    def __hash__(self) -> int:
        return hash(tuple(self._ranges.items()))

    def __repr__(self) -> str:
        parts = [f"{p}.{e}:" + ",".join(f"{lo}-{hi}" for lo, hi in seqs) for (p, e), seqs in self._ranges.items()]
        return f"PatchDigest({' '.join(parts)})"

    def union(self, other: PatchDigest | Iterable[PatchId]) -> PatchDigest:
        """Every id listed by either."""
        if not isinstance(other, PatchDigest):
            other = PatchDigest.of(other)
        table: dict[_Key, list[Range]] = {key: list(seqs) for key, seqs in self._ranges.items()}
        for key, seqs in other._ranges.items():
            table.setdefault(key, []).extend(seqs)
        return PatchDigest(table)

    __or__ = union

    def missing_from(self, held: PatchDigest | set[PatchId], limit: int | None = None) -> list[PatchId]:
        """The ids this digest lists that `held` lacks, sorted; at most `limit` of them if given.

        Works on ranges, so a peer's digest listing a huge range costs no more than its range count, as long
        as a `limit` bounds the answer.
        """
        if not isinstance(held, PatchDigest):
            held = PatchDigest.of(held)
        missing = self._missing_ids(held)
        return list(missing if limit is None else islice(missing, max(limit, 0)))

    def missing_fairly(self, held: PatchDigest, limit: int) -> list[PatchId]:
        """At most `limit` of the ids this digest lists that `held` lacks, taken round robin across producers
        and, within a producer, across its epochs (each epoch's oldest seqs first), in that order. So a digest
        claiming 2**63 seqs of one producer's epoch yields no more of them than of any other epoch it lists that
        still has missing ids. Costs the range count plus `limit`."""
        per_producer = [
            interleave(self._missing_of(key, held) for key in keys)
            for _, keys in groupby(self._ranges, key=lambda k: k[0])
        ]
        return list(islice(interleave(per_producer), max(limit, 0)))

    def _missing_of(self, key: _Key, held: PatchDigest) -> Iterator[PatchId]:
        producer, epoch = key
        for lo, hi in _subtract(self._ranges[key], held._ranges.get(key, ())):
            for seq in range(lo, hi + 1):
                yield PatchId(producer, epoch, seq)

    def _missing_ids(self, held: PatchDigest) -> Iterator[PatchId]:
        for key in self._ranges:
            yield from self._missing_of(key, held)

    def announced(self) -> PatchDigest:
        """The part of this digest that fits the wire bounds, chosen from its content alone (two agents holding
        the same ids announce the same): a subset, so a receiver never takes an id for held that is not.

        Per producer its newest `MAX_EPOCHS_PER_PRODUCER` epochs; of more than `MAX_PRODUCERS` producers, those
        with the most ids (ties to the lower id); then entries are taken round robin across the producers, each
        producer's newest epoch first, while `MAX_ENTRIES` entries and `MAX_RANGES` ranges allow (an entry with
        more ranges than are left keeps its first ones). What is left out is still served on request; it is
        only not advertised, so a peer that never saw it listed does not ask for it."""
        per_producer: dict[int, list[_Key]] = {}
        for key in self._ranges:
            per_producer.setdefault(key[0], []).append(key)
        if (
            len(per_producer) <= MAX_PRODUCERS
            and len(self._ranges) <= MAX_ENTRIES
            and self.range_count <= MAX_RANGES
            and all(len(keys) <= MAX_EPOCHS_PER_PRODUCER for keys in per_producer.values())
        ):
            return self
        size = {p: sum(hi - lo + 1 for k in keys for lo, hi in self._ranges[k]) for p, keys in per_producer.items()}
        kept = sorted(per_producer, key=lambda p: (-size[p], p))[:MAX_PRODUCERS]
        newest = [sorted(per_producer[p], reverse=True)[:MAX_EPOCHS_PER_PRODUCER] for p in sorted(kept)]
        table: dict[_Key, tuple[Range, ...]] = {}
        ranges_left = MAX_RANGES
        for key in _round_robin_keys(newest):
            if len(table) >= MAX_ENTRIES or ranges_left == 0:
                break
            seqs = self._ranges[key][:ranges_left]
            table[key] = seqs
            ranges_left -= len(seqs)
        digest = PatchDigest.__new__(PatchDigest)
        digest._ranges = dict(sorted(table.items()))
        return digest

    # --- wire -------------------------------------------------------------------------------------------

    def to_wire_model(self, content: Mapping[_Key, int] | None = None) -> DigestWire:
        """The validated wire model, with each entry's content fingerprint from `content` when given; raises
        ValueError if the digest exceeds the wire bounds."""
        entries = []
        for (producer, epoch), seqs in self._ranges.items():
            entry: dict[str, Any] = {"producer": producer, "epoch": epoch, "ranges": [list(r) for r in seqs]}
            if content is not None and (producer, epoch) in content:
                entry["content"] = content[(producer, epoch)]
            entries.append(entry)
        return _validated({"entries": entries})

    def fingerprints(self, of: Mapping[PatchId, int]) -> dict[_Key, int]:
        """Each entry's content fingerprint: the XOR of `of[pid]` (`fingerprint_of_hash`) over the ids it lists;
        every listed id must be in `of`."""
        table: dict[_Key, int] = {}
        for pid in self.ids():
            key = (pid.producer, pid.epoch)
            table[key] = table.get(key, 0) ^ of[pid]
        return table

    def to_wire(self) -> dict[str, Any]:
        """``{"entries": [{"producer", "epoch", "ranges": [[lo, hi], ...]}, ...]}``; ValueError if too big."""
        return _to_dict(self.to_wire_model())

    @classmethod
    def from_wire_model(cls, wire: DigestWire) -> PatchDigest:
        digest = cls.__new__(cls)
        digest._ranges = {(e.producer, e.epoch): tuple((lo, hi) for lo, hi in e.ranges) for e in wire.entries}
        return digest

    @staticmethod
    def content_of(wire: DigestWire) -> dict[_Key, int]:
        """The content fingerprints a wire digest announces, per (producer, epoch) (entries without one left out)."""
        return {(e.producer, e.epoch): e.content for e in wire.entries if e.content is not None}

    @classmethod
    def from_wire(cls, data: Any) -> PatchDigest:
        """Validate a (hostile) wire dict; raise ValueError if it is not a canonical, bounded digest."""
        return cls.from_wire_model(_validated(data))


def _validated(data: Any) -> DigestWire:
    if isinstance(data, DigestWire):
        return data
    if not isinstance(data, dict):
        raise ValueError(f"a digest must be a dict, got {type(data).__name__}")
    try:
        return DigestWire.model_validate(data)
    except ValidationError as exc:
        raise ValueError(f"invalid digest: {validation_problem(exc, echo_input=False)}"[:300]) from None


def _to_dict(wire: DigestWire) -> dict[str, Any]:
    entries = []
    for e in wire.entries:
        entry: dict[str, Any] = {"producer": e.producer, "epoch": e.epoch, "ranges": [[lo, hi] for lo, hi in e.ranges]}
        if e.content is not None:
            entry["content"] = e.content
        entries.append(entry)
    return {"entries": entries}


class DigestMessage(WireMessage):
    """What agent `id` (in its process epoch `epoch`) holds: sent alone or inside a heartbeat."""

    KIND = "digest"

    id: _Producer
    epoch: _Counter = Field(description="the sender's process epoch")
    digest: DigestWire

    @classmethod
    def of(cls, agent_id: int, epoch: int, digest: PatchDigest) -> DigestMessage:
        """ValueError if the digest exceeds the wire bounds."""
        return cls(id=agent_id, epoch=epoch, digest=digest.to_wire_model())

    def patch_digest(self) -> PatchDigest:
        return PatchDigest.from_wire_model(self.digest)
