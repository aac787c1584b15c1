"""The wire form of a patch digest (which patch ids an agent holds), carried in every heartbeat.

A producer numbers its patches 0, 1, 2, ... within an epoch, so what an agent holds is a few ranges of seq per
(producer, epoch): ``{"entries": [{"producer": p, "epoch": e, "ranges": [[lo, hi], ...], "content": c}, ...]}``,
entries sorted by (producer, epoch) and unique, ranges sorted, disjoint, non-adjacent and inclusive. `content`,
when given, is the entry's content fingerprint: the XOR of the first 8 bytes (little-endian) of the SHA-256 of
every listed patch's bytes (`fingerprint_of_hash`), so two holders of the same ids with other bytes for one of
them announce different fingerprints (a producer that signed two contents for one id). Received digests
are hostile: validation checks every bound (`MAX_PRODUCERS` producers, `MAX_EPOCHS_PER_PRODUCER` epochs each,
`MAX_ENTRIES` (producer, epoch) entries and `MAX_RANGES` ranges in all, ints in range, strict types). What an
agent announces is cut to these bounds (`PatchDigest.announced`), so holding more never stops its heartbeat.
The set logic lives in `swarm.patches.digest`.
"""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field, model_validator

from swarm.bus.keys import MAX_AGENT_ID, MIN_AGENT_ID

MAX_PRODUCERS = 64
# A producer takes a new epoch each time its process starts: 64 covers restarts, the entry bound the receiver's cost.
MAX_EPOCHS_PER_PRODUCER = 64
MAX_ENTRIES = 1024
MAX_RANGES = 4096
MAX_COUNTER = 2**63 - 1

# Strict: a hostile peer's True, 1.0 or "1" is not an int.
_Producer = Annotated[int, Field(ge=MIN_AGENT_ID, le=MAX_AGENT_ID, strict=True)]
_Counter = Annotated[int, Field(ge=0, le=MAX_COUNTER, strict=True)]

Range = tuple[int, int]
_Key = tuple[int, int]  # (producer, epoch)


class DigestEntry(BaseModel):
    """The seq ranges held of one producer's epoch: sorted, disjoint, non-adjacent, inclusive."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    producer: _Producer
    epoch: _Counter
    ranges: Annotated[list[tuple[_Counter, _Counter]], Field(min_length=1, max_length=MAX_RANGES)]
    content: Annotated[int, Field(ge=0, le=2**64 - 1, strict=True)] | None = None

    @model_validator(mode="after")
    def _canonical(self) -> DigestEntry:
        previous_hi = -2
        for lo, hi in self.ranges:
            if lo > hi:
                raise ValueError(f"range [{lo}, {hi}] is empty")
            if lo <= previous_hi + 1:
                raise ValueError("ranges must be sorted, disjoint and not adjacent")
            previous_hi = hi
        return self


class DigestWire(BaseModel):
    """The wire form of a `PatchDigest`; validating it checks every bound."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    entries: Annotated[list[DigestEntry], Field(max_length=MAX_ENTRIES)]

    @model_validator(mode="after")
    def _bounded(self) -> DigestWire:
        previous: _Key | None = None
        epochs_of: dict[int, int] = {}
        total = 0
        for entry in self.entries:
            key = (entry.producer, entry.epoch)
            if previous is not None and key <= previous:
                raise ValueError("entries must be sorted by (producer, epoch) and unique")
            previous = key
            epochs_of[entry.producer] = epochs_of.get(entry.producer, 0) + 1
            if epochs_of[entry.producer] > MAX_EPOCHS_PER_PRODUCER:
                raise ValueError(f"more than {MAX_EPOCHS_PER_PRODUCER} epochs of producer {entry.producer}")
            total += len(entry.ranges)
        if len(epochs_of) > MAX_PRODUCERS:
            raise ValueError(f"more than {MAX_PRODUCERS} producers")
        if total > MAX_RANGES:
            raise ValueError(f"more than {MAX_RANGES} ranges")
        return self


EMPTY_DIGEST = DigestWire(entries=[])


def fingerprint_of_hash(sha256: bytes) -> int:
    """One patch's share of its entry's `content`, from the SHA-256 of its bytes: the first 8 bytes, little-endian."""
    return int.from_bytes(sha256[:8], "little")
