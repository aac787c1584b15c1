"""Pull scheduling: which missing patches to ask for, and from whom (design §2.3.5).

An agent compares its own digest with the digests its peers put in their heartbeats and asks for what it
misses from the nearest alive holder, which is not necessarily the producer (a relay that holds a copy is
asked if it is nearer). `PullScheduler` is pure and synchronous: no I/O, no threads, no randomness, time from
an injected clock. The agent feeds it heartbeats (`update_peer`), departures (`remove_peer`), what it holds
(`set_held` / `note_received`) and replies (`on_reply`), and sends what `next_requests` returns; it calls
`expire` periodically. Jitter, if wanted, is the caller's.

State machine of one patch id (only ids some alive peer lists and the agent lacks are tracked):

    missing ──next_requests──▶ requested(holder, token, deadline)
       ▲                          │          │
       │                          │          └─ note_received / on_reply lists it ─▶ received (held)
       │                          ▼
       └── back-off over ──── failed(holder, back-off until t)
                               (expire past the deadline, on_reply without it, or remove_peer(holder))

- A *missing* id is requested only once it has been tracked for ``grace_s`` (a push may be bringing it), from
  its holder: the alive peer (not this agent) whose digest lists it, nearest
  by Euclidean distance between the last heartbeat position and ``own_position``, ties to the lower peer id,
  skipping holders the id is backing off from. With no such holder the id waits (it is never requested from
  a peer that does not list it).
- A failure puts the (id, holder) pair on back-off: ``backoff_initial_s`` the first time, doubled on every
  further failure with that holder, capped at ``backoff_max_s``. Meanwhile the id is missing again and the
  next request goes to the next-nearest holder not backing off; once the back-off is over the first holder
  may be chosen again (its back-off level is kept, so a repeated failure waits twice as long). Receiving the
  id forgets all its back-offs.
- A removed peer's in-flight ids fail over at once (they count as failures in the stats) and its back-offs
  are forgotten: it is no longer a holder, and comes back fresh with its next heartbeat.

Fairness: a peer's digest is a claim, and a hostile or broken peer may claim ids nobody holds (seqs 0 to 2**63
of a real producer) to crowd real patches out. So every peer's claims are tracked under a quota of their own:
of ``max_missing_tracked``, each alive peer gets an equal share, filled round robin across the producers its
digest lists and, within a producer, across its epochs (`PatchDigest.missing_fairly`); the tracked ids are the
union of the peers' shares, and an id's holders are every peer whose digest lists it. A claim beyond its quota
is cut and counted (`PullStats.over_quota`, once per digest). Requests are handed out the same way: each
holder's ids in round-robin order (`fair_order`), and the free request slots round robin across the holders,
the one with the fewest requests in flight first (ties to the one whose next id is oldest). So a holder that
never answers holds at most its share of the slots, its ids fail and back off, and every other holder's ids are
still asked for; an id it claims and an honest peer holds fails over to that peer by the back-off above.

Bounds: at most ``max_in_flight`` requests in flight of at most ``batch_size`` ids each; at most
``max_missing_tracked`` missing ids are tracked (a peer digest listing 10^9 ids costs its range count plus its
share, through `PatchDigest.missing_fairly`); back-offs are kept only for tracked ids and known peers.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

from swarm.config import SyncSettings, Vec3
from swarm.patches.digest import PatchDigest, fair_order
from swarm.patches.patch import PatchId


@dataclass(frozen=True)
class PullRequest:
    """Ask `holder` for `ids`; the reply (or its absence by `deadline`) is matched by `token`."""

    holder: int
    ids: tuple[PatchId, ...]
    token: int
    deadline: float


@dataclass(frozen=True)
class PullStats:
    requested: int  # ids requested (an id asked twice counts twice)
    received: int  # ids newly held through note_received / on_reply
    timeouts: int  # requests expired past their deadline
    failures: dict[int, int]  # holder -> ids that failed with it (timeout, missing from a reply, removal)
    in_flight: int  # requests in flight now
    over_quota: dict[int, int]  # peer -> its digests whose missing ids were cut at its share of the tracking


@dataclass
class _InFlight:
    holder: int
    pending: set[PatchId]
    token: int
    deadline: float


@dataclass
class _Backoff:
    until: float
    duration: float


@dataclass
class _Peer:
    position: Vec3
    digest: PatchDigest


@dataclass
class _Counters:
    requested: int = 0
    received: int = 0
    timeouts: int = 0
    failures: dict[int, int] = field(default_factory=dict)
    over_quota: dict[int, int] = field(default_factory=dict)


class PullScheduler:
    """Decides which missing patches to request from which peer; see the module docstring."""

    def __init__(
        self, own_id: int, settings: SyncSettings | None = None, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.own_id = own_id
        self.settings = settings or SyncSettings()
        self._clock = clock
        self._peers: dict[int, _Peer] = {}
        self._held = PatchDigest()
        self._holders: dict[PatchId, set[int]] = {}  # tracked missing id -> alive peers listing it
        self._first_seen: dict[PatchId, float] = {}  # tracked missing id -> when it was first tracked
        self._dirty = False  # _holders must be recomputed
        self._in_flight: dict[int, _InFlight] = {}  # token -> request
        self._token_of: dict[PatchId, int] = {}  # in-flight id -> token
        self._backoff: dict[tuple[PatchId, int], _Backoff] = {}
        self._over_quota_digest: dict[int, PatchDigest] = {}  # peer -> its last digest counted over quota
        self._next_token = 1
        self._counters = _Counters()

    # --- inputs -----------------------------------------------------------------------------------------

    def update_peer(self, peer_id: int, position: Iterable[float], digest: PatchDigest) -> None:
        """From a heartbeat: the peer is alive, at `position`, and holds `digest`. Its own id is ignored."""
        if peer_id == self.own_id:
            return
        x, y, z = (float(c) for c in position)
        previous = self._peers.get(peer_id)
        if previous is None or previous.digest != digest:
            self._dirty = True
        self._peers[peer_id] = _Peer((x, y, z), digest)

    def remove_peer(self, peer_id: int) -> None:
        """The peer left or is unreachable: its in-flight ids fail over at once, its back-offs are forgotten."""
        if self._peers.pop(peer_id, None) is not None:
            self._dirty = True
        for request in [r for r in self._in_flight.values() if r.holder == peer_id]:
            self._close(request)
            self._count_failures(peer_id, len(request.pending))
        for key in [k for k in self._backoff if k[1] == peer_id]:
            del self._backoff[key]

    def set_held(self, held: PatchDigest | set[PatchId]) -> None:
        """What this agent holds now (replaces the previous); held ids leave the in-flight requests."""
        self._held = held if isinstance(held, PatchDigest) else PatchDigest.of(held)
        self._dirty = True
        for pid in [p for p in self._token_of if p in self._held]:
            self._forget(pid)

    def note_received(self, pid: PatchId) -> None:
        """A patch arrived (push or reply) and was accepted: no longer missing, no longer in flight."""
        if pid not in self._held:
            self._held = self._held.union((pid,))
            self._counters.received += 1
            self._dirty = True
        self._forget(pid)

    def on_reply(self, token: int, received: Iterable[PatchId]) -> None:
        """The reply to request `token` brought `received`; the request's other ids failed with its holder.

        A late reply (after `expire`) or an unknown token still marks `received` as held.
        """
        request = self._in_flight.get(token)
        for pid in received:
            self.note_received(pid)
        if request is None or self._in_flight.get(token) is not request:
            return
        self._close(request)
        now = self._clock()
        for pid in sorted(request.pending):
            self._fail(pid, request.holder, now)

    # --- outputs ----------------------------------------------------------------------------------------

    def next_requests(self, own_position: Iterable[float]) -> list[PullRequest]:
        """The requests to send now (marked in flight): missing ids not in flight and not backing off, grouped
        per chosen holder (the nearest) into batches of at most `batch_size` in round-robin order across
        producers and epochs, the free slots of `max_in_flight` handed out round robin across the holders."""
        slots = self.settings.max_in_flight - len(self._in_flight)
        if slots <= 0:
            return []
        self._refresh()
        now = self._clock()
        here = tuple(float(c) for c in own_position)
        distance = {pid: _distance(here, peer.position) for pid, peer in self._peers.items()}
        wanted: dict[int, list[PatchId]] = {}
        young = now - self.settings.grace_s
        for pid in self._holders:
            if pid in self._token_of or self._first_seen.get(pid, now) > young:
                continue
            holder = self._choose(pid, self._holders[pid], distance, now)
            if holder is not None:
                wanted.setdefault(holder, []).append(pid)
        size = self.settings.batch_size
        queues: dict[int, list[list[PatchId]]] = {}
        for holder, ids in wanted.items():
            ordered = fair_order(ids)
            queues[holder] = [ordered[i : i + size] for i in range(0, len(ordered), size)]
        busy = {holder: 0 for holder in queues}
        for pending in self._in_flight.values():
            if pending.holder in busy:
                busy[pending.holder] += 1
        batches: list[tuple[int, list[PatchId]]] = []
        while slots > 0 and queues:
            holder = min(queues, key=lambda h: (busy[h], min(queues[h][0]), h))
            batches.append((holder, queues[holder].pop(0)))
            busy[holder] += 1
            slots -= 1
            if not queues[holder]:
                del queues[holder]
        requests = []
        for holder, ids in batches:
            request = PullRequest(holder, tuple(ids), self._next_token, now + self.settings.request_timeout_s)
            self._next_token += 1
            self._in_flight[request.token] = _InFlight(holder, set(ids), request.token, request.deadline)
            for pid in ids:
                self._token_of[pid] = request.token
            self._counters.requested += len(ids)
            requests.append(request)
        return requests

    def expire(self) -> list[PullRequest]:
        """Requests past their deadline, each with the ids still pending: they fail with their holder."""
        now = self._clock()
        expired = []
        for request in sorted(self._in_flight.values(), key=lambda r: r.token):
            if now < request.deadline:
                continue
            self._close(request)
            self._counters.timeouts += 1
            ids = tuple(sorted(request.pending))
            for pid in ids:
                self._fail(pid, request.holder, now)
            expired.append(PullRequest(request.holder, ids, request.token, request.deadline))
        return expired

    # --- introspection ----------------------------------------------------------------------------------

    @property
    def stats(self) -> PullStats:
        c = self._counters
        return PullStats(
            c.requested, c.received, c.timeouts, dict(c.failures), len(self._in_flight), dict(c.over_quota)
        )

    def missing(self) -> list[PatchId]:
        """The tracked missing ids (in flight or not), sorted."""
        self._refresh()
        return sorted(self._holders)

    def missing_from(self, peers: Iterable[int]) -> int:
        """How many tracked missing ids one of `peers` lists (patches of theirs this map does not hold yet)."""
        self._refresh()
        wanted = set(peers)
        return sum(1 for holders in self._holders.values() if holders & wanted)

    def in_flight(self) -> dict[PatchId, int]:
        """In-flight id -> holder asked."""
        return {pid: self._in_flight[token].holder for pid, token in self._token_of.items()}

    def backoff_until(self, pid: PatchId, holder: int) -> float | None:
        """When the (id, holder) back-off ends, or None if the pair never failed (or was forgotten)."""
        entry = self._backoff.get((pid, holder))
        return None if entry is None else entry.until

    # --- internals --------------------------------------------------------------------------------------

    def _refresh(self) -> None:
        """Recompute the tracked missing ids and their holders: each peer's share of max_missing_tracked, filled
        fairly from its digest; an id's holders are every peer whose digest lists it."""
        if not self._dirty:
            return
        quota = max(1, self.settings.max_missing_tracked // max(1, len(self._peers)))
        tracked: set[PatchId] = set()
        for peer_id, peer in sorted(self._peers.items()):
            share = peer.digest.missing_fairly(self._held, limit=quota + 1)
            if len(share) > quota:
                share = share[:quota]
                if self._over_quota_digest.get(peer_id) != peer.digest:
                    self._over_quota_digest[peer_id] = peer.digest
                    self._counters.over_quota[peer_id] = self._counters.over_quota.get(peer_id, 0) + 1
            tracked.update(share)
        peers = sorted(self._peers.items())
        self._holders = {pid: {p for p, peer in peers if pid in peer.digest} for pid in sorted(tracked)}
        now = self._clock()
        self._first_seen = {pid: self._first_seen.get(pid, now) for pid in self._holders}
        self._dirty = False
        self._backoff = {k: v for k, v in self._backoff.items() if k[0] in self._holders and k[1] in self._peers}
        self._over_quota_digest = {p: d for p, d in self._over_quota_digest.items() if p in self._peers}

    def _choose(self, pid: PatchId, holders: set[int], distance: dict[int, float], now: float) -> int | None:
        best: tuple[float, int] | None = None
        for holder in holders:
            if holder not in self._peers:
                continue
            backoff = self._backoff.get((pid, holder))
            if backoff is not None and backoff.until > now:
                continue
            key = (distance[holder], holder)
            if best is None or key < best:
                best = key
        return None if best is None else best[1]

    def _fail(self, pid: PatchId, holder: int, now: float) -> None:
        self._count_failures(holder, 1)
        previous = self._backoff.get((pid, holder))
        s = self.settings
        duration = s.backoff_initial_s if previous is None else min(previous.duration * 2, s.backoff_max_s)
        self._backoff[(pid, holder)] = _Backoff(now + duration, duration)

    def _count_failures(self, holder: int, n: int) -> None:
        if n:
            self._counters.failures[holder] = self._counters.failures.get(holder, 0) + n

    def _close(self, request: _InFlight) -> None:
        del self._in_flight[request.token]
        for pid in request.pending:
            if self._token_of.get(pid) == request.token:
                del self._token_of[pid]

    def _forget(self, pid: PatchId) -> None:
        """`pid` is held: out of the missing set, out of its request (closed once empty), back-offs dropped."""
        self._holders.pop(pid, None)
        self._first_seen.pop(pid, None)
        token = self._token_of.pop(pid, None)
        if token is not None:
            request = self._in_flight[token]
            request.pending.discard(pid)
            if not request.pending:
                del self._in_flight[token]
        for key in [k for k in self._backoff if k[0] == pid]:
            del self._backoff[key]


def _distance(a: tuple[float, ...], b: Vec3) -> float:
    d = math.dist(a, b)
    return d if math.isfinite(d) else math.inf
