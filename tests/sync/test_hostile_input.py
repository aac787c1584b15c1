"""Hostile input on every key expression of map sharing (issue 4, test 7): random bytes, wrong schema versions,
absurd lengths, lies in valid envelopes, and a fake holder answering pulls with garbage. The nodes keep running,
count what they drop, and their maps do not change."""

from __future__ import annotations

import random
import time
import zlib
from collections.abc import Iterator
from pathlib import Path

import msgpack
import pytest
import zenoh

from swarm.bus.codec import SCHEMA_VERSION, encode
from swarm.bus.holdings import DigestWire
from swarm.bus.keys import Keys
from swarm.bus.messages import AgentState
from swarm.bus.phase import Phase
from swarm.sync.chunks import PatchChunk
from tests.sync.nodes import NodeSpec, NodeSwarm, holds_all

pytestmark = pytest.mark.bus

FAKE_ID = 9


@pytest.fixture
def swarm(tmp_path: Path) -> Iterator[NodeSwarm]:
    nodes = NodeSwarm(tmp_path, mission="hostile")
    try:
        yield nodes
    finally:
        nodes.close()


def _garbage(rng: random.Random) -> list[bytes]:
    envelope = lambda v, k, d: msgpack.packb({"v": v, "k": k, "d": d}, use_bin_type=True)  # noqa: E731
    return [
        rng.randbytes(1),
        rng.randbytes(64),
        rng.randbytes(5000),
        b"",
        envelope(SCHEMA_VERSION + 7, "state", {}),
        envelope(SCHEMA_VERSION, "patch_chunk", {"sender": 1}),
        envelope(SCHEMA_VERSION, "state", {"id": "x" * 100_000}),
        b"\xdd\xff\xff\xff\xff",  # msgpack array header claiming 4 billion items
        b"\xc6\x7f\xff\xff\xff",  # bin32 header claiming 2 GB
        msgpack.packb([[[[[[[[[[]]]]]]]]]] * 100),
    ]


def _lying_chunks(keys: Keys) -> list[tuple[str, bytes]]:
    """Valid envelopes that lie: a chunk on another sender's key, a bad index, a 'patch' of random bytes with a
    correct CRC (it completes and must fail to decode), a chunk claiming a patch of 1 GB."""
    junk = random.Random(3).randbytes(3000)
    chunks = [
        PatchChunk(
            sender=FAKE_ID,
            producer=FAKE_ID,
            epoch=1,
            seq=i,
            index=j,
            count=2,
            total_bytes=3000,
            crc32=zlib.crc32(junk),
            data=junk[j * 1500 : (j + 1) * 1500],
        )
        for i in range(3)
        for j in range(2)
    ]
    out = [(keys.patch(FAKE_ID), encode(c)) for c in chunks]
    out.append((keys.patch(2), encode(chunks[0])))  # sender 9 on drone 2's key
    huge = PatchChunk(
        sender=FAKE_ID, producer=FAKE_ID, epoch=1, seq=99, index=0, count=1, total_bytes=1 << 30, crc32=0, data=b"x"
    )
    out.append((keys.patch(FAKE_ID), encode(huge)))
    return out


def _fake_holder_state(seq: int) -> AgentState:
    holdings = DigestWire.model_validate({"entries": [{"producer": FAKE_ID, "epoch": 5, "ranges": [[0, 10**15]]}]})
    return AgentState(
        id=FAKE_ID,
        epoch=5,
        seq=seq,
        t=time.time(),
        position=(0.0, 0.0, 1.0),
        velocity=(0.0, 0.0, 0.0),
        yaw_deg=0.0,
        flight_mode="NONE",
        phase=Phase.MAPPING,
        role="explorer",
        leader=FAKE_ID,
        holdings=holdings,
    )


