"""A fuzzing entry point for every decoder of network input.

`fuzz_one(data)` routes ``data[0]`` to one of `DECODERS` and feeds it ``data[1:]``. A decoder either accepts
the input (and then checks that the result re-encodes to the same message) or raises its documented error
(`DecodeError`, `PatchDecodeError`, `ValueError` for pull requests), which is swallowed; any other exception
propagates, and so does a `FuzzFailure` when one input took more than `TIME_LIMIT_S` of CPU time a decode
(measured twice, so a garbage collection or a preempted thread is not taken for a slow decoder; the time
includes the re-encoding check of an accepted input): a decoder of network input holds the GIL, so a slow one
starves the receiving loop (issue 25). The pull-request route reads its bytes as selector parameters
(``ids=...;from=...``), the reassembly route as a sequence of honest and lying chunks fed to a `Reassembler`
(see `_reassembly`; the limit holds per chunk). Bytes in, nothing out, so an atheris-style harness can drive
it as is::

    atheris.Setup(sys.argv, fuzz_one)
    atheris.Fuzz()

``python -m swarm.fuzz --iterations N --seed S`` (or ``--seconds T``) runs it over inputs of its own (random
bytes, valid messages, valid messages with bytes flipped, inserted or cut), prints how many inputs each decoder
accepted and rejected, the throughput and the slowest input, and exits 1 with the input in hex on the first
unexpected exception or input over the time limit (``--time-limit-ms``).
"""

from __future__ import annotations

import argparse
import random
import sys
import tempfile
import time
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np

from swarm.bus.codec import DecodeError, WireMessage, decode, encode
from swarm.bus.holdings import DigestWire
from swarm.bus.messages import AgentState
from swarm.bus.phase import Phase
from swarm.patches.digest import DigestMessage, PatchDigest
from swarm.patches.lattice import Lattice
from swarm.patches.patch import FrameSpan, Patch, PatchId, VoxelBlocks
from swarm.patches.signing import Signing, load_signing
from swarm.patches.wire import PatchDecodeError, decode_expected, decode_patch, encode_patch
from swarm.roles.messages import FrontierReport, TargetAssignment, as_points
from swarm.sync.chunks import PatchChunk, Reassembler, split_patch
from swarm.sync.requests import parse_request, request_parameters

LATTICE = Lattice(0.2, 4, 4.0)  # 64 voxels a block keeps seed patches small
SEED_PATCH_ID = PatchId(2, 1, 0)
PATCH_MAX_BYTES = 1 << 16  # caps a hostile patch's decompressed size at MAX_EXPANSION * 64 KiB = 1 MiB
CHUNK_MAX_BYTES = 8192 + 512  # the sync service's bound for default settings
ASSEMBLY_CHUNK = 512
ASSEMBLY_SIZES = (1, 700, 1500, 3000)  # patch sizes the reassembly route mixes; 3000 is over its limit
ASSEMBLY_MAX_BYTES = 2048
TIME_LIMIT_S = 0.005  # CPU time one input may take (the slowest seen: about 1 ms)


class FuzzFailure(AssertionError):
    """A decoder accepted an input but broke one of its invariants."""


def _require(condition: bool, what: str) -> None:
    if not condition:
        raise FuzzFailure(what)


def _one(data: bytes) -> int:
    return 1


@dataclass(frozen=True)
class Decoder:
    """One decoder: `run` returns True (accepted), False (rejected with the documented error) or raises.
    `decodes(data)`: how many decodes `run(data)` does, each allowed the time limit (1 but for reassembly)."""

    name: str
    run: Callable[[bytes], bool]
    seed: Callable[[], bytes]
    decodes: Callable[[bytes], int] = _one


def _codec(model: type[WireMessage], max_bytes: int) -> Callable[[bytes], bool]:
    def run(data: bytes) -> bool:
        try:
            msg = decode(data, model, max_bytes)
        except DecodeError:
            return False
        wire = encode(msg)
        _require(decode(wire, model, len(wire)) == msg, f"{model.KIND} changes when re-encoded")
        return True

    return run


@cache
def fuzz_signing() -> Signing:
    """A signing authority of the fuzzer's own (in a temporary directory, read back at once) and producer 2's key."""
    from swarm.deploy.certs import make_signing_authority

    with tempfile.TemporaryDirectory(prefix="swarm-fuzz-keys-") as directory:
        make_signing_authority(Path(directory), SEED_PATCH_ID.producer)
        return load_signing(Path(directory), SEED_PATCH_ID.producer)


