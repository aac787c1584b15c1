"""Token buckets for what other members may cost this one (issue 25): pure, clock injected, thread-safe.

`TokenBucket` holds up to `burst` tokens and gains `rate` a second. `KeyedBuckets` gives each key (a key
expression, a requester) buckets of its own, up to `max_keys` of them (the rest share one), and one more for
all keys together, so a flood on one key is stopped by that key's bucket and a flood spread over many keys by
the shared one. `ReceiveLimiter` is what a subscription uses: a message bucket and a decode-CPU bucket per key.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

Clock = Callable[[], float]


class TokenBucket:
    """Up to `burst` tokens, refilled at `rate` a second. Not locked: its owner locks."""

    __slots__ = ("rate", "burst", "tokens", "last")

    def __init__(self, rate: float, burst: float, now: float) -> None:
        self.rate = rate
        self.burst = burst
        self.tokens = burst
        self.last = now

    def refill(self, now: float) -> float:
        if now > self.last:
            self.tokens = min(self.burst, self.tokens + (now - self.last) * self.rate)
            self.last = now
        return self.tokens

    @property
    def full(self) -> bool:
        return self.tokens >= self.burst


class KeyedBuckets:
    """A bucket per key and one for all keys; `take(key, amount)` takes from both or from neither.

    Returns None when taken, else why not: "rate" (the key's bucket) or "rate_total" (the shared one). With
    `allow_debt`, a take succeeds while the buckets hold anything and may leave them negative (for costs known
    only afterwards, or larger than a burst: the next takes wait until the debt is paid)."""

    def __init__(
        self, rate: float, burst: float, total_factor: float, max_keys: int, clock: Clock = time.monotonic
    ) -> None:
        self._rate, self._burst, self._max_keys, self._clock = rate, burst, max_keys, clock
        self._lock = threading.Lock()
        self._keys: dict[str, TokenBucket] = {}
        self._overflow = TokenBucket(rate, burst, clock())  # shared by the keys beyond max_keys
        self.total = TokenBucket(rate * total_factor, burst * total_factor, clock())

    def _bucket(self, key: str, now: float) -> TokenBucket:
        bucket = self._keys.get(key)
        if bucket is None:
            if len(self._keys) >= self._max_keys:
                for old in [k for k, b in self._keys.items() if b.refill(now) >= b.burst]:
                    del self._keys[old]  # full again: forgetting it changes nothing
            if len(self._keys) >= self._max_keys:
                return self._overflow
            bucket = self._keys[key] = TokenBucket(self._rate, self._burst, now)
        return bucket

    def take(self, key: str, amount: float = 1.0, allow_debt: bool = False) -> str | None:
        now = self._clock()
        with self._lock:
            bucket = self._bucket(key, now)
            need = 1e-9 if allow_debt else amount
            if bucket.refill(now) < need:
                return "rate"
            if self.total.refill(now) < need:
                return "rate_total"
            bucket.tokens -= amount
            self.total.tokens -= amount
            return None

    def charge(self, key: str, amount: float) -> None:
        """Take `amount` from the key's bucket and the shared one, into debt if need be."""
        now = self._clock()
        with self._lock:
            self._bucket(key, now).tokens -= amount
            self.total.refill(now)
            self.total.tokens -= amount

    def tokens(self, key: str) -> float:
        with self._lock:
            return self._bucket(key, self._clock()).refill(self._clock())

    def __len__(self) -> int:
        with self._lock:
            return len(self._keys)


class ReceiveLimiter:
    """Per key: `rate_hz` messages a second (burst: one second's worth) and `decode_cpu` of a core for decoding
    them (burst: one second's worth); `total_keys` times that for all keys together.

    `admit(key)` before decoding: None, or the reason to drop ("rate", "rate_total", "decode_budget");
    `charge(key, cpu_s)` after, with the CPU time the decode took."""

    def __init__(
        self, rate_hz: float, decode_cpu: float, total_keys: int, max_keys: int, clock: Clock = time.monotonic
    ) -> None:
        self.messages = KeyedBuckets(rate_hz, max(1.0, rate_hz), total_keys, max_keys, clock)
        self.cpu = KeyedBuckets(decode_cpu, decode_cpu, total_keys, max_keys, clock)

    def admit(self, key: str) -> str | None:
        if self.cpu.take(key, 0.0, allow_debt=True) is not None:
            return "decode_budget"
        return self.messages.take(key)

    def charge(self, key: str, cpu_s: float) -> None:
        self.cpu.charge(key, cpu_s)
