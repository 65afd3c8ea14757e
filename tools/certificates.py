"""The certificates of a secure set (:func:`tools.secure.write_secure_set`): the CA, kept and reused, and a leaf
certificate and key per identity, EC P-256 and SHA-256, valid for :data:`VALID_DAYS` days.

A module of its own so that only the processes that write a set import cryptography::

    ca_key, ca = load_or_make_ca(folder, "ca.pem", "ca.key")
    cert_pem, key_pem = leaf(ca_key, ca, "actor-0", ["actor-0"], server=False)
    write_file(folder / "actor-0.key", key_pem, SECRET)
"""

from __future__ import annotations

import datetime
import ipaddress
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

VALID_DAYS = 365
SECRET, PUBLIC = 0o600, 0o644


def write_file(path: Path, data: bytes, mode: int) -> None:
    # Created with its final mode: a key is never readable by others, not even between open and chmod.
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, mode)
    try:
        os.write(fd, data)
    finally:
        os.close(fd)
    os.chmod(path, mode)


def _key() -> ec.EllipticCurvePrivateKey:
    return ec.generate_private_key(ec.SECP256R1())


def _pem_key(key: ec.EllipticCurvePrivateKey) -> bytes:
    return key.private_bytes(
        serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
    )


def _name(common_name: str) -> x509.Name:
    return x509.Name(
        [x509.NameAttribute(NameOID.ORGANIZATION_NAME, "ennc-ql"), x509.NameAttribute(NameOID.COMMON_NAME, common_name)]
    )


def _builder(subject: x509.Name, issuer: x509.Name, public_key: Any) -> x509.CertificateBuilder:
    now = datetime.datetime.now(datetime.UTC)
    return (
        x509.CertificateBuilder()
        .subject_name(subject)
        .issuer_name(issuer)
        .public_key(public_key)
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))  # clocks of other machines may lag a little
        .not_valid_after(now + datetime.timedelta(days=VALID_DAYS))
    )


def load_or_make_ca(folder: Path, cert_file: str, key_file: str) -> tuple[ec.EllipticCurvePrivateKey, x509.Certificate]:
    cert_path, key_path = folder / cert_file, folder / key_file
    if cert_path.exists() and key_path.exists():
        key = serialization.load_pem_private_key(key_path.read_bytes(), password=None)
        if not isinstance(key, ec.EllipticCurvePrivateKey):
            raise ValueError(f"{key_path} is not an EC private key written by ennc-ql secure init")
        return key, x509.load_pem_x509_certificate(cert_path.read_bytes())
    key = _key()
    name = _name("ennc-ql CA")
    cert = (
        _builder(name, name, key.public_key())
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(
            x509.KeyUsage(False, False, False, False, False, True, True, False, False), critical=True
        )  # key_cert_sign and crl_sign only
        .sign(key, hashes.SHA256())
    )
    write_file(key_path, _pem_key(key), SECRET)
    write_file(cert_path, cert.public_bytes(serialization.Encoding.PEM), PUBLIC)
    return key, cert


def _alt_names(hosts: Sequence[str]) -> list[x509.GeneralName]:
    names: list[x509.GeneralName] = []
    for host in hosts:
        try:
            names.append(x509.IPAddress(ipaddress.ip_address(host)))
        except ValueError:
            names.append(x509.DNSName(host))
    return names


def leaf(
    ca_key: ec.EllipticCurvePrivateKey, ca: x509.Certificate, ident: str, hosts: Sequence[str], server: bool
) -> tuple[bytes, bytes]:
    key = _key()
    usage = [ExtendedKeyUsageOID.SERVER_AUTH] if server else [ExtendedKeyUsageOID.CLIENT_AUTH]
    cert = (
        _builder(_name(ident), ca.subject, key.public_key())
        # A leaf: zenoh's TLS (rustls) refuses a CA certificate presented as an end entity.
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(x509.SubjectAlternativeName(_alt_names(hosts)), critical=False)
        .add_extension(x509.ExtendedKeyUsage(usage), critical=False)
        .sign(ca_key, hashes.SHA256())
    )
    return cert.public_bytes(serialization.Encoding.PEM), _pem_key(key)
