"""What an agent announces when it holds more than a heartbeat's digest may list: `PatchSync.holdings` and
`stats` (the bus is a stand-in holding only the key names, nothing is published or received)."""

from __future__ import annotations

from swarm.bus.holdings import MAX_EPOCHS_PER_PRODUCER
from swarm.patches.digest import PatchDigest
from swarm.patches.patch import PatchId
from tests.sync.test_settled import _finished_state, _sync

START_MS = 1_795_340_000_000  # a process epoch: its start time in ms


def test_seventeen_restarts_of_one_producer_are_all_announced_and_stats_do_not_raise() -> None:
    sync = _sync()
    for restart in range(17):
        sync.add_recovered(PatchId(1, START_MS + 60_000 * restart, 0), b"patch")
    announced = PatchDigest.from_wire_model(sync.holdings)
    assert announced == PatchDigest.of(sync.held_ids()) and len(announced.ranges) == 17
    stats = sync.stats()
    assert stats["limits"] == {"pull_claims_over_quota": 0, "holdings_unannounced": 0, "content_conflicts": 0}
    assert PatchDigest.from_wire(stats["holdings"]) == announced


def test_beyond_the_epoch_bound_the_newest_epochs_are_announced_and_the_rest_counted() -> None:
    sync = _sync()
    epochs = [START_MS + 60_000 * k for k in range(MAX_EPOCHS_PER_PRODUCER + 6)]
    for epoch in epochs:
        sync.add_recovered(PatchId(1, epoch, 0), b"patch")
        sync.add_recovered(PatchId(1, epoch, 1), b"patch")
    announced = PatchDigest.from_wire_model(sync.holdings)
    assert sorted(e for _, e in announced.ranges) == epochs[6:]  # not frozen: the newest epoch is in it
    assert set(announced.ids()) <= set(sync.held_ids())  # never a patch it does not hold
    stats = sync.stats()  # does not raise
    assert stats["limits"]["holdings_unannounced"] == 12
    assert PatchDigest.from_wire(stats["holdings"]) == announced
    sync.add_recovered(PatchId(1, epochs[-1], 2), b"patch")  # the announcement keeps following what is held
    assert PatchId(1, epochs[-1], 2) in PatchDigest.from_wire_model(sync.holdings)


def test_a_peer_holding_the_same_beyond_the_bound_is_in_step() -> None:
    sync = _sync()
    for k in range(MAX_EPOCHS_PER_PRODUCER + 3):
        sync.add_recovered(PatchId(1, START_MS + k, 0), b"patch")
    peer = _finished_state(2).model_copy(update={"holdings": sync.holdings})
    sync.on_state(peer)
    assert sync.settled(now=100.0)


def test_a_heartbeat_claiming_2_to_the_63_patches_is_counted_in_the_stats() -> None:
    sync = _sync()
    claim = PatchDigest({(2, 0): [(0, 2**63 - 1)]}).to_wire_model()
    sync.on_state(_finished_state(2).model_copy(update={"holdings": claim}))
    tracked = sync.scheduler.missing()  # what the pull loop's next pass looks at
    assert len(tracked) == sync.settings.max_missing_tracked  # its share: it is the only peer
    assert sync.stats()["limits"]["pull_claims_over_quota"] == 1
