"""Patches in chunks: splitting a patch's wire bytes into small messages, and putting them back together.

Measured with Zenoh 1.10 under nftables loss: a 200 kB reliable message stalls a TCP link at 30 % loss and
never arrives over UDP, so a patch (50-80 kB at 0.1 m) never travels as one message. Every push and every pull
reply is a stream of `PatchChunk`s of at most `chunk_bytes` payload each. A chunk names its patch, its index and
the patch's total size and CRC-32, so the `Reassembler` can mix chunks of the same patch from different senders
(a push that lost chunks, then a pull reply from another holder: every holder serves the exact bytes it
received) and tell when they cannot belong together.

The reassembler is bounded: at most `max_bytes` of incomplete patches (the oldest is dropped to make room; a
single one may reach `max_patch_bytes`), at most `max_assemblies` incomplete patches, at most `max_per_sender` of
them started by one sender, and an assembly that gets no chunk for `timeout_s` is dropped. A sender over its
count drops its own oldest assembly, so one sender's stream of one-byte chunks of ever new patches cannot push
out the others'; past the total count the oldest assembly of the sender that started the most goes. Every way,
the digests show the patch missing and it is pulled again. A chunk that contradicts its assembly (another
size, CRC or count, or more bytes than the size leaves room for) restarts it, so no assembly holds more than its
patch's size.
"""

from __future__ import annotations

import time
import zlib
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field

from pydantic import Field, model_validator

from swarm.bus.codec import WireMessage
from swarm.bus.messages import AgentId, Counter
from swarm.patches.patch import PatchId

MAX_CHUNKS = 4096  # a patch of more chunks than this is not a patch (4096 x 8 kB = 32 MB)
# Incomplete patches at once: an honest sender has at most its unfinished pushes (one patch a second, kept up to
# `assembly_timeout_s`) and the replies to one requester's requests (`max_in_flight` x `batch_size` <= 64 x 64)
# in progress; the swarm has at most a few dozen senders.
MAX_ASSEMBLIES = 1024
MAX_ASSEMBLIES_PER_SENDER = 256


class PatchChunk(WireMessage):
    """Chunk `index` of `count` of patch (producer, epoch, seq), sent by agent `sender` (any holder)."""

    KIND = "patch_chunk"

    sender: AgentId
    producer: AgentId
    epoch: Counter
    seq: Counter
    index: int = Field(ge=0, lt=MAX_CHUNKS)
    count: int = Field(ge=1, le=MAX_CHUNKS)
    total_bytes: int = Field(ge=1, le=1 << 30)
    crc32: int = Field(ge=0, le=0xFFFFFFFF, description="CRC-32 of the whole patch's wire bytes")
    data: bytes

    @model_validator(mode="after")
    def _consistent(self) -> PatchChunk:
        if self.index >= self.count:
            raise ValueError(f"chunk index {self.index} is not below count {self.count}")
        if len(self.data) == 0 or len(self.data) > self.total_bytes:
            raise ValueError(f"chunk of {len(self.data)} bytes in a patch of {self.total_bytes}")
        return self

    @property
    def patch_id(self) -> PatchId:
        return PatchId(self.producer, self.epoch, self.seq)


