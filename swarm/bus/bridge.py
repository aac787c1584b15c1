"""The asyncio face of the bus: validated messages in and out of a Zenoh session.

Zenoh calls back on its own threads. Every callback here only counts, decodes and hands the result to the
event loop with `call_soon_threadsafe`; it never blocks and never lets an exception into Zenoh. Before decoding,
each sample passes its key's token buckets (`swarm.bus.limits.ReceiveLimiter`, settings `bus.receive`):
messages a second, and the CPU time its key's earlier messages took to decode; a sample over either is dropped
and counted ("rate", "rate_total", "decode_budget") at the cost of a dictionary look-up. Decoding holds the GIL,
so without them a member sending costly messages fast starves the event loop that flies the drone. Handlers,
liveliness callbacks included, run on the loop thread; an exception in a handler is logged and counted.

Always close the bus (`await bus.close()`, or ``async with await AsyncBus.open(...) as bus``). A bus still
open when the interpreter exits is closed by an exit hook, because Zenoh otherwise hangs the exit.

Publishing never blocks the loop:
- best-effort (heartbeats, default): BEST_EFFORT + CongestionControl.DROP + express, put directly on the
  calling thread; with a UDP link available it travels over UDP. A full queue drops the message, and the next
  heartbeat replaces it.
- reliable: RELIABLE + CongestionControl.DROP, put from one writer thread (FIFO, so order is kept) behind a
  bounded backlog. RELIABLE makes the link retransmit, so nothing queued in Zenoh is lost while the session
  is up. DROP rather than BLOCK because a BLOCK put stalls the caller for as long as the slowest peer's queue is
  full, holds up traffic to every other peer, and after 5 s makes Zenoh close the transport (measured: sessions
  flap at 30 % loss). With DROP, only a congested peer loses messages, and the protocols above (digests, pull
  with retry) repair the gaps. The writer thread keeps even DROP's short waits (up to 50 ms for a fragmented
  large message) off the loop. When the backlog is full, the message is dropped and counted as "backlog".

Queries (`declare_queryable` / `get`) carry raw bytes, not `WireMessage`s, so the caller picks the encoding
(a patch served as its wire bytes, a digest as an encoded message). Both sides count under a caller-given
`kind`: the querier counts its selector as sent and every ok reply as received; the queryable counts each
query (its selector) as received and every reply it serves as sent. A session never answers its own queries:
queryables are declared with ``allowed_origin=REMOTE``, as subscribers are, so a drone asking "who holds
patch X" is not answered by itself. Zenoh 1.10 ignores (and deprecates) a congestion control given to a
reply: replies follow the query's QoS, and `get` sends with CongestionControl.DROP as puts do. A query or
reply lost to congestion makes the querier time out; the sync protocol retries.

`refresh_routes` undeclares every subscriber and queryable and declares it again, for a session that has gone
deaf to a peer whose token it still sees (`swarm.roles.membership`): the new declarations make every router
recompute its routes to us. The old one must go first: a session declares a key expression to the network once,
however many subscribers it has on it, so a second subscriber declared alongside changes no route.
"""

from __future__ import annotations

import asyncio
import atexit
import collections
import inspect
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TypeVar

import zenoh

from swarm.bus.codec import DEFAULT_MAX_BYTES, DecodeError, WireMessage, decode, encode
from swarm.bus.counters import TrafficCounters
from swarm.bus.keys import Keys
from swarm.bus.limits import ReceiveLimiter
from swarm.bus.session import open_session, zenoh_error_text
from swarm.config import BusSettings, ReceiveLimits
from swarm.errors import BusError

log = logging.getLogger(__name__)

T = TypeVar("T", bound=WireMessage)
R = TypeVar("R")
ReplyBuilder = Callable[[], list[bytes]]
QueryHandler = Callable[[str, dict[str, str]], "bytes | list[bytes] | ReplyBuilder | None"]

