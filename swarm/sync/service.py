"""`PatchSync`: one agent's side of map sharing, on the bus (design: docs/architecture.md, "Patch sync").

- **Push:** an own sealed patch goes out once, as chunks on ``agent/<own>/patch`` (reliable, drop when
  congested).
- **Announce:** `holdings` is the digest of every patch held, own and received; the agent puts it in each
  heartbeat and sends an extra heartbeat when it changes (`on_holdings_changed`).
- **Pull:** heartbeats from peers (`on_state`) feed a `PullScheduler`; every `period_s` the missing patches are
  requested from the nearest alive holder with a query on ``agent/<holder>/store``; the reply is the patches'
  chunks.
- **Serve:** the queryable answers for every held patch, own or received, with the exact bytes it holds, so any
  holder relays and a healed partition converges by store and forward. A 1.2 kB query asks for up to 64
  patches (4 MiB of replies: 3400 times the query), so serving is bounded per requester and for all of them
  together: a token bucket of queries (`serve_requests_hz`) and one of reply bytes (`serve_bytes_per_s`).
  The requester names itself (``from=``, or nobody), so a liar can take another's share but not more than
  the total (`serve_total_factor` requesters' worth). Patches past the byte budget are left out of the reply;
  the requester asks again after its back-off. The chunks are built and sent on a worker thread. With TLS the
  observer's certificate may not query at all (swarm/bus/session.py).

Received chunks are reassembled (`Reassembler`), the whole patch is handed to the `sink` (decode, validate,
verify its producer's signature, fuse; in the mapper's thread), and only a patch the sink accepted is held,
announced and served. A push carries its sender's own patches only, so a chunk of another producer's patch is a
relay, taken only from a store reply (and, with signing, fused only when its producer's signature holds). No
chunk of this agent's own current epoch is ever taken from another: a member cannot pre-empt the id of a patch
this agent has yet to seal (dropped as "own_id"). A patch held
already is ignored, so receiving it twice changes nothing. Anything malformed is counted (`stats()`) and
dropped. Everything here runs on the event loop thread except the sink's work.
"""

from __future__ import annotations

import asyncio
import hashlib
import logging
import random
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any

from swarm.bus.bridge import AsyncBus
from swarm.bus.codec import DecodeError, decode, encode
from swarm.bus.holdings import EMPTY_DIGEST, DigestWire, fingerprint_of_hash
from swarm.bus.limits import KeyedBuckets
from swarm.bus.messages import AgentState
from swarm.config import SyncSettings, Vec3
from swarm.patches.digest import PatchDigest
from swarm.patches.patch import PatchId
from swarm.patches.pull import PullRequest, PullScheduler
from swarm.patches.wire import PatchDecodeError
from swarm.sync.chunks import PatchChunk, Reassembler, split_patch
from swarm.sync.requests import parse_request, request_parameters

log = logging.getLogger(__name__)

CHUNK_KIND = PatchChunk.KIND
STORE_KIND = "store"
_CHUNK_OVERHEAD = 512  # envelope and header fields around a chunk's data, generously

# Decode and validate a patch's wire bytes, check that they hold patch `pid`, and fuse it; raise
# PatchDecodeError (reason "id_mismatch" for another id) without changing anything if it is unusable.
PatchSink = Callable[[bytes, PatchId], Awaitable[None]]
Position = Callable[[], Vec3]


@dataclass
class SyncCounters:
    pushed: int = 0  # own patches pushed
    push_chunks_dropped: int = 0  # on purpose (push_drop_fraction)
    received_by_push: int = 0
    received_by_pull: int = 0
    duplicate_chunks: int = 0  # chunks of patches already held (a push and a pull overlapped)
    served: int = 0  # patches sent in replies
    requests_served: int = 0
    requests_refused: int = 0  # malformed requests
    # also in the bus counters: "store" dropped "rate", "rate_total", "budget"; "withheld" for a reply left short
    requests_limited: int = 0  # over the requester's (or everybody's) query rate or byte budget: nothing served
    patches_withheld: int = 0  # held and asked for, left out of a reply by the byte budget


