"""`swarm bench sync`: how fast and how cheaply patches reach everyone, on loopback, for several swarm sizes.

Three measurements per swarm size N, all with real processes and the mission's configuration (0.1 m voxels,
15-frame patches, 8 kB chunks unless overridden; patches signed and verified as in a mission):

1. **Seal to everyone:** N `swarm mapnode`s each seal `patches` patches, one every `period_s`; for each patch,
   the time from its seal at the producer until the last other node holds it (wall clocks of one host).
2. **Convergence after a heal:** N-1 nodes seal 100 patches between them and share them; then node N joins
   (from the sync protocol's side a heal: a peer whose digest lacks 100 patches) and the time from its first
   contact with a peer until it holds all 100 is measured.
3. **Signing (once, not per size):** real patches sealed in the mission's world (`flight_patches`), encoded and
   decoded with and without the producer's signature: what signing and verifying cost a patch, in time and bytes,
   and the Ed25519 and SHA-256 parts of it.
4. **Bandwidth in a mission:** `swarm run` with N drones in the world; the report's received bus bytes per
   agent-second against the whole-map baseline (every agent sending its whole fused map to every other once per
   exploration loop) at the configured loop period, and what the baseline would be at other periods.

Targets (issue 4): p95 seal-to-everyone < 1 s with 5 agents, convergence of 100 patches < 10 s, at least 10x
less traffic than the whole-map baseline.
"""

from __future__ import annotations

import hashlib
import json
import statistics
import time
from pathlib import Path
from typing import Any

from rich.table import Table

from swarm.config import SwarmConfig, dump_config
from swarm.mission.bench import _console_and_root
from swarm.mission.mapnodes import NodeSpec, NodeSwarm, holds_all
from swarm.mission.run import run_mission
from swarm.patches.signing import CONTEXT

HEAL_PATCHES = 100
SIGNING_PATCHES = 20
BASELINE_PERIODS_S = (1.0, 2.0, 5.0, 20.0)


def _sets(config: SwarmConfig) -> list[str]:
    """The config as --set overrides for mapnodes (mission, mapping, camera, sync and bus mode)."""
    tree = dump_config(config)
    sets = []
    for section in ("mapping", "camera", "sync"):
        for key, value in tree[section].items():
            sets.append(f"{section}.{key}={_toml(value)}")
    sets += [f"mission.world={json.dumps(tree['mission']['world'])}", f"bus.mode={json.dumps(config.bus.mode)}"]
    return sets


def _signed_sets(config: SwarmConfig, root: Path, n: int) -> list[str]:
    """`_sets`, and patches signed as a mission signs them (one authority for the N nodes)."""
    from swarm.deploy.certs import make_signing_authority

    keys = root / f"keys-{n}"
    if not (keys / "ca.pem").exists():
        make_signing_authority(keys, n)
    return [*_sets(config), f"sync.signing_dir={json.dumps(str(keys))}"]


def _toml(value: Any) -> str:
    """A config value as the TOML an override reads: JSON is TOML for scalars and arrays, not for tables."""
    if isinstance(value, dict):
        return "{" + ", ".join(f"{key} = {_toml(item)}" for key, item in value.items()) + "}"
    if isinstance(value, list):
        return "[" + ", ".join(_toml(item) for item in value) + "]"
    return json.dumps(value)


def _percentile(values: list[float], q: float) -> float:
    if not values:
        return float("nan")
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, max(0, round(q * (len(ordered) - 1))))]


def measure_latency(config: SwarmConfig, n: int, root: Path, patches: int = 8, period_s: float = 0.5) -> dict[str, Any]:
    swarm = NodeSwarm(root / f"latency-{n}", f"bench-latency-{n}", config.bus.mode, _signed_sets(config, root, n))
    swarm.tmp.mkdir(parents=True, exist_ok=True)
    try:
        for k in range(1, n + 1):
            swarm.start(NodeSpec(k, patches=patches, period_s=period_s, delay_s=4.0))
        swarm.wait_for(lambda s: all(len(st.get("sealed", [])) == patches for st in s.values()), 180, "all sealed")
        swarm.wait_for(holds_all(swarm.all_sealed()), 60, "every node holds every patch")
        statuses = swarm.statuses()
    finally:
        swarm.close()
    latencies = []
    for k, status in statuses.items():
        for sealed in status["sealed"]:
            others = [s["held_at"][sealed["id"]] for j, s in statuses.items() if j != k]
            latencies.append(max(others) - sealed["t"])
    sizes = [s["bytes"] for st in statuses.values() for s in st["sealed"]]
    return {
        "patches": len(latencies),
        "patch_kb_mean": round(statistics.mean(sizes) / 1000, 1),
        "seal_to_everyone_p50_s": round(_percentile(latencies, 0.5), 3),
        "seal_to_everyone_p95_s": round(_percentile(latencies, 0.95), 3),
        "seal_to_everyone_max_s": round(max(latencies), 3),
    }


