from __future__ import annotations

import time

import pytest

from swarm.config import SyncSettings
from swarm.patches.digest import PatchDigest
from swarm.patches.patch import PatchId
from swarm.patches.pull import PullScheduler

HERE = (0.0, 0.0, 0.0)


class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def pid(seq: int, producer: int = 9, epoch: int = 0) -> PatchId:
    return PatchId(producer, epoch, seq)


def digest(*seqs: int, producer: int = 9) -> PatchDigest:
    return PatchDigest.of(pid(s, producer) for s in seqs)


def make(**settings: object) -> tuple[PullScheduler, Clock]:
    clock = Clock()
    return PullScheduler(1, SyncSettings.model_validate({"grace_s": 0.0} | settings), clock), clock


def asked(requests: list) -> dict[PatchId, int]:
    return {i: r.holder for r in requests for i in r.ids}


def test_nearest_holder_ties_to_lower_id_never_self_never_a_peer_lacking_the_id() -> None:
    s, _ = make(batch_size=1, max_in_flight=10)
    s.update_peer(1, (0.1, 0, 0), digest(0, 1, 2, 3))  # itself: ignored
    s.update_peer(5, (3, 0, 0), digest(0, 1, 2))
    s.update_peer(4, (0, 3, 0), digest(0, 1))  # same distance as 5, lower id
    s.update_peer(2, (0.5, 0, 0), digest(2))  # nearest, but holds only seq 2
    s.update_peer(3, (0.2, 0, 0), PatchDigest())  # nearest, holds nothing
    got = asked(s.next_requests(HERE))
    assert got == {pid(0): 4, pid(1): 4, pid(2): 2}  # seq 3: only listed by itself


def test_relay_nearer_than_the_producer_is_asked() -> None:
    s, _ = make()
    s.update_peer(9, (100, 0, 0), digest(0, 1))  # the producer, far away
    s.update_peer(7, (2, 0, 0), digest(0, 1))  # a relay holding copies
    [request] = s.next_requests((1, 0, 0))
    assert request.holder == 7 and request.ids == (pid(0), pid(1))


def test_batching_and_in_flight_bound() -> None:
    s, clock = make(batch_size=3, max_in_flight=2, request_timeout_s=2.0)
    s.update_peer(2, (1, 0, 0), digest(*range(10)))
    s.update_peer(3, (5, 0, 0), digest(100, 101))
    first = s.next_requests(HERE)
    assert [(r.holder, r.ids) for r in first] == [(2, (pid(0), pid(1), pid(2))), (3, (pid(100), pid(101)))]
    assert all(r.deadline == clock.t + 2.0 for r in first) and len({r.token for r in first}) == 2
    assert s.next_requests(HERE) == [] and s.stats.in_flight == 2
    s.on_reply(first[0].token, first[0].ids)
    [third] = s.next_requests(HERE)
    assert third.holder == 2 and third.ids == (pid(3), pid(4), pid(5))
    assert s.stats.in_flight == 2 and s.stats.requested == 8 and s.stats.received == 3


def test_slots_go_round_robin_across_holders_each_holders_ids_oldest_first_in_full_batches() -> None:
    s, _ = make(batch_size=2, max_in_flight=2)
    s.update_peer(2, (1, 0, 0), digest(0, 2, 4))
    s.update_peer(3, (1, 0, 0), digest(1, 3, 5, producer=8))
    reqs = s.next_requests(HERE)  # (oldest first alone gave both slots to holder 3)
    assert [(r.holder, r.ids) for r in reqs] == [(3, (pid(1, 8), pid(3, 8))), (2, (pid(0), pid(2)))]
    s2, _ = make(batch_size=3, max_in_flight=2)
    s2.update_peer(2, (1, 0, 0), digest(1, 3, 5, 7))
    s2.update_peer(3, (1, 0, 0), digest(0, 2, 4, producer=8))  # older ids
    reqs = s2.next_requests(HERE)
    assert [(r.holder, r.ids) for r in reqs] == [(3, (pid(0, 8), pid(2, 8), pid(4, 8))), (2, (pid(1), pid(3), pid(5)))]


def test_one_holders_ids_go_round_robin_across_producers_and_epochs() -> None:
    s, _ = make(batch_size=4, max_in_flight=1)
    s.update_peer(2, (1, 0, 0), PatchDigest({(2, 0): [(0, 9)], (2, 5): [(0, 9)], (9, 0): [(0, 9)]}))
    [r] = s.next_requests(HERE)
    assert r.ids == (PatchId(2, 0, 0), PatchId(9, 0, 0), PatchId(2, 5, 0), PatchId(9, 0, 1))


