"""Token buckets that bound what other members may cost this one (issue 25), on a fake clock."""

from __future__ import annotations

import pytest

from swarm.bus.limits import KeyedBuckets, ReceiveLimiter, TokenBucket
from swarm.config import BusSettings, ConfigError, ReceiveLimits, load_config


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_a_bucket_refills_at_its_rate_up_to_its_burst() -> None:
    bucket = TokenBucket(rate=10.0, burst=5.0, now=0.0)
    bucket.tokens = 0.0
    assert bucket.refill(0.2) == pytest.approx(2.0)
    assert bucket.refill(10.0) == 5.0 and bucket.full
    assert bucket.refill(9.0) == 5.0  # a clock that steps back adds nothing


def test_a_key_gets_its_burst_then_its_rate() -> None:
    clock = Clock()
    buckets = KeyedBuckets(rate=10.0, burst=10.0, total_factor=4.0, max_keys=8, clock=clock)
    assert [buckets.take("a") for _ in range(10)] == [None] * 10
    assert buckets.take("a") == "rate"
    clock.now += 0.15
    assert buckets.take("a") is None and buckets.take("a") == "rate"


def test_a_flood_on_one_key_leaves_the_other_keys_their_own_rate() -> None:
    clock = Clock()
    buckets = KeyedBuckets(rate=10.0, burst=10.0, total_factor=4.0, max_keys=8, clock=clock)
    refused = [buckets.take("flood") for _ in range(1000)]
    assert refused.count(None) == 10 and set(refused[10:]) == {"rate"}
    assert [buckets.take("honest") for _ in range(10)] == [None] * 10


def test_a_flood_spread_over_many_keys_is_stopped_by_the_shared_bucket() -> None:
    clock = Clock()
    buckets = KeyedBuckets(rate=10.0, burst=10.0, total_factor=4.0, max_keys=1000, clock=clock)
    outcomes = [buckets.take(f"key{i}") for i in range(100) for _ in range(10)]
    assert outcomes.count(None) == 40  # 4 keys' worth
    assert outcomes.count("rate_total") == 960


def test_keys_beyond_the_table_share_one_bucket_and_idle_ones_are_forgotten() -> None:
    clock = Clock()
    buckets = KeyedBuckets(rate=1.0, burst=2.0, total_factor=100.0, max_keys=3, clock=clock)
    for key in ("a", "b", "c"):
        assert buckets.take(key) is None
    assert [buckets.take(f"new{i}") for i in range(4)] == [None, None, "rate", "rate"]  # the shared bucket
    assert len(buckets) == 3
    clock.now += 10  # every bucket full again: the next new key may take one of the places
    assert buckets.take("later") is None and buckets.tokens("later") == 1.0


def test_debt_lets_a_cost_known_afterwards_through_once_then_waits_until_paid() -> None:
    clock = Clock()
    cpu = KeyedBuckets(rate=0.1, burst=0.1, total_factor=10.0, max_keys=8, clock=clock)
    assert cpu.take("k", 0.0, allow_debt=True) is None
    cpu.charge("k", 0.3)  # one decode took 300 ms
    assert cpu.take("k", 0.0, allow_debt=True) == "rate"
    clock.now += 1.9
    assert cpu.take("k", 0.0, allow_debt=True) == "rate"
    clock.now += 0.2
    assert cpu.take("k", 0.0, allow_debt=True) is None


def test_the_receive_limiter_drops_for_rate_and_for_decode_cpu() -> None:
    clock = Clock()
    limiter = ReceiveLimiter(rate_hz=100.0, decode_cpu=0.01, total_keys=4, max_keys=8, clock=clock)
    assert limiter.admit("k") is None
    limiter.charge("k", 0.015)  # 15 ms: more than the key's 10 ms a second
    assert limiter.admit("k") == "decode_budget"
    assert limiter.admit("other") is None
    clock.now += 0.6
    assert limiter.admit("k") is None
    assert [limiter.admit("fast") for _ in range(101)][-1] == "rate"


def test_default_limits_are_far_above_legitimate_rates() -> None:
    limits = ReceiveLimits()
    assert limits.hz("state") >= 4 * 50  # heartbeat_hz <= 50
    assert limits.hz("patch_chunk") >= 2 * 512  # a 4 MiB patch is a burst of 512 chunks; burst = 1 s
    assert limits.hz("frontiers") >= 10 * 3  # about one report per explore.loop_s; arrivals add a few
    assert limits.decode_cpu >= 10 * 7e-3  # ten heartbeats a second with holdings at every bound (7 ms each)


def test_the_limits_are_set_in_the_bus_section() -> None:
    config = load_config(overrides={"bus.receive.default_hz": 5.0, "bus.receive.decode_cpu": 0.5})
    assert config.bus.receive.hz("targets") == 5.0 and config.bus.receive.decode_cpu == 0.5
    assert BusSettings().receive == ReceiveLimits()
    with pytest.raises(ConfigError):
        load_config(overrides={"bus.receive.decode_cpu": 0.0})
