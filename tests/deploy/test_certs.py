"""`swarm deploy certs`: the CA and per-drone certificates for mutual TLS (the sessions are tested in
tests/bus/test_tls.py)."""

from __future__ import annotations

import stat
from pathlib import Path

import pytest
from cryptography import x509
from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import serialization
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from swarm.config import ConfigError
from swarm.deploy.certs import make_certs
from tests.deploy.test_cli_deploy import one_line, swarm


def _cert(path: Path) -> x509.Certificate:
    return x509.load_pem_x509_certificate(path.read_bytes())


def _common_name(cert: x509.Certificate) -> str:
    return cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value


def test_every_drone_and_the_observer_get_a_certificate_signed_by_the_swarm_ca(tmp_path: Path) -> None:
    names = make_certs(tmp_path, drones=3, days=30)
    assert names == ["ca", "drone-1", "drone-2", "drone-3", "observer"]
    ca = _cert(tmp_path / "ca.pem")
    assert ca.extensions.get_extension_for_class(x509.BasicConstraints).value.ca
    for name in names[1:]:
        cert = _cert(tmp_path / f"{name}.pem")
        assert _common_name(cert) == name
        cert.verify_directly_issued_by(ca)  # raises if the signature or issuer is wrong
        usage = cert.extensions.get_extension_for_class(x509.ExtendedKeyUsage).value
        assert {ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH} <= set(usage)
        assert (cert.not_valid_after_utc - cert.not_valid_before_utc).days == 30
        key = serialization.load_pem_private_key((tmp_path / f"{name}.key").read_bytes(), password=None)
        assert key.public_key().public_numbers() == cert.public_key().public_numbers()
    for key_file in tmp_path.glob("*.key"):
        assert stat.S_IMODE(key_file.stat().st_mode) == 0o600, key_file


def test_two_runs_make_two_unrelated_cas(tmp_path: Path) -> None:
    make_certs(tmp_path / "a", drones=1)
    make_certs(tmp_path / "b", drones=1)
    with pytest.raises(InvalidSignature):  # same names, other key
        _cert(tmp_path / "b" / "drone-1.pem").verify_directly_issued_by(_cert(tmp_path / "a" / "ca.pem"))


def test_an_existing_ca_is_never_overwritten(tmp_path: Path) -> None:
    make_certs(tmp_path, drones=1)
    before = (tmp_path / "ca.key").read_bytes()
    with pytest.raises(ConfigError, match="already holds a CA"):
        make_certs(tmp_path, drones=2)
    assert (tmp_path / "ca.key").read_bytes() == before
    assert not (tmp_path / "drone-2.pem").exists()


@pytest.mark.sim
def test_the_command_writes_the_directory_and_refuses_bad_input_in_one_line(tmp_path: Path) -> None:
    done = swarm(tmp_path, "deploy", "certs", "--drones", "2", "--out", "c")
    assert done.returncode == 0, done.stderr
    tls = [f"{n}.{ext}" for n in ("ca", "drone-1", "drone-2", "observer") for ext in ("pem", "key")]
    signing = [f"drone-{k}.sign.{ext}" for k in (1, 2) for ext in ("pem", "key")]
    assert sorted(p.name for p in (tmp_path / "c").iterdir()) == sorted(tls + signing)
    again = swarm(tmp_path, "deploy", "certs", "--drones", "2", "--out", "c")
    assert again.returncode == 2 and "already holds a CA" in one_line(again)
    too_many = swarm(tmp_path, "deploy", "certs", "--drones", "251", "--out", "d")
    assert too_many.returncode == 2 and "--drones must be 1 to 250" in one_line(too_many)
    missing = swarm(tmp_path, "deploy", "certs", "--out", "e")
    assert missing.returncode == 2 and "--drones" in one_line(missing)