def _signed_patch(data: bytes) -> bool:
    """The patch route with the producer's signature required: what a receiver with signing runs."""
    signing = fuzz_signing()
    try:
        patch = decode_patch(data, LATTICE, PATCH_MAX_BYTES, verifier=signing.verifier)
    except PatchDecodeError:
        return False
    _require(patch.id.producer == SEED_PATCH_ID.producer, f"patch {patch.id} verified for another producer")
    wire = encode_patch(patch, signer=signing.signer)
    again = decode_patch(wire, LATTICE, max(len(wire), PATCH_MAX_BYTES), verifier=signing.verifier)
    _require(again == patch, "signed patch changes")
    return True


def _patch(expected: PatchId | None) -> Callable[[bytes], bool]:
    def run(data: bytes) -> bool:
        try:
            if expected is None:
                patch = decode_patch(data, LATTICE, PATCH_MAX_BYTES)
            else:
                patch = decode_expected(data, expected, LATTICE, PATCH_MAX_BYTES)
        except PatchDecodeError:
            return False
        wire = encode_patch(patch)
        _require(decode_patch(wire, LATTICE, max(len(wire), PATCH_MAX_BYTES)) == patch, "patch changes")
        return True

    return run


def parameters_of(data: bytes) -> dict[str, str]:
    """Selector parameters as a queryable receives them: ``k=v`` pairs separated by ';'."""
    text = data.decode("utf-8", "replace")
    return {key: value for key, _, value in (part.partition("=") for part in text.split(";") if part)}


def _request(data: bytes) -> bool:
    try:
        ids, requester = parse_request(parameters_of(data))
    except ValueError:
        return False
    _require(0 < len(ids) == len(set(ids)), f"ids {ids} are empty or repeated")
    requester = requester or 1  # request_parameters always names one
    again = parse_request(parameters_of(request_parameters(ids, requester).encode()))
    _require(again == (ids, requester), "request changes when re-encoded")
    return True


@cache
def assembly_patches() -> tuple[bytes, ...]:
    rng = random.Random(0)
    return tuple(rng.randbytes(n) for n in ASSEMBLY_SIZES)


def _lying_chunk(seq: int, kind: int, pick: int, param: int) -> PatchChunk:
    """Chunk `pick` of patch `seq` from sender 1-3; kinds 4-6 lie about the CRC, the count or the data.
    ValueError if the lie is not even a valid chunk (it would not decode)."""
    honest = split_patch(1 + pick % 3, PatchId(1, 0, seq), assembly_patches()[seq], ASSEMBLY_CHUNK)
    fields = honest[pick % len(honest)].model_dump()
    if kind == 4:
        fields["crc32"] ^= param + 1
    elif kind == 5:
        fields["count"] = 1 + param % 8
        fields["index"] = pick % fields["count"]
    elif kind == 6:
        fields["data"] = bytes([param]) * (1 + 4 * param)
    return PatchChunk(**fields)


def _reassembly(data: bytes) -> bool:
    """Chunks described by `data`, 3 bytes each (seq and kind, pick, param; kind 7 lets time pass), into a
    Reassembler; True if a patch completed. Completed bytes must be the patch, memory within the bounds."""
    now = [0.0]
    reassembler = Reassembler(ASSEMBLY_MAX_BYTES, 5.0, ASSEMBLY_MAX_BYTES, clock=lambda: now[0])
    completed = False
    for i in range(0, len(data) - 2, 3):
        seq, kind, pick, param = data[i] & 3, (data[i] >> 2) & 7, data[i + 1], data[i + 2]
        if kind == 7:
            now[0] += param / 16
            reassembler.expire()
            continue
        try:
            chunk = _lying_chunk(seq, kind, pick, param)
        except ValueError:
            continue
        out = reassembler.add(chunk)
        _require(out is None or out == assembly_patches()[seq], f"patch {seq} completed with other bytes")
        _require(0 <= reassembler.pending_bytes <= ASSEMBLY_MAX_BYTES, f"{reassembler.pending_bytes} bytes held")
        completed = completed or out is not None
    return completed


def _seed_patch() -> Patch:
    rng = np.random.default_rng(0)
    weight = rng.integers(0, 4, size=(3, LATTICE.voxels_per_block), dtype=np.uint8)
    tsdf = (rng.integers(-127, 128, size=weight.shape) * (weight > 0)).astype(np.int8)
    keys = np.array([[0, 0, 0], [1, 0, 0], [0, 1, -1]], dtype=np.int32)
    span = FrameSpan(0, 5, 1_700_000_000.0, 1_700_000_000.5)
    return Patch.seal(SEED_PATCH_ID, LATTICE, span, np.eye(4), VoxelBlocks(keys, tsdf, weight))