def test_timeout_fails_over_to_the_next_nearest_then_backs_off_doubling_to_the_max() -> None:
    s, clock = make(request_timeout_s=2.0, backoff_initial_s=0.5, backoff_max_s=2.0)
    s.update_peer(2, (1, 0, 0), digest(0))
    s.update_peer(3, (2, 0, 0), digest(0))
    [r] = s.next_requests(HERE)
    assert r.holder == 2
    clock.t += 1.9
    assert s.expire() == []
    clock.t += 0.1
    [expired] = s.expire()
    assert expired.token == r.token and expired.ids == (pid(0),)
    assert s.stats.timeouts == 1 and s.stats.failures == {2: 1} and s.stats.in_flight == 0
    assert s.backoff_until(pid(0), 2) == clock.t + 0.5
    [r] = s.next_requests(HERE)
    assert r.holder == 3  # next-nearest
    clock.t += 0.4  # 3 fails early (a Nack): both backing off, nothing to ask
    s.on_reply(r.token, [])
    assert s.next_requests(HERE) == []
    clock.t = s.backoff_until(pid(0), 2)  # holder 2's back-off ends: the nearest is tried again...
    s.remove_peer(3)  # (3's back-off is forgotten with it)
    durations = []  # ...and the back-off doubles on each further failure, up to the max
    for _ in range(4):
        [r] = s.next_requests(HERE)
        assert r.holder == 2
        clock.t = r.deadline
        s.expire()
        durations.append(s.backoff_until(pid(0), 2) - clock.t)
        assert s.next_requests(HERE) == []  # still backing off
        clock.t = s.backoff_until(pid(0), 2)
    assert durations == [1.0, 2.0, 2.0, 2.0]
    assert s.stats.failures == {2: 5, 3: 1}


def test_after_back_off_the_first_holder_is_tried_again() -> None:
    s, clock = make(request_timeout_s=1.0, backoff_initial_s=3.0, backoff_max_s=8.0)
    s.update_peer(2, (1, 0, 0), digest(0))
    s.update_peer(3, (2, 0, 0), digest(0))
    [r] = s.next_requests(HERE)
    clock.t = r.deadline
    s.expire()
    [r] = s.next_requests(HERE)
    assert r.holder == 3
    s.on_reply(r.token, [])  # a Nack: fails with 3
    assert s.stats.failures == {2: 1, 3: 1}
    clock.t = s.backoff_until(pid(0), 2)
    [r] = s.next_requests(HERE)
    assert r.holder == 2


def test_remove_peer_fails_over_its_in_flight_ids_at_once() -> None:
    s, _ = make(batch_size=4)
    s.update_peer(2, (1, 0, 0), digest(0, 1))
    s.update_peer(3, (9, 0, 0), digest(0, 1))
    [r] = s.next_requests(HERE)
    assert r.holder == 2
    s.remove_peer(2)
    assert s.stats.in_flight == 0 and s.stats.failures == {2: 2}
    [r2] = s.next_requests(HERE)  # no waiting for the deadline
    assert r2.holder == 3 and r2.ids == r.ids
    s.on_reply(r.token, [])  # a late reply from the removed peer is ignored
    assert s.stats.in_flight == 1


def test_note_received_and_replies_remove_ids_partial_replies_fail_the_rest() -> None:
    s, clock = make(batch_size=3, max_in_flight=1, backoff_initial_s=1.0)
    s.update_peer(2, (1, 0, 0), digest(0, 1, 2, 3))
    s.update_peer(3, (5, 0, 0), digest(0, 1, 2, 3))
    [r] = s.next_requests(HERE)
    assert r.ids == (pid(0), pid(1), pid(2))
    s.note_received(pid(0))  # a push overtook the request
    s.note_received(pid(3))  # not requested yet: no longer missing
    assert s.missing() == [pid(1), pid(2)] and set(s.in_flight()) == {pid(1), pid(2)}
    s.on_reply(r.token, [pid(1)])  # pid(2) was not in the reply
    assert s.missing() == [pid(2)] and s.in_flight() == {} and s.stats.in_flight == 0
    assert s.stats.failures == {2: 1} and s.stats.received == 3
    assert s.backoff_until(pid(2), 2) == clock.t + 1.0
    [r] = s.next_requests(HERE)
    assert r.holder == 3 and r.ids == (pid(2),)
    s.note_received(pid(2))  # the last id of a request closes it
    assert s.stats.in_flight == 0 and s.missing() == [] and s.backoff_until(pid(2), 2) is None
    s.on_reply(r.token, [pid(2)])  # a reply after the push: harmless
    assert s.stats.received == 4 and s.next_requests(HERE) == []


def test_set_held_cancels_in_flight_ids() -> None:
    s, _ = make()
    s.update_peer(2, (1, 0, 0), digest(0, 1))
    [r] = s.next_requests(HERE)
    s.set_held({pid(0), pid(1)})
    assert s.stats.in_flight == 0 and s.missing() == []
    s.set_held(digest(0))
    assert s.missing() == [pid(1)]


def test_nothing_missing_nothing_requested_and_ids_nobody_holds_are_not_requested() -> None:
    s, _ = make()
    assert s.next_requests(HERE) == []
    s.set_held(digest(0, 1, 2))
    s.update_peer(2, (1, 0, 0), digest(0, 1, 2))
    assert s.next_requests(HERE) == []
    s.update_peer(2, (1, 0, 0), digest(0, 1, 2, 5))
    s.update_peer(3, (1, 0, 0), digest(6))
    s.remove_peer(3)  # the only holder of 6 left
    assert asked(s.next_requests(HERE)) == {pid(5): 2}
    assert s.stats.requested == 1


