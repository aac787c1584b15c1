import json
import threading

from swarm.bus.counters import TrafficCounters


def test_snapshot_shape() -> None:
    counters = TrafficCounters()
    counters.sent("state", 100)
    counters.sent("state", 50)
    counters.received("state", 70)
    counters.dropped("state", "invalid")
    counters.dropped("state", "invalid")
    counters.received("patch", 1000)
    snapshot = counters.snapshot()
    assert snapshot == {
        "patch": {"sent_msgs": 0, "sent_bytes": 0, "recv_msgs": 1, "recv_bytes": 1000, "dropped": {}},
        "state": {"sent_msgs": 2, "sent_bytes": 150, "recv_msgs": 1, "recv_bytes": 70, "dropped": {"invalid": 2}},
    }
    assert json.loads(json.dumps(snapshot)) == snapshot
    assert counters.bytes_sent == 150
    assert counters.bytes_received == 1070
    assert counters.dropped_count("state") == 2
    assert counters.dropped_count("state", "invalid") == 2
    assert counters.dropped_count("state", "kind") == 0
    assert counters.dropped_count("nothing") == 0


def test_snapshot_is_a_copy() -> None:
    counters = TrafficCounters()
    counters.dropped("state", "invalid")
    snapshot = counters.snapshot()
    counters.dropped("state", "invalid")
    assert snapshot["state"]["dropped"] == {"invalid": 1}


def test_concurrent_increments_are_exact() -> None:
    counters = TrafficCounters()
    threads_n, per_thread = 8, 5000
    start = threading.Barrier(threads_n)

    def work(index: int) -> None:
        kind = "state" if index % 2 else "patch"
        start.wait()
        for _ in range(per_thread):
            counters.sent(kind, 3)
            counters.received(kind, 5)
            counters.dropped(kind, "invalid")

    threads = [threading.Thread(target=work, args=(i,)) for i in range(threads_n)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()

    per_kind = threads_n // 2 * per_thread
    for kind in ("state", "patch"):
        counts = counters.snapshot()[kind]
        assert counts == {
            "sent_msgs": per_kind,
            "sent_bytes": 3 * per_kind,
            "recv_msgs": per_kind,
            "recv_bytes": 5 * per_kind,
            "dropped": {"invalid": per_kind},
        }
    assert counters.bytes_sent == 3 * threads_n * per_thread
    assert counters.bytes_received == 5 * threads_n * per_thread
