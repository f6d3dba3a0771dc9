"""Test certificates for mutual TLS on the Zenoh links: one certificate authority and a
certificate per identity (``ivfm ground certs``).

Each certificate's common name is its identity, the one the vehicles' access control
reads: only ``ground`` may query their perturbation and command services. They are for
rehearsals and tests: a fleet's own certificates come from its own authority.
"""

from __future__ import annotations

import datetime
import ipaddress
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import NameOID

from contracts.atomic_file import write_atomic

VALID_DAYS = 365
DEFAULT_NAMES = ("ground", "vehicle")
DEFAULT_HOSTS = ("localhost", "127.0.0.1")


def _write_key(path: Path, key: ec.EllipticCurvePrivateKey) -> None:
    data = key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                             serialization.NoEncryption())
    write_atomic(path, data, private=True)  # keys: owner only


def _san(host: str) -> x509.GeneralName:
    try:
        return x509.IPAddress(ipaddress.ip_address(host))
    except ValueError:
        return x509.DNSName(host)


def make_certificates(out_dir: Path, names: tuple[str, ...] = DEFAULT_NAMES,
                      hosts: tuple[str, ...] = DEFAULT_HOSTS) -> list[Path]:
    """``ca.pem`` (and its key) and, per name, ``NAME.pem`` and ``NAME-key.pem``, valid
    for ``hosts`` (the addresses the peers reach each other at). Returns the files."""
    for name in names:
        if not name or not all(c.isalnum() or c in "-_." for c in name):
            raise ValueError(f"identity {name!r}: letters, digits, '-', '_' and '.' only")
    out_dir.mkdir(parents=True, exist_ok=True)
    now = datetime.datetime.now(datetime.UTC)
    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca_name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "ivfm test authority")])
    ca = (x509.CertificateBuilder().subject_name(ca_name).issuer_name(ca_name)
          .public_key(ca_key.public_key()).serial_number(x509.random_serial_number())
          .not_valid_before(now).not_valid_after(now + datetime.timedelta(days=VALID_DAYS))
          .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
          .add_extension(x509.KeyUsage(False, False, False, False, False, True, True, False,
                                       False), critical=True)
          .sign(ca_key, hashes.SHA256()))
    written = [out_dir / "ca.pem", out_dir / "ca-key.pem"]
    write_atomic(written[0], ca.public_bytes(serialization.Encoding.PEM))
    _write_key(written[1], ca_key)
    for name in names:
        key = ec.generate_private_key(ec.SECP256R1())
        cert = (x509.CertificateBuilder()
                .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)]))
                .issuer_name(ca_name).public_key(key.public_key())
                .serial_number(x509.random_serial_number()).not_valid_before(now)
                .not_valid_after(now + datetime.timedelta(days=VALID_DAYS))
                .add_extension(x509.SubjectAlternativeName([_san(h) for h in hosts]),
                               critical=False)
                .add_extension(x509.BasicConstraints(ca=False, path_length=None),
                               critical=True)
                .add_extension(x509.ExtendedKeyUsage(
                    [x509.ExtendedKeyUsageOID.SERVER_AUTH,
                     x509.ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False)
                .sign(ca_key, hashes.SHA256()))
        write_atomic(out_dir / f"{name}.pem", cert.public_bytes(serialization.Encoding.PEM))
        _write_key(out_dir / f"{name}-key.pem", key)
        written += [out_dir / f"{name}.pem", out_dir / f"{name}-key.pem"]
    return written
