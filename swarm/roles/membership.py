"""Who is in the swarm right now, as one agent sees it.

A peer is present while its liveliness token is alive and its heartbeats keep coming; it leaves when the token
goes (Zenoh's lease, about a second after its link dies) or when it falls silent for `timeout_s`, whichever is
first. The cluster is this agent plus every present peer that still takes part in exploration; its leader is the
lowest id (Mahdoui's rule). Every agent starts as the leader of a cluster of one.

A heartbeat still on its way when the token went (sent just before the peer died, delivered just after its
token left) does not bring the peer back: after its token goes, a peer's heartbeats of the same epoch are stale
for `timeout_s`, unless its token comes back first (a healed link) or a new epoch says it restarted. Otherwise
a killed leader is taken back for the whole silence timeout, and its cluster follows it again.

A peer whose heartbeat says it is down for good (`RETIRED_PHASES` of `swarm.bus.phase`: landed, failed, or
handed to the autopilot's failsafe) stays present (it still serves and pulls patches while it lingers) but
leaves the cluster: it no longer decides, so as the lowest id it would leave its explorers waiting for
assignments that never come.

A peer whose token is alive but whose heartbeats do not arrive is one this agent has gone deaf to: its session
reaches ours (liveliness is routed) but its publications are not routed to our subscriptions. Zenoh 1.10 routers
can be left in that state after a link is re-established (measured: about half the times a router is frozen past
its lease); `deaf` names such peers so the agent can re-declare its subscriptions, which repairs the routes.

Each peer's heartbeat positions make its `track`: breadcrumbs TRACK_SPACING_M apart, the last TRACK_POINTS of
them, so every position heard is within TRACK_SPACING_M of one. A position farther from the last one heard
than TRACK_MAX_SPEED_M_S allows in the time since (plus TRACK_JUMP_SLACK_M) is not added: a peer cannot
teleport its track; the allowance grows with the time since, so a real jump (an estimator reset, heartbeats
lost) is taken a few seconds later. The leader trusts a member's reported looks only near its track
(`swarm.roles.protocol`).
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from swarm.bus.phase import RETIRED_PHASES, Phase
from swarm.config import Vec3

Role = Literal["leader", "explorer"]
MembershipEvent = Literal["joined", "left"]

TRACK_SPACING_M = 0.25  # a heartbeat position this far from the track's last point is a new breadcrumb
TRACK_POINTS = 4096  # breadcrumbs kept per peer: a kilometre of flight at TRACK_SPACING_M
TRACK_MAX_SPEED_M_S = 12.0  # no drone this runtime flies goes faster (PX4's default MPC_XY_VEL_MAX)
TRACK_JUMP_SLACK_M = 1.0  # position noise and heartbeats delivered together


@dataclass
class Peer:
    id: int
    first_seen: float
    last_heard: float
    position: Vec3 = (0.0, 0.0, 0.0)
    velocity: Vec3 = (0.0, 0.0, 0.0)
    heading_to: Vec3 | None = None
    phase: Phase | None = None  # None: heard only by its token so far
    epoch: int = 0
    token_alive: bool = False
    heartbeats: int = 0
    track: deque[Vec3] = field(default_factory=lambda: deque(maxlen=TRACK_POINTS))
    track_last: tuple[float, Vec3] | None = None  # the last position taken into the track's motion, and when
    track_jumps: int = 0  # heartbeat positions left out of the track: farther than the peer could have flown

    def follow(self, now: float, position: Vec3) -> None:
        """Take a heartbeat position into the track (see the module docstring)."""
        if not all(math.isfinite(v) for v in position):
            self.track_jumps += 1
            return
        if self.track_last is not None:
            since, last = self.track_last
            if math.dist(last, position) > TRACK_MAX_SPEED_M_S * max(now - since, 0.0) + TRACK_JUMP_SLACK_M:
                self.track_jumps += 1
                return
        self.track_last = (now, position)
        if not self.track or math.dist(self.track[-1], position) >= TRACK_SPACING_M:
            self.track.append(position)

    def track_array(self) -> np.ndarray:
        """(N, 3) the track's breadcrumbs, oldest first."""
        return np.asarray(self.track, dtype=float).reshape(-1, 3)