CLOSE_TIMEOUT_S = 5.0
MAX_RELIABLE_BACKLOG_BYTES = 16 << 20
MAX_PENDING_DELIVERY_BYTES = 64 << 20
MAX_PENDING_QUERIES = 1024
_GET_GRACE_S = 1.0  # how long past its timeout a get waits for Zenoh to finish the query
_WRITER_DRAIN_S = 1.0


class _ReliableWriter:
    """One thread that puts reliable messages in order, behind a backlog bounded in bytes."""

    def __init__(self, counters: TrafficCounters, max_backlog_bytes: int) -> None:
        self._counters = counters
        self._max_backlog_bytes = max_backlog_bytes
        self._queue: collections.deque[tuple[zenoh.Publisher, str, bytes]] = collections.deque()
        self._backlog_bytes = 0
        self._cond = threading.Condition()
        self._drain_deadline: float | None = None
        self._thread = threading.Thread(target=self._run, name="bus-reliable-writer", daemon=True)
        self._thread.start()

    def submit(self, publisher: zenoh.Publisher, kind: str, data: bytes) -> bool:
        with self._cond:
            if self._drain_deadline is not None:
                return False
            if self._queue and self._backlog_bytes + len(data) > self._max_backlog_bytes:
                return False
            self._queue.append((publisher, kind, data))
            self._backlog_bytes += len(data)
            self._cond.notify()
            return True

    def _next(self) -> tuple[zenoh.Publisher, str, bytes] | None:
        with self._cond:
            while not self._queue and self._drain_deadline is None:
                self._cond.wait()
            if not self._queue:
                return None
            if self._drain_deadline is not None and time.monotonic() > self._drain_deadline:
                for _, kind, _ in self._queue:
                    self._counters.dropped(kind, "closed")
                self._queue.clear()
                return None
            item = self._queue.popleft()
            self._backlog_bytes -= len(item[2])
            return item

    def _run(self) -> None:
        while (item := self._next()) is not None:
            publisher, kind, data = item
            try:
                publisher.put(data)
                self._counters.sent(kind, len(data))
            except Exception as exc:
                self._counters.dropped(kind, "send_error")
                log.warning("reliable put of %s failed: %s", kind, zenoh_error_text(exc))

    def stop(self, drain_s: float) -> None:
        """Put what is queued for up to `drain_s`, drop the rest, and end the thread."""
        with self._cond:
            self._drain_deadline = time.monotonic() + drain_s
            self._cond.notify()
        self._thread.join(drain_s + 1.0)


@dataclass
class _Declared:
    """A subscriber or queryable, with how to declare it again (`AsyncBus.refresh_routes`)."""

    entity: Any
    declare: Callable[[], Any]
    what: str
    routed: bool  # data subscribers and queryables: re-declared by refresh_routes (liveliness is not)


