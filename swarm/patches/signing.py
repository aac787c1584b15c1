"""Patches bound to their producer: Ed25519 signatures over a patch's content hash, keys certified by an authority.

Every member of a swarm can send any bytes it likes, so a patch's id is worth nothing unless its content is bound
to its producer. Each drone holds a signing key (Ed25519) and a *signing certificate* for it, issued by the
swarm's authority: the TLS CA when the swarm runs TLS (`swarm deploy certs` writes both kinds), else a per-mission
authority `swarm run` makes in OUT/keys. The certificate names the drone (common name ``drone-<id>``, as its TLS
certificate does) and carries an Ed25519 key; a TLS certificate (ECDSA) is therefore never a signing certificate.

A sealed patch carries its producer's signing certificate (DER, about 400 bytes) and the signature of
``CONTEXT + sha256(header fields, payload)`` (`swarm.patches.wire._content_hash`). A receiver with an authority
checks, before it decompresses anything: the certificate was issued by the authority (checked once per certificate
and cached), it is an Ed25519 signing certificate, it names the patch's producer, and the signature holds.
Otherwise the patch is refused with reason "unsigned" (no signature), "signer" (a certificate that is not the
producer's) or "signature" (a signature that does not hold), counted, and never fused, held or served. A relay
serves the bytes it received, so a relayed patch verifies exactly as its producer's push does.

What this does not check: the certificates' validity dates (a companion computer may boot with no real-time clock;
the TLS layer checks dates where it runs) and revocation (a drone whose key is stolen needs a new authority).
"""

from __future__ import annotations

import hashlib
import os
import warnings
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

from cryptography import x509
from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric import ed25519
from cryptography.hazmat.primitives.asymmetric.types import PrivateKeyTypes
from cryptography.utils import CryptographyDeprecationWarning

from swarm.config import ConfigError, tls_drone_name

# A certificate in a received patch is hostile input: what cryptography warns about in one (a serial number that
# is not positive) is refused or not by the checks below, and must not write to the agent's log per patch.
warnings.filterwarnings("ignore", message="Parsed a serial number", category=CryptographyDeprecationWarning)

CONTEXT = b"swarm-patch-v2\0"  # signed with the hash, so a signature over anything else never verifies a patch
AUTHORITY_FILE = "ca.pem"
MAX_SIGNER_BYTES = 2048  # a signing certificate's DER is about 400 bytes
SIGNATURE_BYTES = 64
_CACHE = 256  # certificates remembered as checked: a swarm has at most a few dozen drones


def signing_cert_path(directory: Path, agent_id: int) -> Path:
    return directory / f"{tls_drone_name(agent_id)}.sign.pem"


def signing_key_path(directory: Path, agent_id: int) -> Path:
    return directory / f"{tls_drone_name(agent_id)}.sign.key"


class SigningError(ConfigError):
    """Signing material that cannot be used (a missing or malformed file): one line for the operator."""


@dataclass(frozen=True)
class PatchSigner:
    """One drone's key and its certificate (DER), which every patch it seals carries."""

    producer: int
    key: ed25519.Ed25519PrivateKey
    cert_der: bytes

    def sign(self, digest: bytes) -> bytes:
        return self.key.sign(CONTEXT + digest)