def split_patch(sender: int, pid: PatchId, data: bytes, chunk_bytes: int) -> list[PatchChunk]:
    """The chunks of a patch's wire bytes, in order."""
    if not data:
        raise ValueError("a patch has at least one byte")
    count = -(-len(data) // chunk_bytes)
    if count > MAX_CHUNKS:
        raise ValueError(f"{len(data)} bytes need {count} chunks of {chunk_bytes}, more than {MAX_CHUNKS}")
    crc = zlib.crc32(data)
    return [
        PatchChunk(
            sender=sender,
            producer=pid.producer,
            epoch=pid.epoch,
            seq=pid.seq,
            index=i,
            count=count,
            total_bytes=len(data),
            crc32=crc,
            data=data[i * chunk_bytes : (i + 1) * chunk_bytes],
        )
        for i in range(count)
    ]


@dataclass
class _Assembly:
    sender: int  # the sender of its first chunk, which the per-sender bound charges
    count: int
    total_bytes: int
    crc32: int
    parts: dict[int, bytes] = field(default_factory=dict)
    received_bytes: int = 0
    touched: float = 0.0

    def matches(self, chunk: PatchChunk) -> bool:
        if (chunk.count, chunk.total_bytes, chunk.crc32) != (self.count, self.total_bytes, self.crc32):
            return False
        return chunk.index in self.parts or self.received_bytes + len(chunk.data) <= self.total_bytes


class Reassembler:
    """Collects chunks into whole patches; `add` returns the patch's bytes once the last chunk arrives.

    Counts what it throws away in `dropped` (reason -> chunks or assemblies): "mismatch" (a chunk contradicting
    or overfilling its assembly, which restarts it), "overflow" (an assembly evicted for room), "sender_limit"
    (a sender's oldest assembly, evicted when it starts one more than `max_per_sender`), "count_limit" (evicted
    to stay within `max_assemblies`), "expired", "corrupt" (all chunks arrived but the CRC-32 or size is wrong),
    "oversize" (a patch larger than `max_patch_bytes`).
    """

    def __init__(
        self,
        max_bytes: int,
        timeout_s: float,
        max_patch_bytes: int,
        clock: Callable[[], float] = time.monotonic,
        max_assemblies: int = MAX_ASSEMBLIES,
        max_per_sender: int = MAX_ASSEMBLIES_PER_SENDER,
    ) -> None:
        if max_assemblies < 1 or max_per_sender < 1:
            raise ValueError("the assembly bounds must be at least 1")
        self.max_bytes = max_bytes
        self.timeout_s = timeout_s
        self.max_patch_bytes = max_patch_bytes
        self.max_assemblies = max_assemblies
        self.max_per_sender = max_per_sender
        self._clock = clock
        self._assemblies: dict[PatchId, _Assembly] = {}
        # sender -> the assemblies it started, least recently touched first
        self._by_sender: dict[int, OrderedDict[PatchId, None]] = {}
        self._bytes = 0
        self.dropped: dict[str, int] = {}

    def add(self, chunk: PatchChunk) -> bytes | None:
        """Take one chunk; the whole patch's bytes when this chunk completes it, else None."""
        pid = chunk.patch_id
        if chunk.total_bytes > self.max_patch_bytes:
            self._count("oversize")
            return None
        assembly = self._assemblies.get(pid)
        if assembly is not None and not assembly.matches(chunk):
            self._count("mismatch")
            self._discard(pid)
            assembly = None
        if assembly is None:
            self._make_count_room(chunk.sender)
            assembly = self._assemblies[pid] = _Assembly(chunk.sender, chunk.count, chunk.total_bytes, chunk.crc32)
            self._by_sender.setdefault(chunk.sender, OrderedDict())[pid] = None
        else:
            self._by_sender[assembly.sender].move_to_end(pid)
        assembly.touched = self._clock()
        if chunk.index in assembly.parts:
            return None  # a duplicate (push and pull overlapped)
        assembly.parts[chunk.index] = chunk.data
        assembly.received_bytes += len(chunk.data)
        self._bytes += len(chunk.data)
        if len(assembly.parts) == assembly.count:
            self._discard(pid)
            data = b"".join(assembly.parts[i] for i in range(assembly.count))
            if len(data) != assembly.total_bytes or zlib.crc32(data) != assembly.crc32:
                self._count("corrupt")
                return None
            return data
        self._make_room()
        return None

    def forget(self, pid: PatchId) -> None:
        """Drop a partial patch that is no longer wanted (e.g. it arrived whole by another way)."""
        self._discard(pid)

    def expire(self) -> None:
        """Drop assemblies that got no chunk for `timeout_s`."""
        cutoff = self._clock() - self.timeout_s
        for pid in [p for p, a in self._assemblies.items() if a.touched < cutoff]:
            self._count("expired")
            self._discard(pid)

    def partial(self, pid: PatchId) -> tuple[int, int] | None:
        """(chunks received, chunks expected) of an incomplete patch, or None."""
        assembly = self._assemblies.get(pid)
        return None if assembly is None else (len(assembly.parts), assembly.count)

    @property
    def pending_bytes(self) -> int:
        return self._bytes

    def per_sender(self) -> dict[int, int]:
        """Sender -> incomplete patches it started."""
        return {sender: len(pids) for sender, pids in self._by_sender.items()}

    def __len__(self) -> int:
        return len(self._assemblies)

    def _make_room(self) -> None:
        while self._bytes > self.max_bytes and len(self._assemblies) > 1:
            oldest = min(self._assemblies, key=lambda p: self._assemblies[p].touched)
            self._count("overflow")
            self._discard(oldest)

    def _make_count_room(self, sender: int) -> None:
        """Before `sender` starts an assembly: evict its own oldest if it is at its bound, and the oldest of the
        sender that started the most (ties to the higher id) if the total is."""
        own = self._by_sender.get(sender)
        if own is not None and len(own) >= self.max_per_sender:
            self._count("sender_limit")
            self._discard(next(iter(own)))
        if len(self._assemblies) >= self.max_assemblies:
            largest = max(self._by_sender, key=lambda s: (len(self._by_sender[s]), s))
            self._count("count_limit")
            self._discard(next(iter(self._by_sender[largest])))

    def _discard(self, pid: PatchId) -> None:
        assembly = self._assemblies.pop(pid, None)
        if assembly is not None:
            self._bytes -= assembly.received_bytes
            own = self._by_sender[assembly.sender]
            del own[pid]
            if not own:
                del self._by_sender[assembly.sender]

    def _count(self, reason: str) -> None:
        self.dropped[reason] = self.dropped.get(reason, 0) + 1