def measure_heal(config: SwarmConfig, n: int, root: Path) -> dict[str, Any]:
    swarm = NodeSwarm(root / f"heal-{n}", f"bench-heal-{n}", config.bus.mode, _signed_sets(config, root, n))
    swarm.tmp.mkdir(parents=True, exist_ok=True)
    producers = list(range(1, n))
    share = [
        HEAL_PATCHES // len(producers) + (1 if i < HEAL_PATCHES % len(producers) else 0) for i in range(len(producers))
    ]
    try:
        for k, count in zip(producers, share):
            swarm.start(NodeSpec(k, patches=count, period_s=0.05, delay_s=3.0))
        swarm.wait_for(lambda s: sum(len(st.get("sealed", [])) for st in s.values()) == HEAL_PATCHES, 300, "sealed")
        expected = swarm.all_sealed()
        swarm.wait_for(holds_all(expected, producers), 120, "the producers share their patches")
        swarm.start(NodeSpec(n, patches=0))
        swarm.wait_for(holds_all(expected, [n]), 120, "the joining node holds all 100 patches")
        status = swarm.status(n)
    finally:
        swarm.close()
    done = max(status["held_at"].values())
    return {
        "missing_patches": len(expected),
        "converge_after_contact_s": round(done - status["first_peer_t"], 2),
        "by_pull": status["sync"]["received_by_pull"],
        "bytes_received": sum(v["recv_bytes"] for v in status["traffic"].values()),
    }


def measure_mission(config: SwarmConfig, n: int, root: Path) -> dict[str, Any]:
    run_config = config.model_copy(deep=True)
    run_config.mission.drones = n
    run_config.mission.out = root / f"mission-{n}"
    run_config.explore.strategy = "scripted"  # the same flights at every size: comparable figures

    report = run_mission(run_config, live=False)
    bandwidth = report["bandwidth"]
    per_loop = bandwidth["whole_map_baseline_bytes_per_agent_s"] * (bandwidth["baseline_loop_s"] or 0.0)
    return {
        "status": report["status"],
        "converged": report["converged"],
        "duration_s": report["duration_s"],
        **bandwidth,
        "baseline_at": {f"{p:g}s": round(per_loop / p, 1) for p in BASELINE_PERIODS_S},
    }


def measure_signing(config: SwarmConfig, root: Path, patches: int = SIGNING_PATCHES) -> dict[str, Any]:
    from swarm.deploy.certs import make_signing_authority
    from swarm.mission.bench_mapping import flight_patches
    from swarm.patches.signing import load_signing
    from swarm.patches.wire import decode_patch, encode_patch

    keys = root / "signing-keys"
    make_signing_authority(keys, 1)
    signing = load_signing(keys, 1)
    sealed = flight_patches(config, patches)
    max_bytes = config.mapping.max_patch_bytes
    costs: dict[str, list[float]] = {"sign": [], "verify": [], "extra_bytes": [], "kb": []}
    for patch in sealed:
        lattice = patch.lattice
        times = []
        for signer in (None, signing.signer):
            t0 = time.perf_counter()
            data = encode_patch(patch, signer=signer)
            t1 = time.perf_counter()
            decode_patch(data, lattice, max_bytes, verifier=signing.verifier if signer else None)
            times.append((t1 - t0, time.perf_counter() - t1, len(data)))
        (enc, dec, size), (enc_signed, dec_verified, size_signed) = times
        costs["sign"].append(enc_signed - enc)
        costs["verify"].append(dec_verified - dec)
        costs["extra_bytes"].append(size_signed - size)
        costs["kb"].append(size_signed / 1000)
    assert signing.signer is not None
    digest = hashlib.sha256(b"x").digest()
    t0 = time.perf_counter()
    for _ in range(200):
        signature = signing.signer.sign(digest)
    t1 = time.perf_counter()
    key = signing.signer.key.public_key()
    for _ in range(200):
        key.verify(signature, CONTEXT + digest)
    t2 = time.perf_counter()
    return {
        "patches": len(sealed),
        "patch_kb_mean": round(statistics.mean(costs["kb"]), 1) if sealed else None,
        "sign_ms_median": _ms(costs["sign"]),
        "verify_ms_median": _ms(costs["verify"]),
        "ed25519_sign_ms": round((t1 - t0) / 200 * 1e3, 3),
        "ed25519_verify_ms": round((t2 - t1) / 200 * 1e3, 3),
        "extra_bytes": int(statistics.median(costs["extra_bytes"])) if sealed else None,
    }