class PatchSync:
    def __init__(
        self,
        bus: AsyncBus,
        settings: SyncSettings,
        own_id: int,
        sink: PatchSink,
        position: Position,
        max_patch_bytes: int,
        on_holdings_changed: Callable[[], None] | None = None,
        share: bool = True,
        clock: Callable[[], float] = time.monotonic,
        own_epoch: int | None = None,
    ) -> None:
        self.bus = bus
        self.share = share  # False: hold and announce own patches only (the frontier-only strategy)
        self.keys = bus.keys
        self.settings = settings
        self.own_id = own_id
        self.own_epoch = own_epoch  # this process's epoch: its ids are ours alone to fill
        self._sink = sink
        self._position = position
        self._on_holdings_changed = on_holdings_changed
        self.scheduler = PullScheduler(own_id, settings)
        self.reassembler = Reassembler(settings.max_assembly_bytes, settings.assembly_timeout_s, max_patch_bytes)
        self.counters = SyncCounters()
        self.rejected: dict[str, int] = {}  # whole patches the sink refused, by reason
        self.received_from: dict[int, int] = {}  # sender -> patches completed by its chunks
        self.served_to: dict[int, int] = {}  # requester -> patches served
        self.held_at: dict[PatchId, float] = {}  # wall-clock time each patch was first held
        self._held: dict[PatchId, bytes] = {}
        self._content: dict[PatchId, bytes] = {}  # SHA-256 of each held patch's bytes
        self._announced_content: dict[tuple[int, int], int] = {}  # content fingerprint per announced entry
        self.content_conflicts: set[tuple[int, int, int]] = set()  # (peer, producer, epoch) announced otherwise
        self._digest = PatchDigest()
        self._announced = PatchDigest()  # the part of _digest that fits a heartbeat (PatchDigest.announced)
        self._holdings: DigestWire = EMPTY_DIGEST
        # peer -> (holdings, finished, content fingerprints of its entries), from heartbeats
        self._peers: dict[int, tuple[PatchDigest, bool, dict[tuple[int, int], int]]] = {}
        # peer -> (monotonic time it left, its last holdings and finished flag); judged against what we hold
        # when asked, so a peer that left in step and missed a patch we sealed after is waited for too
        self._departed: dict[int, tuple[float, PatchDigest, bool, dict[tuple[int, int], int]]] = {}
        self._accepting: set[PatchId] = set()
        self._tasks: set[asyncio.Task[Any]] = set()
        self._loop_task: asyncio.Task[None] | None = None
        self._random = random.Random(own_id)
        factor = settings.serve_total_factor
        rate, budget = settings.serve_requests_hz, settings.serve_bytes_per_s
        self._serve_requests = KeyedBuckets(rate, rate, factor, 1024, clock)
        self._serve_bytes = KeyedBuckets(budget, budget, factor, 1024, clock)

    # --- lifecycle --------------------------------------------------------------------------------------

    def start(self) -> None:
        """Subscribe to pushes, serve the store, and start the pull loop (call on the event loop); without
        sharing, nothing (own patches are still held and announced)."""
        if not self.share:
            return
        self.bus.subscribe(
            self.keys.all_patches, PatchChunk, self._on_push, max_bytes=self.settings.chunk_bytes + _CHUNK_OVERHEAD
        )
        self.bus.declare_queryable(self.keys.store(self.own_id), STORE_KIND, self._serve)
        self._loop_task = asyncio.create_task(self._run())

    async def stop(self) -> None:
        tasks = [t for t in (self._loop_task, *self._tasks) if t is not None]
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)

    # --- what we hold -----------------------------------------------------------------------------------

    @property
    def holdings(self) -> DigestWire:
        """The digest to put in the heartbeat."""
        return self._holdings

    def held_ids(self) -> list[PatchId]:
        return sorted(self._held)

    def content_hashes(self) -> dict[str, str]:
        """Patch id -> SHA-256 of the bytes held (what is served): a signature is deterministic and a relay serves
        what it received, so two holders of one patch hold the same bytes, and a different hash is other content."""
        return {str(pid): self._content[pid].hex() for pid in sorted(self._held)}

    def add_own(self, pid: PatchId, data: bytes) -> None:
        """An own patch was sealed: hold it, announce it, push it."""
        if pid.producer != self.own_id:
            raise ValueError(f"patch {pid} is not produced by agent {self.own_id}")
        if not self._hold(pid, data) or not self.share:
            return
        self.counters.pushed += 1
        key = self.keys.patch(self.own_id)
        for chunk in split_patch(self.own_id, pid, data, self.settings.chunk_bytes):
            if self.settings.push_drop_fraction and self._random.random() < self.settings.push_drop_fraction:
                self.counters.push_chunks_dropped += 1
                continue
            self.bus.publish(key, chunk, reliable=True)

    def add_recovered(self, pid: PatchId, data: bytes) -> None:
        """An own patch of an earlier run, reloaded from disk: hold and announce it (peers pull what they lack)."""
        if pid.producer != self.own_id:
            raise ValueError(f"patch {pid} is not produced by agent {self.own_id}")
        self._hold(pid, data)

    def _hold(self, pid: PatchId, data: bytes) -> bool:
        if pid in self._held:
            return False
        self._held[pid] = data
        self._content[pid] = hashlib.sha256(data).digest()
        self.held_at[pid] = time.time()
        self._digest = self._digest.union((pid,))
        self._announced = self._digest.announced()
        self._announced_content = self._announced.fingerprints(
            {p: fingerprint_of_hash(self._content[p]) for p in self._announced.ids()}
        )
        self._holdings = self._announced.to_wire_model(self._announced_content)
        self.scheduler.note_received(pid)
        self.reassembler.forget(pid)
        if self._on_holdings_changed is not None:
            self._on_holdings_changed()
        return True

    # --- peers ------------------------------------------------------------------------------------------

    def on_state(self, state: AgentState) -> None:
        """A peer's heartbeat: where it is and what it holds."""
        if state.id == self.own_id:
            return
        digest = PatchDigest.from_wire_model(state.holdings)
        self._peers[state.id] = (digest, state.finished, PatchDigest.content_of(state.holdings))
        self._departed.pop(state.id, None)
        self.scheduler.update_peer(state.id, state.position, digest)

    def peer_left(self, peer_id: int, now: float | None = None) -> None:
        now = time.monotonic() if now is None else now
        last = self._peers.pop(peer_id, None)
        self.scheduler.remove_peer(peer_id)
        if last is not None:
            self._departed[peer_id] = (now, *last)
        elif peer_id in self._departed:  # back by its token alone and gone again: still the one we wait for
            self._departed[peer_id] = (now, *self._departed[peer_id][1:])

    def _in_step(self, peer: int, digest: PatchDigest, finished: bool, content: dict[tuple[int, int], int]) -> bool:
        """A peer holding what we hold announces the same part, and the same bytes for it where it says."""
        return finished and digest == self._announced and self._same_content(peer, content)

    def _same_content(self, peer: int, content: dict[tuple[int, int], int]) -> bool:
        """Whether the peer's fingerprints agree with ours on every entry both give; a disagreement is other bytes
        under one id (a producer that signed two contents), counted once per peer and entry."""
        same = True
        for key, fingerprint in content.items():
            ours = self._announced_content.get(key)
            if ours is not None and ours != fingerprint:
                self.content_conflicts.add((peer, *key))
                same = False
        return same

    def settled(self, now: float | None = None) -> bool:
        """Every peer heard from has finished (sealed its last patch) and holds exactly what this agent holds:
        nothing more will come, so the swarm has one map.

        A peer that left less than `linger_wait_departed_s` ago and was, when it left, not in step with what
        this agent holds now holds this back: on a lossy radio a lease expiry is often a flap, and the peer's
        next heartbeat brings it back (then it is judged on that heartbeat)."""
        now = time.monotonic() if now is None else now
        for peer, (left, digest, finished, content) in self._departed.items():
            if now - left < self.settings.linger_wait_departed_s and not self._in_step(peer, digest, finished, content):
                return False
        return all(self._in_step(peer, *heard) for peer, heard in self._peers.items())

    def heard_from(self) -> set[int]:
        """The peers whose heartbeat (holdings) has arrived and who have not left since."""
        return set(self._peers)

    # --- receiving --------------------------------------------------------------------------------------

    def _on_push(self, key: str, chunk: PatchChunk) -> None:
        if self.keys.agent_id_of(key) != chunk.sender:
            self.bus.counters.dropped(CHUNK_KIND, "sender_mismatch")
            return
        if chunk.producer != chunk.sender:
            self.bus.counters.dropped(CHUNK_KIND, "pushed_relay")
            return
        self._take(chunk, via_pull=False)

    def _take(self, chunk: PatchChunk, via_pull: bool) -> asyncio.Task[None] | None:
        pid = chunk.patch_id
        if pid.producer == self.own_id and pid.epoch == self.own_epoch:
            self.bus.counters.dropped(CHUNK_KIND, "own_id")
            return None
        if pid in self._held or pid in self._accepting:
            self.counters.duplicate_chunks += 1
            return None
        data = self.reassembler.add(chunk)
        if data is None:
            return None
        self._accepting.add(pid)
        task = asyncio.create_task(self._accept(pid, data, chunk.sender, via_pull))
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)
        return task

    async def _accept(self, pid: PatchId, data: bytes, sender: int, via_pull: bool) -> None:
        try:
            try:
                await self._sink(data, pid)
            except PatchDecodeError as exc:
                self._reject(exc.reason)
                return
            self._hold(pid, data)  # new: `_take` lets one completed copy of a patch through
            self.received_from[sender] = self.received_from.get(sender, 0) + 1
            if via_pull:
                self.counters.received_by_pull += 1
            else:
                self.counters.received_by_push += 1
        finally:
            self._accepting.discard(pid)

    def _reject(self, reason: str) -> None:
        self.rejected[reason] = self.rejected.get(reason, 0) + 1
        self.bus.counters.dropped(CHUNK_KIND, f"patch_{reason}")

    # --- serving ----------------------------------------------------------------------------------------

    def _serve(self, key: str, parameters: dict[str, str]) -> Callable[[], list[bytes]] | None:
        """Pick what to serve (on the loop) and return the function that builds the chunks (on a worker)."""
        try:
            ids, requester = parse_request(parameters)
        except ValueError:
            self.counters.requests_refused += 1
            self.bus.counters.dropped(STORE_KIND, "bad_request")
            return None
        held = [(pid, data) for pid in ids if (data := self._held.get(pid)) is not None]
        if not held:
            return None
        who = str(requester) if requester is not None else "-"
        refused = self._serve_requests.take(who)
        chosen: list[tuple[PatchId, bytes]] = []
        if refused is None:
            for pid, data in held:  # in debt past the budget by one patch at most; the next query waits
                if self._serve_bytes.take(who, len(data), allow_debt=True) is not None:
                    break
                chosen.append((pid, data))
            refused = None if chosen else "budget"
        if refused is not None:
            self.counters.requests_limited += 1
            self.bus.counters.dropped(STORE_KIND, refused)
            return None
        if len(chosen) < len(held):
            self.counters.patches_withheld += len(held) - len(chosen)
            self.bus.counters.dropped(STORE_KIND, "withheld")
        self.counters.requests_served += 1
        self.counters.served += len(chosen)
        if requester is not None:
            self.served_to[requester] = self.served_to.get(requester, 0) + len(chosen)
        own_id, chunk_bytes = self.own_id, self.settings.chunk_bytes

        def build() -> list[bytes]:  # a worker thread: only the immutable bytes picked above
            return [encode(c) for pid, data in chosen for c in split_patch(own_id, pid, data, chunk_bytes)]

        return build

    # --- pulling ----------------------------------------------------------------------------------------

    async def _run(self) -> None:
        while True:
            self.reassembler.expire()
            self.scheduler.expire()
            for request in self.scheduler.next_requests(self._position()):
                task = asyncio.create_task(self._pull(request))
                self._tasks.add(task)
                task.add_done_callback(self._tasks.discard)
            await asyncio.sleep(self.settings.period_s)

    async def _pull(self, request: PullRequest) -> None:
        selector = f"{self.keys.store(request.holder)}?{request_parameters(request.ids, self.own_id)}"
        timeout = max(0.1, request.deadline - time.monotonic())
        replies = await self.bus.get(selector, STORE_KIND, timeout)
        accepting = []
        for _, payload in replies:
            try:
                chunk = decode(payload, PatchChunk, self.settings.chunk_bytes + _CHUNK_OVERHEAD)
            except DecodeError as exc:
                self.bus.counters.dropped(STORE_KIND, exc.reason)
                continue
            task = self._take(chunk, via_pull=True)
            if task is not None:
                accepting.append(task)
        await asyncio.gather(*accepting, return_exceptions=True)
        self.scheduler.on_reply(request.token, [pid for pid in request.ids if pid in self._held])

    # --- reporting --------------------------------------------------------------------------------------

    def stats(self) -> dict[str, Any]:
        pull = self.scheduler.stats
        c = self.counters
        return {
            "patches_held": len(self._held),
            "patches_requested": pull.requested,
            "patches_served": c.served,
            "patches_pushed": c.pushed,
            "received_by_push": c.received_by_push,
            "received_by_pull": c.received_by_pull,
            "duplicate_chunks": c.duplicate_chunks,
            "requests_served": c.requests_served,
            "requests_refused": c.requests_refused,
            "request_timeouts": pull.timeouts,
            "push_chunks_dropped_on_purpose": c.push_chunks_dropped,
            "rejected": dict(self.rejected),
            "assembly_dropped": dict(self.reassembler.dropped),
            "received_from": {str(k): v for k, v in sorted(self.received_from.items())},
            "served_to": {str(k): v for k, v in sorted(self.served_to.items())},
            "holdings": self._announced.to_wire(),
            "content": self.content_hashes(),
            "held_at": {str(pid): round(t, 3) for pid, t in sorted(self.held_at.items())},
            "limits": {
                "pull_claims_over_quota": sum(pull.over_quota.values()),
                "holdings_unannounced": self._digest.count - self._announced.count,
                "content_conflicts": len(self.content_conflicts),
            },
        }
