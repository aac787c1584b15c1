"""`swarm deploy certs`: a certificate authority and one certificate per drone, for Zenoh over mutual TLS.

Layout of the directory (PEM files; private keys are mode 0600):

    ca.pem, ca.key             the swarm's CA (keep ca.key off the drones; it signs new drones)
    drone-<k>.pem, drone-<k>.key   drone k: common name "drone-<k>", what access control keys on
    drone-<k>.sign.pem, .sign.key  drone k's patch signing certificate and Ed25519 key (swarm.patches.signing)
    observer.pem, observer.key     the ground station / mission observer: may listen, never publish

Every drone needs ca.pem plus its own two pairs. Keys are ECDSA P-256; certificates carry both server and client
use, since every Zenoh session both listens and dials. Names are not bound to addresses: drones change
addresses (and the simulated radio picks them at run time), so sessions check the CA signature and the common
name, not the host name (`verify_name_on_connect` off, swarm/bus/session.py).
"""

from __future__ import annotations

import datetime
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec, ed25519
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from swarm.bus.keys import MAX_AGENT_ID
from swarm.config import TLS_OBSERVER_NAME, ConfigError, tls_drone_name
from swarm.patches.signing import signing_cert_path, signing_key_path, write_private_key

CA_NAME = "ca"
CA_COMMON_NAME = "swarm-ca"
DEFAULT_DAYS = 365
_BACKDATE = datetime.timedelta(minutes=10)  # tolerate drones whose clocks run a little behind


def cert_path(directory: Path, name: str) -> Path:
    return directory / f"{name}.pem"


def key_path(directory: Path, name: str) -> Path:
    return directory / f"{name}.key"


def _name(common_name: str) -> x509.Name:
    return x509.Name(
        [x509.NameAttribute(NameOID.ORGANIZATION_NAME, "swarm"), x509.NameAttribute(NameOID.COMMON_NAME, common_name)]
    )


def _validity(builder: x509.CertificateBuilder, days: int) -> x509.CertificateBuilder:
    now = datetime.datetime.now(datetime.UTC)
    return builder.not_valid_before(now - _BACKDATE).not_valid_after(now + datetime.timedelta(days=days))


def _key_usage(certifies: bool) -> x509.KeyUsage:
    """Digital signatures, and either certificates and CRLs (the CA) or content commitment (patch signing)."""
    return x509.KeyUsage(
        digital_signature=True,
        content_commitment=not certifies,
        key_cert_sign=certifies,
        crl_sign=certifies,
        key_encipherment=False,
        data_encipherment=False,
        key_agreement=False,
        encipher_only=False,
        decipher_only=False,
    )


def _make_ca(days: int) -> tuple[ec.EllipticCurvePrivateKey, x509.Certificate]:
    key = ec.generate_private_key(ec.SECP256R1())
    builder = (
        x509.CertificateBuilder()
        .subject_name(_name(CA_COMMON_NAME))
        .issuer_name(_name(CA_COMMON_NAME))
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(_key_usage(certifies=True), critical=True)
    )
    return key, _validity(builder, days).sign(key, hashes.SHA256())


def _make_leaf(
    ca_key: ec.EllipticCurvePrivateKey, ca: x509.Certificate, common_name: str, days: int
) -> tuple[ec.EllipticCurvePrivateKey, x509.Certificate]:
    key = ec.generate_private_key(ec.SECP256R1())
    builder = (
        x509.CertificateBuilder()
        .subject_name(_name(common_name))
        .issuer_name(ca.subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .add_extension(x509.SubjectAlternativeName([x509.DNSName(common_name)]), critical=False)
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(
            x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False
        )
    )
    return key, _validity(builder, days).sign(ca_key, hashes.SHA256())


def _make_signing_leaf(
    ca_key: ec.EllipticCurvePrivateKey, ca: x509.Certificate, agent_id: int, days: int
) -> tuple[ed25519.Ed25519PrivateKey, x509.Certificate]:
    """Drone `agent_id`'s patch signing key and certificate: Ed25519, digital signatures only, no TLS use."""
    key = ed25519.Ed25519PrivateKey.generate()
    builder = (
        x509.CertificateBuilder()
        .subject_name(_name(tls_drone_name(agent_id)))
        .issuer_name(ca.subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(_key_usage(certifies=False), critical=True)
    )
    return key, _validity(builder, days).sign(ca_key, hashes.SHA256())


def _new_authority(directory: Path, drones: int, days: int) -> tuple[ec.EllipticCurvePrivateKey, x509.Certificate]:
    if not 1 <= drones <= MAX_AGENT_ID:
        raise ConfigError(f"--drones must be 1 to {MAX_AGENT_ID}, got {drones}")
    if not 1 <= days <= 3650:
        raise ConfigError(f"--days must be 1 to 3650, got {days}")
    if cert_path(directory, CA_NAME).exists() or key_path(directory, CA_NAME).exists():
        raise ConfigError(f"{directory} already holds a CA ({CA_NAME}.pem); choose another directory")
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"cannot create {directory}: {exc.strerror}") from None
    ca_key, ca = _make_ca(days)
    write_private_key(ca_key, key_path(directory, CA_NAME))
    cert_path(directory, CA_NAME).write_bytes(ca.public_bytes(serialization.Encoding.PEM))
    for k in range(1, drones + 1):
        sign_key, sign_cert = _make_signing_leaf(ca_key, ca, k, days)
        write_private_key(sign_key, signing_key_path(directory, k))
        signing_cert_path(directory, k).write_bytes(sign_cert.public_bytes(serialization.Encoding.PEM))
    return ca_key, ca


def make_signing_authority(directory: Path, drones: int, days: int = DEFAULT_DAYS) -> None:
    """A per-mission authority and patch signing certificates for drones 1..`drones`, for a swarm without TLS
    (`swarm run` writes one to OUT/keys). Refuses a directory that already holds a CA."""
    _new_authority(directory, drones, days)


def make_certs(directory: Path, drones: int, days: int = DEFAULT_DAYS) -> list[str]:
    """Write a new CA, TLS certificates for drones 1..`drones` and the observer, and the drones' patch signing
    certificates; returns the TLS names written.

    Refuses (ConfigError) a directory that already holds a CA, so that a running swarm's keys are never
    replaced by accident."""
    ca_key, ca = _new_authority(directory, drones, days)
    names = [tls_drone_name(k) for k in range(1, drones + 1)] + [TLS_OBSERVER_NAME]
    for name in names:
        key, cert = _make_leaf(ca_key, ca, name, days)
        write_private_key(key, key_path(directory, name))
        cert_path(directory, name).write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    return [CA_NAME, *names]


def certs_command(directory: Path, drones: int, days: int) -> int:
    names = make_certs(directory, drones, days)
    print(
        f"swarm deploy certs: wrote {len(names)} certificates to {directory} "
        f"(ca, drone-1..drone-{drones}, observer), valid {days} days"
    )
    print(
        f"  each drone needs {CA_NAME}.pem, its own drone-<id>.pem/.key and drone-<id>.sign.pem/.sign.key; "
        f"keep {CA_NAME}.key off the drones"
    )
    return 0