@dataclass
class PeerTable:
    own_id: int
    timeout_s: float = 3.0
    on_change: Callable[[MembershipEvent, int, str], None] | None = None
    clock: Callable[[], float] = time.monotonic
    peers: dict[int, Peer] = field(default_factory=dict)
    ever_seen: set[int] = field(default_factory=set)
    # liveliness and heartbeats by id, kept when a peer leaves on silence: a live token with no heartbeat
    # since is what `deaf` looks for
    tokens_since: dict[int, float] = field(default_factory=dict)
    last_heartbeat: dict[int, float] = field(default_factory=dict)
    track_jumps: int = 0  # heartbeat positions left out of a track, over every peer (the agent's summary)
    vanished: dict[int, tuple[float, int]] = field(default_factory=dict)  # token gone: when, and the epoch then
    stale_heartbeats: int = 0  # heartbeats of a peer whose token had gone, left out (see the module docstring)

    def heard(
        self,
        peer_id: int,
        position: Vec3,
        phase: Phase,
        epoch: int,
        velocity: Vec3 = (0.0, 0.0, 0.0),
        heading_to: Vec3 | None = None,
    ) -> bool:
        """A heartbeat arrived from `peer_id`; False if it was left out as stale (see the module docstring)."""
        if peer_id == self.own_id:
            return False
        if self._stale(peer_id, epoch):
            self.stale_heartbeats += 1
            return False
        peer = self._known(peer_id, "heartbeat")
        peer.last_heard = self.last_heartbeat[peer_id] = self.clock()
        if phase != Phase.CONNECTING:  # before its first telemetry a peer says (0, 0, 0): no place it was
            jumps = peer.track_jumps
            peer.follow(peer.last_heard, position)
            self.track_jumps += peer.track_jumps - jumps
        peer.position, peer.velocity, peer.heading_to = position, velocity, heading_to
        peer.phase, peer.epoch = phase, epoch
        peer.heartbeats += 1
        return True

    def _stale(self, peer_id: int, epoch: int) -> bool:
        gone = self.vanished.get(peer_id)
        if gone is None:
            return False
        at, epoch_then = gone
        if epoch > epoch_then or self.clock() - at > self.timeout_s:
            del self.vanished[peer_id]
            return False
        return True

    def token_appeared(self, peer_id: int) -> None:
        if peer_id == self.own_id:
            return
        self.tokens_since.setdefault(peer_id, self.clock())
        self.vanished.pop(peer_id, None)
        self._known(peer_id, "token").token_alive = True

    def _known(self, peer_id: int, cause: str) -> Peer:
        """The peer's entry, created (and announced as joined) on first contact."""
        peer = self.peers.get(peer_id)
        if peer is None:
            now = self.clock()
            peer = self.peers[peer_id] = Peer(peer_id, first_seen=now, last_heard=now)
            self._emit("joined", peer_id, cause)
        return peer

    def token_vanished(self, peer_id: int) -> None:
        self.tokens_since.pop(peer_id, None)
        peer = self.peers.pop(peer_id, None)
        if peer is not None:
            self.vanished[peer_id] = (self.clock(), peer.epoch)
            self._emit("left", peer_id, "token")

    def expire(self) -> list[int]:
        """Drop peers silent for longer than timeout_s; returns their ids."""
        now = self.clock()
        gone = [p.id for p in self.peers.values() if now - p.last_heard > self.timeout_s]
        for peer_id in gone:
            del self.peers[peer_id]
            self._emit("left", peer_id, "silent")
        return gone

    def deaf(self, after_s: float) -> list[int]:
        """Peers whose token has been alive, and whose heartbeats silent, for longer than `after_s` (whether or
        not they have left on silence since)."""
        now = self.clock()
        return sorted(
            k for k, since in self.tokens_since.items() if now - max(since, self.last_heartbeat.get(k, since)) > after_s
        )

    @property
    def cluster(self) -> list[int]:
        """This agent and the present peers still exploring (a peer heard only by its token counts: it is
        starting)."""
        return sorted({self.own_id, *(p.id for p in self.peers.values() if p.phase not in RETIRED_PHASES)})

    @property
    def leader(self) -> int:
        return min(self.cluster)

    @property
    def role(self) -> Role:
        return "leader" if self.leader == self.own_id else "explorer"

    def _emit(self, event: MembershipEvent, peer_id: int, cause: str) -> None:
        if event == "joined":
            self.ever_seen.add(peer_id)
        if self.on_change is not None:
            self.on_change(event, peer_id, cause)