def _seed_digest() -> DigestWire:
    ids = [PatchId(2, 1, s) for s in (0, 1, 2, 5)] + [PatchId(7, 1_795_340_000_000, 3)]
    return PatchDigest.of(ids).to_wire_model()


def _seed_state() -> bytes:
    return encode(
        AgentState(
            id=3,
            epoch=1_795_340_000_000,
            seq=41,
            t=1_700_000_000.25,
            position=(1.0, -2.5, 1.5),
            velocity=(0.5, 0.0, -0.1),
            heading_to=(4.0, 4.0, 1.5),
            yaw_deg=-45.0,
            flight_mode="OFFBOARD",
            phase=Phase.FLYING,
            role="explorer",
            leader=1,
            holdings=_seed_digest(),
        )
    )


def _seed_frontiers() -> bytes:
    points = as_points([(1.0, 2.0, 1.5), (3.0, -1.0, 1.0), (0.5, 0.5, 2.0)])
    return encode(
        FrontierReport(
            id=4,
            epoch=9,
            seq=2,
            position=(0.0, 0.0, 1.5),
            viewpoints=points,
            points=points + 0.5,
            gains=np.array([3.0, 0.0, 1.5], dtype=np.float32),
            visited=points[:2],
            arrived=True,
        )
    )


def _seed_targets() -> bytes:
    return encode(
        TargetAssignment(
            leader=1,
            epoch=9,
            round=7,
            members=[1, 2, 3],
            drones=[2, 3],
            viewpoints=as_points([(1.0, 1.0, 1.0), (5.0, 5.0, 1.0)]),
            points=as_points([(2, 1, 1), (6, 5, 1)]),
        )
    )


def _seed_digest_message() -> bytes:
    return encode(DigestMessage(id=3, epoch=0, digest=_seed_digest()))


def _seed_chunk() -> bytes:
    return encode(split_patch(2, SEED_PATCH_ID, bytes(3000), 1024)[1])


def _seed_patch_bytes() -> bytes:
    return encode_patch(_seed_patch())


def _seed_signed_patch_bytes() -> bytes:
    return encode_patch(_seed_patch(), signer=fuzz_signing().signer)


def _seed_request() -> bytes:
    return request_parameters([SEED_PATCH_ID, PatchId(7, 0, 3)], 4).encode()