def test_hostile_input_is_counted_and_dropped_and_maps_do_not_change(swarm: NodeSwarm) -> None:
    for k in (1, 2, 3):
        swarm.start(NodeSpec(k, patches=2, period_s=0.3, delay_s=1.5))
    swarm.wait_for(lambda s: all(len(st.get("sealed", [])) == 2 for st in s.values()), 60, "all sealed")
    expected = swarm.all_sealed()
    swarm.wait_for(holds_all(expected), 30, "every node holds every patch")
    swarm.wait_for(lambda s: len({st.get("fused_digest") for st in s.values()}) == 1, 10, "equal fused maps")
    before = {k: (s["fused_digest"], s["held"]) for k, s in swarm.statuses().items()}

    keys = Keys("hostile")
    rng = random.Random(7)
    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("connect/endpoints", str([swarm.endpoint(k) for k in (1, 2, 3)]).replace("'", '"'))
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("scouting/gossip/enabled", "false")
    session = zenoh.open(config)
    try:
        # a fake holder: advertises patches, then answers pulls with garbage and with a chunk of a bad CRC
        bad_crc = PatchChunk(
            sender=FAKE_ID, producer=FAKE_ID, epoch=5, seq=0, index=0, count=1, total_bytes=4, crc32=0, data=b"abcd"
        )

        def answer(query: zenoh.Query) -> None:
            for payload in [*_garbage(random.Random(1))[:4], encode(bad_crc)]:
                query.reply(query.key_expr, payload)

        queryable = session.declare_queryable(keys.store(FAKE_ID), answer)
        bad_keys = [
            keys.state(FAKE_ID),
            keys.state(1),
            keys.patch(FAKE_ID),
            keys.patch(1),
            f"{keys.root}/agent/0/state",
            f"{keys.root}/agent/01/patch",
            f"{keys.root}/agent/x/state",
        ]
        deadline = time.monotonic() + 4.0
        seq = 0
        while time.monotonic() < deadline:
            seq += 1
            for key in bad_keys:
                for payload in _garbage(rng):
                    session.put(key, payload)
            for key, payload in _lying_chunks(keys):
                session.put(key, payload)
            session.put(keys.state(FAKE_ID), encode(_fake_holder_state(seq)))
            session.put(keys.state(2), encode(_fake_holder_state(seq)))  # id 9's heartbeat on drone 2's key
            for k in (1, 2, 3):
                for params in (
                    "",
                    "ids=",
                    "ids=garbage",
                    "ids=" + ",".join(["1.2.3"] * 1000),
                    "ids=0.1.1",
                    "ids=1.99999999999999999999.1",
                    "ids=1.1.1;from=0",
                    "from=1",
                ):
                    for _ in session.get(f"{keys.store(k)}?{params}", timeout=0.5):
                        pass
            time.sleep(0.2)
        queryable.undeclare()
    finally:
        session.close()

    # the nodes lived through it, and one more round of real work still converges
    for k, proc in swarm.procs.items():
        assert proc.poll() is None, f"node {k} died: {swarm.log_tail(k)}"
    after = swarm.statuses()
    for k, status in after.items():
        assert (status["fused_digest"], status["held"]) == before[k], f"node {k}'s map changed"
        traffic, sync = status["traffic"], status["sync"]
        assert sum(traffic["state"]["dropped"].values()) > 0, traffic["state"]
        assert sum(traffic["patch_chunk"]["dropped"].values()) > 0, traffic["patch_chunk"]
        assert traffic["patch_chunk"]["dropped"].get("sender_mismatch", 0) > 0
        assert sync["rejected"].get("not_msgpack", 0) + sync["rejected"].get("invalid", 0) > 0, sync["rejected"]
        assert sync["assembly_dropped"].get("oversize", 0) > 0
        assert sync["requests_refused"] > 0
        assert sync["limits"]["pull_claims_over_quota"] > 0  # the fake holder's 10**15 ids, cut at its share
        assert traffic["store"]["dropped"], traffic["store"]  # the fake holder's garbage replies
        assert all(not pid.startswith(f"{FAKE_ID}.") for pid in status["held"])