class AsyncBus:
    """A Zenoh session bound to an event loop. Open with `await AsyncBus.open(...)` or `async with`.

    `publish` may be called from any thread; everything else is meant for the loop thread. Own
    publications reach this session's own subscribers too (Zenoh's default): filter by id if needed.
    """

    def __init__(
        self, session: zenoh.Session, loop: asyncio.AbstractEventLoop, keys: Keys, limits: ReceiveLimits | None = None
    ) -> None:
        self.session = session
        self.keys = keys
        self.limits = limits if limits is not None else ReceiveLimits()
        self.counters = TrafficCounters()
        self.closed_cleanly: bool | None = None
        self._loop = loop
        self._lock = threading.Lock()  # the entity tables; never taken in Zenoh callbacks
        self._pending_lock = threading.Lock()
        self._publishers: dict[tuple[str, bool], zenoh.Publisher] = {}
        self._subscribers: list[_Declared] = []
        self._tokens: dict[str, zenoh.LivelinessToken] = {}
        self._writer: _ReliableWriter | None = None
        self._pending_bytes = 0
        self._pending_queries = 0
        self._closed = False
        with _open_buses_lock:
            _open_buses.add(self)

    @classmethod
    async def open(cls, bus: BusSettings, mission: str) -> AsyncBus:
        """Open a session on a worker thread (opening can take 0.5 s); raises BusError."""
        keys = Keys(mission)
        loop = asyncio.get_running_loop()
        session = await asyncio.to_thread(open_session, bus)
        return cls(session, loop, keys, bus.receive)

    async def __aenter__(self) -> AsyncBus:
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.close()

    @property
    def closed(self) -> bool:
        return self._closed

    # --- publishing -------------------------------------------------------------------------------------

    def _publisher(self, key: str, reliable: bool) -> zenoh.Publisher:
        with self._lock:
            publisher = self._publishers.get((key, reliable))
            if publisher is None:
                publisher = self.session.declare_publisher(
                    key,
                    encoding=zenoh.Encoding.APPLICATION_OCTET_STREAM,
                    congestion_control=zenoh.CongestionControl.DROP,
                    reliability=zenoh.Reliability.RELIABLE if reliable else zenoh.Reliability.BEST_EFFORT,
                    priority=zenoh.Priority.DATA if reliable else zenoh.Priority.DATA_HIGH,
                    express=not reliable,
                )
                self._publishers[(key, reliable)] = publisher
            return publisher

    def publish(self, key: str, msg: WireMessage, *, reliable: bool = False) -> None:
        """Send a message without blocking (see the module docstring for what `reliable` guarantees)."""
        kind = msg.KIND
        if self._closed:
            self.counters.dropped(kind, "closed")
            return
        data = encode(msg)
        try:
            publisher = self._publisher(key, reliable)
        except Exception as exc:
            if self._closed:  # close() ran concurrently
                self.counters.dropped(kind, "closed")
                return
            raise BusError(f"cannot publish on {key}: {zenoh_error_text(exc)}") from None
        if reliable:
            if not self._reliable_writer().submit(publisher, kind, data):
                self.counters.dropped(kind, "backlog")
            return
        try:
            publisher.put(data)
            self.counters.sent(kind, len(data))
        except Exception as exc:
            self.counters.dropped(kind, "send_error")
            log.warning("put of %s on %s failed: %s", kind, key, zenoh_error_text(exc))

    def _reliable_writer(self) -> _ReliableWriter:
        with self._lock:
            if self._writer is None:
                self._writer = _ReliableWriter(self.counters, MAX_RELIABLE_BACKLOG_BYTES)
            return self._writer

    # --- receiving --------------------------------------------------------------------------------------

    def subscribe(
        self, key_expr: str, model: type[T], handler: Callable[[str, T], None], *, max_bytes: int = DEFAULT_MAX_BYTES
    ) -> None:
        """Call `handler(key, message)` on the loop for every valid `model` message on `key_expr`.

        Invalid payloads never reach the handler; they are counted as dropped with the DecodeError reason, and
        payloads beyond their key's limits (`bus.receive`) as "rate", "rate_total" or "decode_budget", undecoded.
        """
        if inspect.iscoroutinefunction(handler):
            raise TypeError("handler must be a plain function; start a task from it for async work")
        kind = model.KIND
        limits = self.limits
        limiter = ReceiveLimiter(limits.hz(kind), limits.decode_cpu, limits.total_keys, limits.max_keys)

        def on_sample(sample: zenoh.Sample) -> None:
            try:
                if sample.kind != zenoh.SampleKind.PUT:
                    return
                key = str(sample.key_expr)
                self.counters.received(kind, len(sample.payload))
                refused = limiter.admit(key)
                if refused is not None:
                    self.counters.dropped(kind, refused)
                    return
                data = sample.payload.to_bytes()
                start = time.thread_time()
                try:
                    msg = decode(data, model, max_bytes)
                except DecodeError as exc:
                    self.counters.dropped(kind, exc.reason)
                    log.debug("dropped %s on %s: %s", kind, key, exc)
                    return
                finally:
                    limiter.charge(key, time.thread_time() - start)
                self._deliver(kind, len(data), handler, key, msg)
            except Exception:
                log.exception("subscriber callback for %s failed", key_expr)

        # REMOTE: a session would otherwise receive its own publications, which are not traffic.
        self._declare(
            lambda: self.session.declare_subscriber(key_expr, on_sample, allowed_origin=zenoh.Locality.REMOTE),
            key_expr,
            routed=True,
        )

    def _deliver(self, kind: str, nbytes: int, handler: Callable[[str, Any], None], key: str, msg: Any) -> None:
        with self._pending_lock:
            if self._pending_bytes + nbytes > MAX_PENDING_DELIVERY_BYTES:
                self.counters.dropped(kind, "backlog")
                return
            self._pending_bytes += nbytes
        try:
            self._loop.call_soon_threadsafe(self._run_handler, kind, nbytes, handler, key, msg)
        except RuntimeError:  # the loop is closed
            self.counters.dropped(kind, "closed")

    def _run_handler(self, kind: str, nbytes: int, handler: Callable[[str, Any], None], key: str, msg: Any) -> None:
        with self._pending_lock:
            self._pending_bytes -= nbytes
        if self._closed:
            self.counters.dropped(kind, "closed")
            return
        try:
            handler(key, msg)
        except Exception:
            self.counters.dropped(kind, "handler_error")
            log.exception("handler for %s on %s failed", kind, key)

    # --- queries ----------------------------------------------------------------------------------------

    def declare_queryable(self, key_expr: str, kind: str, handler: QueryHandler) -> None:
        """Answer queries on `key_expr` with `handler(key, parameters)`, called on the loop thread.

        `key` is the query's key expression, `parameters` its selector parameters (``?a=1;b=2``). The handler
        returns the reply payload, a list of payloads (sent as that many replies, in order: e.g. the chunks of a
        large answer), a function returning such a list (a `ReplyBuilder`: called on a worker thread, which
        then sends the replies, so a large answer is built and sent off the loop; it must not touch state the
        loop changes), or None for "not held" (answered with an error reply, which the querier counts as
        "query_error"). An exception in the handler is logged, counted as "handler_error" and
        answered with an error reply. Only remote sessions' queries arrive here (see the module docstring).
        The reply goes out on the query's key expression when it is concrete, else on `key_expr`.
        """
        if inspect.iscoroutinefunction(handler):
            raise TypeError("handler must be a plain function returning bytes or None")

        def on_query(query: zenoh.Query) -> None:
            # A Zenoh thread: count and hand over. The closure given to the loop keeps the Query alive
            # (Zenoh finalises a query when its Query object is garbage-collected) until it is answered.
            try:
                self.counters.received(kind, len(str(query.selector).encode()))
                with self._pending_lock:
                    busy = self._pending_queries >= MAX_PENDING_QUERIES
                    if not busy:
                        self._pending_queries += 1
                if busy:
                    self.counters.dropped(kind, "backlog")
                    _reply_err(query, b"busy")
                    return
                try:
                    self._loop.call_soon_threadsafe(self._answer, kind, key_expr, handler, query)
                except RuntimeError:  # the loop is closed
                    with self._pending_lock:
                        self._pending_queries -= 1
                    self.counters.dropped(kind, "closed")
                    _reply_err(query, b"closed")
            except Exception:
                log.exception("queryable callback for %s failed", key_expr)

        self._declare(
            lambda: self.session.declare_queryable(
                key_expr, on_query, complete=True, allowed_origin=zenoh.Locality.REMOTE
            ),
            key_expr,
            "declare a queryable on",
            routed=True,
        )

    def _answer(self, kind: str, key_expr: str, handler: QueryHandler, query: zenoh.Query) -> None:
        with self._pending_lock:
            self._pending_queries -= 1
        if self._closed:
            self.counters.dropped(kind, "closed")
            return  # the session is going away; dropping the Query finalises it
        try:
            key = str(query.key_expr)
            data = handler(key, dict(query.parameters))  # type: ignore[call-overload]  # stub's __iter__ gives a list
            if callable(data):
                reply_key = key if "*" not in key else key_expr
                self._loop.run_in_executor(None, self._build_and_reply, kind, reply_key, data, query)
                return
            payloads = [data] if isinstance(data, (bytes, bytearray, memoryview)) else data
            if payloads is not None and not _is_payload_list(payloads):
                raise TypeError(f"handler returned {type(data).__name__}, expected bytes, a list of bytes or None")
        except Exception:
            self._handler_failed(kind, "query handler", key_expr, query)
            return
        if payloads is None:
            self.counters.dropped(kind, "not_held")
            _reply_err(query, b"not held")
            return
        self._reply_all(kind, key if "*" not in key else key_expr, payloads, query)

    def _handler_failed(self, kind: str, what: str, key: str, query: zenoh.Query) -> None:
        """Count and log a query handler's or reply builder's exception (called in its except), answer an error."""
        self.counters.dropped(kind, "handler_error")
        log.exception("%s for %s on %s failed", what, kind, key)
        _reply_err(query, b"handler error")

    def _build_and_reply(self, kind: str, reply_key: str, build: ReplyBuilder, query: zenoh.Query) -> None:
        """A worker thread: build a ReplyBuilder's payloads and send them."""
        try:
            payloads = build()
            if not _is_payload_list(payloads):
                raise TypeError(f"reply builder returned {type(payloads).__name__}, expected a list of bytes")
        except Exception:
            self._handler_failed(kind, "reply builder", reply_key, query)
            return
        if self._closed:
            self.counters.dropped(kind, "closed")
            return
        self._reply_all(kind, reply_key, payloads, query)

    def _reply_all(self, kind: str, reply_key: str, payloads: list[Any], query: zenoh.Query) -> None:
        for payload in payloads:
            try:
                query.reply(reply_key, bytes(payload))
                self.counters.sent(kind, len(payload))
            except Exception as exc:
                self.counters.dropped(kind, "send_error")
                log.warning("reply of %s on %s failed: %s", kind, reply_key, zenoh_error_text(exc))
                return

    async def get(self, selector: str, kind: str, timeout_s: float) -> list[tuple[str | None, bytes]]:
        """Query every queryable matching `selector` (``key?a=1;b=2``); the ok replies as (replier, payload).

        The replier is the answering session's Zenoh id as text, or None if unknown. Error replies are
        counted as dropped "query_error", a query that ran out of time as "timeout"; neither is returned.
        Returns [] at once when no queryable is reachable, and never later than about `timeout_s` (+1 s of
        grace). Never blocks the loop.
        """
        if self._closed:
            self.counters.dropped(kind, "closed")
            return []
        loop = asyncio.get_running_loop()
        done: asyncio.Future[None] = loop.create_future()
        replies: list[tuple[str | None, bytes]] = []

        def on_reply(reply: zenoh.Reply) -> None:  # a Zenoh thread
            try:
                sample = reply.ok
                if sample is not None:
                    data = sample.payload.to_bytes()
                    self.counters.received(kind, len(data))
                    replies.append((_replier_text(reply), data))
                    return
                err = reply.err
                text = err.payload.to_bytes() if err is not None else b""
                self.counters.dropped(kind, "timeout" if text == b"Timeout" else "query_error")
            except Exception:
                log.exception("reply callback for %s failed", selector)

        def on_drop() -> None:  # a Zenoh thread, once the query is finished
            try:
                loop.call_soon_threadsafe(_resolve, done, None)
            except RuntimeError:  # the loop is closed
                pass

        try:
            self.session.get(
                selector,
                zenoh.handlers.Callback(on_reply, on_drop),
                target=zenoh.QueryTarget.ALL,
                consolidation=zenoh.ConsolidationMode.NONE,
                congestion_control=zenoh.CongestionControl.DROP,
                timeout=timeout_s,
            )
        except Exception as exc:
            if self._closed:
                self.counters.dropped(kind, "closed")
                return []
            raise BusError(f"cannot query {selector}: {zenoh_error_text(exc)}") from None
        self.counters.sent(kind, len(selector.encode()))
        try:
            await asyncio.wait_for(asyncio.shield(done), timeout_s + _GET_GRACE_S)
        except TimeoutError:
            self.counters.dropped(kind, "timeout")
            log.warning("query %s was not finished %.1f s after its timeout", selector, _GET_GRACE_S)
        return list(replies)

    # --- liveliness -------------------------------------------------------------------------------------

    def declare_token(self, key: str) -> None:
        """Announce presence on `key` until `undeclare_token`, `close`, or the lease expires after a crash."""
        with self._lock:
            if key in self._tokens:
                return
        token = self._call(lambda: self.session.liveliness().declare_token(key), f"declare token {key}")
        with self._lock:
            self._tokens[key] = token

    def undeclare_token(self, key: str) -> None:
        with self._lock:
            token = self._tokens.pop(key, None)
        if token is not None:
            self._call(token.undeclare, f"undeclare token {key}")

    def watch_liveliness(self, key_expr: str, on_join: Callable[[str], None], on_leave: Callable[[str], None]) -> None:
        """Call `on_join(key)` / `on_leave(key)` on the loop as tokens on `key_expr` appear and vanish.

        Tokens that exist already are reported as joins (history).
        """

        def on_sample(sample: zenoh.Sample) -> None:
            try:
                callback = on_join if sample.kind == zenoh.SampleKind.PUT else on_leave
                self._loop.call_soon_threadsafe(self._run_callback, callback, str(sample.key_expr))
            except RuntimeError:  # the loop is closed
                pass
            except Exception:
                log.exception("liveliness callback for %s failed", key_expr)

        self._declare(lambda: self.session.liveliness().declare_subscriber(key_expr, on_sample, history=True), key_expr)

    def _run_callback(self, callback: Callable[[str], None], key: str) -> None:
        if self._closed:
            return
        try:
            callback(key)
        except Exception:
            log.exception("liveliness handler for %s failed", key)

    # --- lifecycle --------------------------------------------------------------------------------------

    def _call(self, declare: Callable[[], Any], what: str) -> Any:
        if self._closed:
            raise BusError(f"cannot {what}: the bus is closed")
        try:
            return declare()
        except Exception as exc:
            raise BusError(f"cannot {what}: {zenoh_error_text(exc)}") from None

    def _declare(
        self, declare: Callable[[], Any], key_expr: str, what: str = "subscribe to", routed: bool = False
    ) -> None:
        entity = self._call(declare, f"{what} {key_expr}")
        with self._lock:
            self._subscribers.append(_Declared(entity, declare, f"{what} {key_expr}", routed))

    def refresh_routes(self) -> int:
        """Undeclare every data subscriber and queryable and declare it again. Messages arriving in between
        (a few milliseconds) are missed: heartbeats are repeated and patches pulled, so nothing is lost for
        good. Returns how many were re-declared; raises BusError if the bus is closed or Zenoh refuses."""
        with self._lock:
            routed = [d for d in self._subscribers if d.routed]
        for declared in routed:  # all first: two subscribers on one key expression are one declaration
            try:
                declared.entity.undeclare()
            except Exception as exc:
                log.warning("undeclare during a route refresh failed: %s", zenoh_error_text(exc))
        for declared in routed:
            declared.entity = self._call(declared.declare, declared.what)
        return len(routed)

    def _teardown(self) -> None:
        if self._writer is not None:
            self._writer.stop(_WRITER_DRAIN_S)
        with self._lock:
            entities = [*(d.entity for d in self._subscribers), *self._tokens.values(), *self._publishers.values()]
            self._subscribers.clear()
            self._tokens.clear()
            self._publishers.clear()
        # Undeclare first: closing with live subscribers and tokens deadlocked Zenoh about once in 10 runs.
        for entity in entities:
            try:
                entity.undeclare()
            except Exception as exc:
                log.warning("undeclare failed during close: %s", zenoh_error_text(exc))
        self.session.close()

    def _start_close(self, on_done: Callable[[BaseException | None], None]) -> None:
        """Mark the bus closed and tear it down on a daemon thread, which ends with `on_done(error)`."""
        self._closed = True
        with _open_buses_lock:
            _open_buses.discard(self)

        def run() -> None:
            error: BaseException | None = None
            try:
                self._teardown()
            except BaseException as exc:  # reported by the waiter, never raised in this thread
                error = exc
            on_done(error)

        threading.Thread(target=run, name="bus-close", daemon=True).start()

    def _closing_ended(self, finished: bool, error: BaseException | None, timeout_s: float) -> None:
        self.closed_cleanly = finished and error is None
        if not finished:
            log.error("Zenoh session did not close within %.1f s; abandoning it", timeout_s)
        elif error is not None:
            log.error("closing the Zenoh session failed: %s", zenoh_error_text(error))

    async def close(self, timeout_s: float = CLOSE_TIMEOUT_S) -> None:
        """Undeclare everything and close the session; never waits longer than about `timeout_s`.

        Reliable messages still queued get up to 1 s to go out. Closing runs on its own daemon thread: if
        Zenoh deadlocks, the thread is abandoned, an error is logged and `closed_cleanly` is False.
        Safe to call twice.
        """
        if self._closed:
            return
        loop = asyncio.get_running_loop()
        done: asyncio.Future[BaseException | None] = loop.create_future()

        def on_done(error: BaseException | None) -> None:
            try:
                loop.call_soon_threadsafe(_resolve, done, error)
            except RuntimeError:  # the loop is closed
                pass

        self._start_close(on_done)
        try:
            error = await asyncio.wait_for(asyncio.shield(done), timeout_s)
        except TimeoutError:
            self._closing_ended(False, None, timeout_s)
        else:
            self._closing_ended(True, error, timeout_s)

    def _close_blocking(self, timeout_s: float) -> None:
        if self._closed:
            return
        finished = threading.Event()
        errors: list[BaseException | None] = []

        def on_done(error: BaseException | None) -> None:
            errors.append(error)
            finished.set()

        self._start_close(on_done)
        ended = finished.wait(timeout_s)
        self._closing_ended(ended, errors[0] if errors else None, timeout_s)


