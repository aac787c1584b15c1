"""Patches bound to their producer: a signed patch verifies; unsigned, forged, re-signed or tampered ones are refused
with their reason, before anything is decompressed or fused; signing material that cannot be used is one line."""

from dataclasses import replace
from pathlib import Path

import msgpack
import pytest
from cryptography import x509
from cryptography.hazmat.primitives import serialization

from swarm.config import MappingSettings
from swarm.deploy.certs import make_certs, make_signing_authority
from swarm.patches import wire
from swarm.patches.fused import FusedMap
from swarm.patches.mapper import Mapper
from swarm.patches.patch import Patch, PatchId
from swarm.patches.signing import PatchSigner, Signing, SigningError, load_signing, signing_cert_path, signing_key_path
from swarm.patches.wire import PatchDecodeError, decode_patch, encode_patch
from tests.patches.scene import MAX_RANGE, ROOM_HI, ROOM_LO, rotate_in_place

BOUNDS = (ROOM_LO - 1.0, ROOM_HI + 1.0)
MAX_BYTES = 4 << 20
PRODUCER = 2


@pytest.fixture(scope="module")
def keys(tmp_path_factory: pytest.TempPathFactory) -> Path:
    directory = tmp_path_factory.mktemp("keys")
    make_signing_authority(directory, drones=3)
    return directory


@pytest.fixture(scope="module")
def patch() -> Patch:
    mapper = Mapper(MappingSettings(voxel_size_m=0.2, patch_frames=1), PRODUCER, 1795340000000, BOUNDS)
    frame = rotate_in_place()[0]
    sealed = mapper.integrate(frame.depth, frame.K, frame.T, frame.t, MAX_RANGE)
    assert sealed is not None
    return sealed


def refused(data: bytes, patch: Patch, signing: Signing) -> str:
    fused = FusedMap(patch.lattice, BOUNDS)
    try:
        fused.add(decode_patch(data, patch.lattice, MAX_BYTES, verifier=signing.verifier))
    except PatchDecodeError as exc:
        assert not fused.ids and fused.block_count == 0
        return exc.reason
    raise AssertionError("a patch that is not its producer's was accepted")


def test_a_signed_patch_verifies_and_carries_its_certificate(keys: Path, patch: Patch) -> None:
    signing = load_signing(keys, PRODUCER)
    assert signing.signer is not None
    data = encode_patch(patch, signer=signing.signer)
    assert decode_patch(data, patch.lattice, MAX_BYTES, verifier=signing.verifier) == patch
    observer = load_signing(keys, None)  # verifies, signs nothing
    assert observer.signer is None
    assert decode_patch(data, patch.lattice, MAX_BYTES, verifier=observer.verifier) == patch
    unsigned = encode_patch(patch)
    assert 300 < len(data) - len(unsigned) < 700  # the certificate (DER) and 64 bytes of signature
    assert encode_patch(patch, signer=signing.signer) == data  # Ed25519 is deterministic: one patch, one content


def test_an_unsigned_patch_is_refused_by_a_verifier_and_taken_without_one(keys: Path, patch: Patch) -> None:
    data = encode_patch(patch)
    assert refused(data, patch, load_signing(keys, 1)) == "unsigned"
    assert decode_patch(data, patch.lattice, MAX_BYTES) == patch


def test_another_drones_key_cannot_sign_a_patch(keys: Path, patch: Patch) -> None:
    drone_3 = load_signing(keys, 3).signer
    assert drone_3 is not None
    with pytest.raises(ValueError, match="cannot sign"):
        encode_patch(patch, signer=drone_3)
    posing = PatchSigner(PRODUCER, drone_3.key, drone_3.cert_der)  # drone 3's key and certificate, producer 2's id
    assert refused(encode_patch(patch, signer=posing), patch, load_signing(keys, 1)) == "signer"
    # drone 2's certificate with drone 3's key: the signature does not hold
    drone_2 = load_signing(keys, PRODUCER).signer
    assert drone_2 is not None
    borrowed = PatchSigner(PRODUCER, drone_3.key, drone_2.cert_der)
    assert refused(encode_patch(patch, signer=borrowed), patch, load_signing(keys, 1)) == "signature"