def test_hostile_digest_listing_a_billion_ids_is_tracked_bounded_and_fairly() -> None:
    s, _ = make(max_missing_tracked=50, batch_size=8, max_in_flight=4)
    huge = PatchDigest({(9, 0): [(0, 10**9 - 1)], (2, 0): [(0, 10**9 - 1)]})
    s.update_peer(2, (1, 0, 0), huge)
    s.update_peer(3, (2, 0, 0), PatchDigest({(2, 0): [(5, 6)]}))
    start = time.perf_counter()
    reqs = s.next_requests(HERE)
    assert time.perf_counter() - start < 1.0
    missing = s.missing()  # peer 2's share, half of the 50 (2 peers), round robin across its two producers
    assert missing == [PatchId(2, 0, i) for i in range(13)] + [PatchId(9, 0, i) for i in range(12)]
    assert s.stats.over_quota == {2: 1}  # peer 3's claim fits its share
    assert sum(len(r.ids) for r in reqs) == 25 and all(r.holder == 2 for r in reqs)
    for pid_ in missing[:10]:
        s.note_received(pid_)
    assert s.missing() == [PatchId(2, 0, i) for i in range(10, 23)] + [PatchId(9, 0, i) for i in range(12)]
    assert s.stats.over_quota == {2: 1}  # the same digest is counted once


def test_settings_are_validated() -> None:
    for bad in (
        {"max_in_flight": 0},
        {"max_missing_tracked": 0},
        {"request_timeout_s": float("nan")},
        {"backoff_max_s": 0.1},
    ):
        with pytest.raises(ValueError):
            SyncSettings.model_validate(bad)


def test_grace_delays_the_first_request_of_a_newly_advertised_id() -> None:
    now = [0.0]
    scheduler = PullScheduler(1, SyncSettings(grace_s=1.0), clock=lambda: now[0])
    scheduler.update_peer(2, (0.0, 0.0, 0.0), PatchDigest.of([PatchId(2, 0, 0)]))
    assert scheduler.next_requests((0.0, 0.0, 0.0)) == []
    now[0] = 0.5
    assert scheduler.next_requests((0.0, 0.0, 0.0)) == []
    now[0] = 1.0
    [request] = scheduler.next_requests((0.0, 0.0, 0.0))
    assert request.ids == (PatchId(2, 0, 0),) and request.holder == 2


def _serve_honestly(s: PullScheduler, clock: Clock, holds: dict[int, PatchDigest], seconds: float) -> None:
    """Run the pull loop for `seconds`: every holder in `holds` answers at once with what it really holds, any
    other peer never answers (its requests time out)."""
    end = clock.t + seconds
    while clock.t < end:
        s.expire()
        for request in s.next_requests(HERE):
            if request.holder in holds:
                s.on_reply(request.token, [i for i in request.ids if i in holds[request.holder]])
        clock.t += 0.25


def test_a_digest_claiming_2_to_the_63_ids_of_real_producers_does_not_crowd_out_real_patches() -> None:
    s, clock = make()  # the defaults: 4096 ids tracked, 4 requests of 4 ids in flight, 3 s timeout
    real_9 = PatchDigest({(9, 1795340000000): [(0, 9)]})
    real_3 = PatchDigest({(3, 1795340000000): [(0, 4)]})
    everything = PatchDigest({(2, 0): [(0, 2**63 - 1)], (9, 1795340000000): [(0, 2**63 - 1)]})
    s.update_peer(5, (0.5, 0, 0), everything)  # the nearest peer claims seqs 0 to 2**63 of producers 2 and 9
    s.update_peer(9, (5, 0, 0), real_9)
    s.update_peer(3, (6, 0, 0), real_3)
    tracked = s.missing()
    assert len(tracked) <= 4096 and set(real_3.ids()) <= set(tracked) and set(real_9.ids()) <= set(tracked)
    _serve_honestly(s, clock, {9: real_9, 3: real_3}, seconds=30.0)
    assert s.stats.received == 15  # every real patch, from the honest holders
    assert s.stats.over_quota == {5: 1}  # the claim was cut at peer 5's quota (once: its digest never changed)
    assert s.stats.failures.get(5, 0) > 0 and set(s.stats.failures) == {5}


def test_missing_from_counts_the_ids_the_given_peers_list_that_are_not_held() -> None:
    s, _ = make()
    s.update_peer(2, (1, 0, 0), digest(0, 1, 2))
    s.update_peer(3, (2, 0, 0), digest(2, 3, producer=8))
    s.set_held({pid(0)})
    assert s.missing_from([2]) == 2  # seqs 1 and 2 of producer 9
    assert s.missing_from([3]) == 2
    assert s.missing_from([2, 3]) == 4 and s.missing_from([]) == 0 and s.missing_from([7]) == 0
    s.note_received(pid(1))
    assert s.missing_from([2]) == 1