class PatchVerifier:
    """Checks that a patch was signed by its producer's certified key; `check` returns a refusal reason or None."""

    def __init__(self, authority: x509.Certificate) -> None:
        self.authority = authority
        self._checked: OrderedDict[bytes, tuple[str, ed25519.Ed25519PublicKey] | None] = OrderedDict()

    def check(self, producer: int, cert_der: bytes, signature: bytes, digest: bytes) -> str | None:
        if not signature and not cert_der:
            return "unsigned"
        signer = self._signer(cert_der)
        if signer is None or signer[0] != tls_drone_name(producer):
            return "signer"
        try:
            signer[1].verify(signature, CONTEXT + digest)
        except InvalidSignature:
            return "signature"
        return None

    def signer_name(self, cert_der: bytes) -> str | None:
        """The common name of a signing certificate the authority issued, else None."""
        signer = self._signer(cert_der)
        return None if signer is None else signer[0]

    def _signer(self, cert_der: bytes) -> tuple[str, ed25519.Ed25519PublicKey] | None:
        """(common name, key) of a signing certificate the authority issued, else None; cached by content."""
        fingerprint = hashlib.sha256(cert_der).digest()
        if fingerprint in self._checked:
            self._checked.move_to_end(fingerprint)
            return self._checked[fingerprint]
        signer = self._verify_certificate(cert_der)
        self._checked[fingerprint] = signer
        while len(self._checked) > _CACHE:
            self._checked.popitem(last=False)
        return signer

    def _verify_certificate(self, cert_der: bytes) -> tuple[str, ed25519.Ed25519PublicKey] | None:
        try:
            cert = x509.load_der_x509_certificate(cert_der)
            cert.verify_directly_issued_by(self.authority)
            key = cert.public_key()
            names = cert.subject.get_attributes_for_oid(x509.NameOID.COMMON_NAME)
        except (ValueError, TypeError, InvalidSignature):
            return None
        if not isinstance(key, ed25519.Ed25519PublicKey) or len(names) != 1:
            return None
        return str(names[0].value), key


@dataclass(frozen=True)
class Signing:
    """What one process signs with (None: it only verifies, like the observer) and verifies with."""

    signer: PatchSigner | None
    verifier: PatchVerifier


def load_signing(directory: Path, agent_id: int | None) -> Signing:
    """The authority in `directory`, and drone `agent_id`'s key and certificate there when it is given; raise
    SigningError naming the file otherwise."""
    authority = _read_certificate(directory / AUTHORITY_FILE)
    if agent_id is None:
        return Signing(None, PatchVerifier(authority))
    cert = _read_certificate(signing_cert_path(directory, agent_id))
    key_file = signing_key_path(directory, agent_id)
    try:
        key = serialization.load_pem_private_key(key_file.read_bytes(), password=None)
    except OSError as exc:
        raise SigningError(f"cannot read signing key {key_file}: {exc.strerror}") from None
    except (ValueError, TypeError) as exc:
        raise SigningError(f"{key_file} is not a PEM private key: {exc}") from None
    if not isinstance(key, ed25519.Ed25519PrivateKey):
        raise SigningError(f"{key_file} is not an Ed25519 key")
    public = cert.public_key()
    own = key.public_key().public_bytes_raw()
    if not isinstance(public, ed25519.Ed25519PublicKey) or public.public_bytes_raw() != own:
        raise SigningError(f"{signing_cert_path(directory, agent_id)} does not certify the key in {key_file}")
    verifier = PatchVerifier(authority)
    der = cert.public_bytes(serialization.Encoding.DER)
    checked = verifier.signer_name(der)
    if checked != tls_drone_name(agent_id):
        where = signing_cert_path(directory, agent_id)
        raise SigningError(f"{where} is not drone {agent_id}'s signing certificate issued by {AUTHORITY_FILE}")
    return Signing(PatchSigner(agent_id, key, der), verifier)


def _read_certificate(path: Path) -> x509.Certificate:
    try:
        return x509.load_pem_x509_certificate(path.read_bytes())
    except OSError as exc:
        raise SigningError(f"cannot read certificate {path}: {exc.strerror}") from None
    except ValueError as exc:
        raise SigningError(f"{path} is not a PEM certificate: {exc}") from None


def write_private_key(key: PrivateKeyTypes, path: Path) -> None:
    """PEM, PKCS#8, unencrypted, readable by its owner alone (mode 0600 from creation)."""
    encoding, pkcs8 = serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8
    data = key.private_bytes(encoding, pkcs8, serialization.NoEncryption())
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as out:
        out.write(data)