def _seed_assembly() -> bytes:
    records = []
    for seq, size in enumerate(ASSEMBLY_SIZES):
        records += [bytes([seq, index, 0]) for index in range(-(-size // ASSEMBLY_CHUNK))]
    return b"".join(records)


DECODERS: tuple[Decoder, ...] = (
    Decoder("state", _codec(AgentState, 1 << 20), _seed_state),
    Decoder("digest", _codec(DigestMessage, 1 << 20), _seed_digest_message),
    Decoder("chunk", _codec(PatchChunk, CHUNK_MAX_BYTES), _seed_chunk),
    Decoder("frontiers", _codec(FrontierReport, 1 << 20), _seed_frontiers),
    Decoder("targets", _codec(TargetAssignment, 1 << 20), _seed_targets),
    Decoder("patch", _patch(None), _seed_patch_bytes),
    Decoder("patch_expected", _patch(SEED_PATCH_ID), _seed_patch_bytes),
    Decoder("request", _request, _seed_request),
    Decoder("reassembly", _reassembly, _seed_assembly, lambda data: max(1, len(data) // 3)),  # a chunk per record
    Decoder("signed_patch", _signed_patch, _seed_signed_patch_bytes),
)


def route(data: bytes) -> tuple[Decoder, bytes]:
    """The decoder ``data[0]`` names, and the rest of `data`."""
    return DECODERS[data[0] % len(DECODERS) if data else 0], data[1:]


def timed_run(data: bytes) -> tuple[str, bool, float]:
    """(decoder name, accepted, CPU seconds per decode) for one fuzz input; an unexpected exception propagates."""
    decoder, rest = route(data)
    start = time.thread_time()
    accepted = decoder.run(rest)
    return decoder.name, accepted, (time.thread_time() - start) / decoder.decodes(rest)


def checked_run(data: bytes, time_limit_s: float | None = TIME_LIMIT_S) -> tuple[str, bool, float]:
    """`timed_run`, measured again when over `time_limit_s` (None: no limit): the CPU time is the lesser of the
    two, and FuzzFailure names an input over the limit both times."""
    name, accepted, cpu_s = timed_run(data)
    if time_limit_s is not None and cpu_s > time_limit_s:
        cpu_s = min(cpu_s, timed_run(data)[2])
        if cpu_s > time_limit_s:
            raise FuzzFailure(
                f"{name} took {cpu_s * 1000:.1f} ms of CPU a decode, over {time_limit_s * 1000:g} ms, "
                f"on input {data.hex()}"
            )
    return name, accepted, cpu_s


def run_one(data: bytes, time_limit_s: float | None = TIME_LIMIT_S) -> tuple[str, bool]:
    """(decoder name, accepted) for one fuzz input; an unexpected exception propagates, and FuzzFailure names
    an input whose decodes took more than `time_limit_s` of CPU each, twice running (None: no limit)."""
    name, accepted, _ = checked_run(data, time_limit_s)
    return name, accepted


def fuzz_one(data: bytes) -> None:
    """The atheris-style entry point: bytes in, nothing out, only unexpected exceptions (and inputs over the
    time limit) escape."""
    run_one(data)


@cache
def _seeds() -> tuple[bytes, ...]:
    return tuple(decoder.seed() for decoder in DECODERS)


def mutate(data: bytes, rng: random.Random) -> bytes:
    """`data` with 1-4 bytes flipped, set, inserted or deleted, or cut short."""
    out = bytearray(data)
    for _ in range(rng.randint(1, 4)):
        at = rng.randrange(len(out) + 1)
        op = rng.randrange(5)
        if op == 0 and at < len(out):
            out[at] ^= 1 << rng.randrange(8)
        elif op == 1 and at < len(out):
            out[at] = rng.randrange(256)
        elif op == 2:
            out[at:at] = rng.randbytes(rng.randint(1, 8))
        elif op == 3:
            del out[at : at + rng.randint(1, 8)]
        else:
            del out[at:]
    return bytes(out)


def make_input(rng: random.Random) -> bytes:
    """One fuzz input: a decoder's index, then random bytes, its valid seed, or the seed mutated."""
    index = rng.randrange(len(DECODERS))
    shape = rng.random()
    if shape < 0.2:
        body = rng.randbytes(rng.randrange(256))
    elif shape < 0.35:
        body = _seeds()[index]
    else:
        body = mutate(_seeds()[index], rng)
    return bytes([index]) + body


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m swarm.fuzz", description="Fuzz every network decoder.")
    parser.add_argument("--iterations", type=int, default=10_000)
    parser.add_argument("--seconds", type=float, default=None, help="run this long instead of --iterations")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--time-limit-ms", type=float, default=TIME_LIMIT_S * 1000, help="CPU time per input")
    args = parser.parse_args(argv)
    rng = random.Random(args.seed)
    limit_s = args.time_limit_ms / 1000
    counts = {decoder.name: [0, 0] for decoder in DECODERS}
    slowest = (0.0, "", b"")
    start = time.monotonic()
    deadline = None if args.seconds is None else start + args.seconds
    done = 0
    while done < args.iterations if deadline is None else time.monotonic() < deadline:
        data = make_input(rng)
        try:
            name, accepted, cpu_s = checked_run(data, limit_s)
        except Exception:
            traceback.print_exc()
            print(
                f"unexpected exception in {route(data)[0].name} after {done} iterations, input: {data.hex()}",
                file=sys.stderr,
            )
            return 1
        if cpu_s > slowest[0]:
            slowest = (cpu_s, name, data)
        counts[name][0 if accepted else 1] += 1
        done += 1
    elapsed = time.monotonic() - start
    print(f"iterations: {done} (seed {args.seed})")
    print(f"{'decoder':<16}{'accepted':>10}{'rejected':>10}")
    for name, (n_accepted, n_rejected) in counts.items():
        print(f"{name:<16}{n_accepted:>10}{n_rejected:>10}")
    print(f"throughput: {done / max(elapsed, 1e-9):.0f} inputs/s ({done} in {elapsed:.1f} s)")
    print(f"slowest: {slowest[0] * 1000:.2f} ms of CPU a decode in {slowest[1]} (limit {args.time_limit_ms:g} ms)")
    if slowest[2]:
        print(f"slowest input: {slowest[2].hex()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