def test_content_changed_after_signing_is_refused(keys: Path, patch: Patch) -> None:
    signer = load_signing(keys, PRODUCER).signer
    assert signer is not None
    env = msgpack.unpackb(encode_patch(patch, signer=signer), raw=False)
    for field, value in (("t_last", env["d"]["t_last"] + 1.0), ("seq", env["d"]["seq"] + 1), ("producer", 3)):
        forged = dict(env["d"], **{field: value})
        forged["checksum"] = wire._checksum(forged, forged["payload"])  # CRC mended: only the signature is left
        data = msgpack.packb(dict(env, d=forged), use_bin_type=True)
        assert refused(data, patch, load_signing(keys, 1)) in {"signature", "signer"}, field


def test_a_certificate_from_another_authority_or_a_tls_certificate_is_no_signer(
    keys: Path, patch: Patch, tmp_path: Path
) -> None:
    stranger = tmp_path / "stranger"
    make_certs(stranger, drones=3)  # its own CA: TLS certificates and signing certificates
    foreign = load_signing(stranger, PRODUCER).signer
    assert foreign is not None
    ours = load_signing(keys, 1)
    assert refused(encode_patch(patch, signer=foreign), patch, ours) == "signer"
    # the stranger's TLS certificate for drone 2 (ECDSA) does not sign patches even for its own authority
    tls = (stranger / "drone-2.pem").read_bytes()
    tls_der = x509.load_pem_x509_certificate(tls).public_bytes(serialization.Encoding.DER)
    theirs = load_signing(stranger, 1)
    posing = replace(foreign, cert_der=tls_der)
    assert refused(encode_patch(patch, signer=posing), patch, theirs) == "signer"


def test_a_mapper_signs_what_it_seals_and_verifies_what_it_receives(keys: Path, patch: Patch) -> None:
    settings = MappingSettings(voxel_size_m=0.2, patch_frames=1)
    producer = Mapper(settings, PRODUCER, 7, BOUNDS, signing=load_signing(keys, PRODUCER))
    frame = rotate_in_place()[0]
    sealed = producer.integrate(frame.depth, frame.K, frame.T, frame.t, MAX_RANGE)
    assert sealed is not None
    data = producer.data(sealed.id)
    assert data is not None
    receiver = Mapper(settings, 1, 8, BOUNDS, signing=load_signing(keys, 1))
    assert receiver.receive_wire(data, sealed.id, MAX_BYTES)
    with pytest.raises(PatchDecodeError) as refusal:
        receiver.receive_wire(
            encode_patch(replace(patch, id=PatchId(PRODUCER, 9, 0))), PatchId(PRODUCER, 9, 0), MAX_BYTES
        )
    assert refusal.value.reason == "unsigned" and not receiver.holds(PatchId(PRODUCER, 9, 0))
    with pytest.raises(ValueError, match="not 1's"):
        Mapper(settings, 1, 8, BOUNDS, signing=load_signing(keys, PRODUCER))


def test_signing_material_that_cannot_be_used_is_one_clear_line(keys: Path, tmp_path: Path) -> None:
    with pytest.raises(SigningError, match=r"cannot read certificate .*ca\.pem"):
        load_signing(tmp_path, 1)
    with pytest.raises(SigningError, match=r"drone-9\.sign\.pem"):
        load_signing(keys, 9)
    mixed = tmp_path / "mixed"
    mixed.mkdir()
    for name in ("ca.pem",):
        (mixed / name).write_bytes((keys / name).read_bytes())
    signing_cert_path(mixed, 1).write_bytes(signing_cert_path(keys, 1).read_bytes())
    signing_key_path(mixed, 1).write_bytes(signing_key_path(keys, 2).read_bytes())
    with pytest.raises(SigningError, match="does not certify the key"):
        load_signing(mixed, 1)
    signing_key_path(mixed, 1).write_text("not a key")
    with pytest.raises(SigningError, match="not a PEM private key"):
        load_signing(mixed, 1)
    signing_key_path(mixed, 1).write_bytes(signing_key_path(keys, 1).read_bytes())
    signing_cert_path(mixed, 1).write_bytes(signing_cert_path(keys, 2).read_bytes())  # drone 2's, for drone 1
    with pytest.raises(SigningError):
        load_signing(mixed, 1)
    assert oct(signing_key_path(keys, 1).stat().st_mode & 0o777) == "0o600"
