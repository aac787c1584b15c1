"""When a lingering agent may leave: `PatchSync.settled` (one function; the bus is a stand-in holding only the
key names, nothing is published or received)."""

from __future__ import annotations

from types import SimpleNamespace

from swarm.bus.keys import Keys
from swarm.bus.phase import Phase
from swarm.config import SyncSettings
from swarm.patches.digest import PatchDigest
from swarm.patches.patch import PatchId
from swarm.sync.service import PatchSync
from tests.bus.helpers import make_state


async def _sink(data: bytes, pid: object) -> None:
    return None


def _sync(wait_s: float = 8.0) -> PatchSync:
    bus = SimpleNamespace(keys=Keys("settled"))
    settings = SyncSettings(linger_wait_departed_s=wait_s)
    return PatchSync(bus, settings, 1, _sink, lambda: (0.0, 0.0, 0.0), 1 << 20)  # type: ignore[arg-type]


def _finished_state(agent_id: int):
    return make_state(agent_id, seq=1).model_copy(update={"finished": True, "phase": Phase.LANDED})


def test_settled_with_no_peers_and_with_a_finished_peer_holding_the_same() -> None:
    sync = _sync()
    assert sync.settled(now=100.0)
    sync.on_state(_finished_state(2))
    assert sync.settled(now=100.0)


def test_a_peer_still_flying_holds_the_linger() -> None:
    sync = _sync()
    sync.on_state(make_state(2, seq=1))
    assert not sync.settled(now=100.0)


def test_a_peer_that_left_out_of_step_is_waited_for_then_given_up() -> None:
    sync = _sync(wait_s=8.0)
    sync.on_state(make_state(2, seq=1))  # still flying
    sync.peer_left(2, now=100.0)
    assert not sync.settled(now=104.0)
    assert sync.settled(now=108.5)


def test_a_departed_peer_that_comes_back_is_judged_on_its_new_heartbeat() -> None:
    sync = _sync(wait_s=8.0)
    sync.on_state(make_state(2, seq=1))
    sync.peer_left(2, now=100.0)
    sync.on_state(_finished_state(2))
    assert sync.settled(now=101.0)


def test_a_peer_that_left_in_step_is_not_waited_for() -> None:
    sync = _sync(wait_s=8.0)
    sync.on_state(_finished_state(2))
    sync.peer_left(2, now=100.0)
    assert sync.settled(now=100.1)


def test_a_peer_back_by_token_only_and_gone_again_restarts_the_wait() -> None:
    sync = _sync(wait_s=8.0)
    sync.on_state(make_state(2, seq=1))
    sync.peer_left(2, now=100.0)
    sync.peer_left(2, now=106.0)  # its token came and went; no heartbeat in between
    assert not sync.settled(now=110.0)
    assert sync.settled(now=114.5)


def test_a_peer_that_left_in_step_is_waited_for_once_we_seal_a_patch_it_has_not_seen() -> None:
    # The race a lossy radio produces: both peers' tokens expire (in step), then this agent seals its last patch
    # and would otherwise find nobody to wait for and leave with a patch no one else holds.
    sync = _sync(wait_s=8.0)
    sync.on_state(_finished_state(2))
    sync.peer_left(2, now=100.0)
    sync.add_recovered(PatchId(1, 0, 7), b"last patch")
    assert not sync.settled(now=101.0)
    assert sync.settled(now=108.5)


def test_a_peer_holding_other_bytes_under_the_same_ids_is_not_in_step_and_is_counted() -> None:
    """A producer that signed two contents for one id gave each holder a different patch: the ids agree, the
    content fingerprints of their entries do not."""
    ours, theirs = _sync(), _sync()
    for seq in range(3):
        ours.add_recovered(PatchId(1, 5, seq), b"content A" if seq == 1 else b"same")
        theirs.add_recovered(PatchId(1, 5, seq), b"content B" if seq == 1 else b"same")
    assert ours.holdings.entries[0].ranges == theirs.holdings.entries[0].ranges
    assert ours.holdings.entries[0].content != theirs.holdings.entries[0].content
    ours.on_state(_finished_state(2).model_copy(update={"holdings": theirs.holdings}))
    assert not ours.settled(now=100.0)
    assert ours.stats()["limits"]["content_conflicts"] == 1
    same = _sync()
    for seq in range(3):
        same.add_recovered(PatchId(1, 5, seq), b"content A" if seq == 1 else b"same")
    ours.on_state(_finished_state(2).model_copy(update={"holdings": same.holdings}))
    assert ours.settled(now=100.0)


def test_a_peer_announcing_no_fingerprints_is_judged_on_its_ids() -> None:
    ours = _sync()
    ours.add_recovered(PatchId(1, 5, 0), b"patch")
    bare = PatchDigest.from_wire_model(ours.holdings).to_wire_model()  # as a peer of an earlier version sends it
    assert bare.entries[0].content is None
    ours.on_state(_finished_state(2).model_copy(update={"holdings": bare}))
    assert ours.settled(now=100.0)