def _resolve(future: asyncio.Future[R], result: R) -> None:
    """Set `future`'s result unless it is done already (on the loop's thread)."""
    if not future.done():
        future.set_result(result)


def _is_payload_list(payloads: object) -> bool:
    """What a query handler or reply builder must return: a list of bytes-like payloads."""
    return isinstance(payloads, list) and all(isinstance(p, (bytes, bytearray, memoryview)) for p in payloads)


def _reply_err(query: zenoh.Query, text: bytes) -> None:
    try:
        query.reply_err(text)
    except Exception as exc:
        log.debug("error reply failed: %s", zenoh_error_text(exc))


def _replier_text(reply: zenoh.Reply) -> str | None:
    try:
        replier = reply.replier_id
        return None if replier is None else str(replier.zid)
    except Exception:
        return None


# A process that exits with a Zenoh callback still declared hangs in interpreter shutdown (measured: every
# time, even with an undeclare in an `atexit` hook). Buses left open are closed from threading's exit hook,
# which runs before the interpreter starts tearing down.
_open_buses: set[AsyncBus] = set()
_open_buses_lock = threading.Lock()


def _close_leftover_buses() -> None:
    with _open_buses_lock:
        leftovers = list(_open_buses)
    for bus in leftovers:
        log.warning("the bus of mission %s was not closed; closing it at exit", bus.keys.mission)
        bus._close_blocking(CLOSE_TIMEOUT_S)


try:
    threading._register_atexit(_close_leftover_buses)  # type: ignore[attr-defined]
except (AttributeError, RuntimeError):  # not CPython >= 3.9, or already shutting down
    atexit.register(_close_leftover_buses)