def _ms(seconds: list[float]) -> float | None:
    return round(statistics.median(seconds) * 1e3, 3) if seconds else None


def bench_sync(config: SwarmConfig, sizes: list[int], out: Path | None, mission: bool = True) -> int:
    console, root = _console_and_root(out)
    console.print(f"bench sync: signing and verifying up to {SIGNING_PATCHES} patches of '{config.mission.world}' ...")
    signing = measure_signing(config, root)
    console.print(
        f"signing: {signing['patches']} patches of {signing['patch_kb_mean']} kB: "
        f"sign +{signing['sign_ms_median']} ms, verify +{signing['verify_ms_median']} ms a patch (medians; "
        f"Ed25519 alone {signing['ed25519_sign_ms']} / {signing['ed25519_verify_ms']} ms), "
        f"+{signing['extra_bytes']} bytes a patch (certificate and signature)"
    )
    results: list[dict[str, Any]] = []
    for n in sizes:
        if n < 2:
            console.print(f"bench sync: skipping {n} agent(s): sharing needs at least 2")
            continue
        console.print(f"bench sync: {n} agents: seal-to-everyone latency ...")
        row: dict[str, Any] = {"agents": n, "latency": measure_latency(config, n, root)}
        console.print(f"bench sync: {n} agents: convergence of {HEAL_PATCHES} missing patches ...")
        row["heal"] = measure_heal(config, n, root)
        if mission:
            console.print(f"bench sync: {n} agents: bandwidth in a '{config.mission.world}' mission ...")
            row["mission"] = measure_mission(config, n, root)
        results.append(row)
    _print(console, results)
    path = root / "bench-sync.json"
    path.write_text(json.dumps({"signing": signing, "sizes": results}, indent=2))
    console.print(f"figures: {path}")
    ok = all(r.get("mission", {}).get("converged", True) for r in results)
    return 0 if ok else 1


def _print(console: Any, results: list[dict[str, Any]]) -> None:
    table = Table(
        title="swarm bench sync (loopback; targets: p95 < 1 s at 5 agents, heal < 10 s, >= 10x less than baseline)"
    )
    for column in (
        "agents",
        "patch kB",
        "seal->all p50 s",
        "p95 s",
        "max s",
        "heal: 100 patches s",
        "mission B/agent-s",
        "whole-map baseline B/agent-s",
        "ratio",
        "converged",
    ):
        table.add_column(column, justify="right")
    for r in results:
        lat, heal, m = r["latency"], r["heal"], r.get("mission", {})
        table.add_row(
            str(r["agents"]),
            str(lat["patch_kb_mean"]),
            str(lat["seal_to_everyone_p50_s"]),
            str(lat["seal_to_everyone_p95_s"]),
            str(lat["seal_to_everyone_max_s"]),
            str(heal["converge_after_contact_s"]),
            str(m.get("bytes_per_agent_s", "-")),
            f"{m.get('whole_map_baseline_bytes_per_agent_s', '-')} (loop {m.get('baseline_loop_s', '-')} s)",
            str(m.get("baseline_ratio", "-")),
            str(m.get("converged", "-")),
        )
    console.print(table)
    for r in results:
        if "mission" in r:
            console.print(
                f"{r['agents']} agents: whole-map baseline B/agent-s at other loop periods: "
                f"{r['mission']['baseline_at']}"
            )
