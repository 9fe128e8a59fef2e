"""TLS for the station's LAN services: the certificate files given, or a self-signed one made on first start.

``certificate(directory, cert=None, key=None, hosts=...)`` returns a :class:`Certificate` (PEM files and the
certificate's SHA-256 fingerprint, which the operator reads out to whoever connects, so they can check what
their client shows). Given files are used as they are; otherwise ``directory/station-cert.pem`` and
``station-key.pem`` are reused, or made once (RSA 2048, two years, this PC's names and addresses and the OPC UA
application URI in its subject alternative names: OPC UA's Basic256Sha256 needs an RSA key and the URI).
The key file is written with mode 0600.
"""

from __future__ import annotations

import datetime as dt
import ipaddress
import os
import socket
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

CERT_NAME, KEY_NAME = "station-cert.pem", "station-key.pem"
APPLICATION_URI = "urn:cmm-station:opcua"


@dataclass(frozen=True)
class Certificate:
    cert_path: Path
    key_path: Path
    fingerprint: str  # SHA-256, "AB:CD:..."
    made: bool = False  # made now (self-signed), not found or given

    def ssl_context(self):  # noqa: ANN201 - ssl.SSLContext for a server (the pendant's WebSocket, a web server)
        import ssl

        ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
        ctx.minimum_version = ssl.TLSVersion.TLSv1_2
        ctx.load_cert_chain(str(self.cert_path), str(self.key_path))
        return ctx


def fingerprint(cert_path: str | Path) -> str:
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes

    data = Path(cert_path).read_bytes()
    cert = x509.load_pem_x509_certificate(data) if b"-----BEGIN" in data else x509.load_der_x509_certificate(data)
    return ":".join(f"{b:02X}" for b in cert.fingerprint(hashes.SHA256()))


def certificate(directory: str | Path, cert: str | Path | None = None, key: str | Path | None = None, *,
                hosts: Iterable[str] = (), application_uri: str = APPLICATION_URI) -> Certificate:
    """The station's certificate (see the module text); ValueError names a missing or unreadable file."""
    if (cert is None) != (key is None):
        raise ValueError("give both the certificate and its key (--tls-cert FILE --tls-key FILE), or neither")
    if cert is not None:
        for p in (cert, key):
            if not Path(p).is_file():
                raise ValueError(f"the TLS file {p} does not exist")
        try:
            return Certificate(Path(cert), Path(key), fingerprint(cert))
        except ValueError as exc:
            raise ValueError(f"the certificate {cert} cannot be read: {exc}") from None
    folder = Path(directory)
    cert_path, key_path = folder / CERT_NAME, folder / KEY_NAME
    if cert_path.is_file() and key_path.is_file():
        return Certificate(cert_path, key_path, fingerprint(cert_path))
    make(cert_path, key_path, hosts=hosts, application_uri=application_uri)
    return Certificate(cert_path, key_path, fingerprint(cert_path), made=True)


def make(cert_path: Path, key_path: Path, *, hosts: Iterable[str] = (), application_uri: str = APPLICATION_URI,
         common_name: str | None = None, days: int = 730) -> None:
    """Write a self-signed certificate and its RSA key (PEM)."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import rsa
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    key = rsa.generate_private_key(public_exponent=65537, key_size=2048)
    name = common_name or f"CMM station {socket.gethostname()}"
    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name[:64])])
    names: list[x509.GeneralName] = [x509.UniformResourceIdentifier(application_uri)]
    for host in {"localhost", socket.gethostname(), "127.0.0.1", *hosts}:
        try:
            names.append(x509.IPAddress(ipaddress.ip_address(host)))
        except ValueError:
            names.append(x509.DNSName(host))
    now = dt.datetime.now(dt.timezone.utc)
    cert = (x509.CertificateBuilder().subject_name(subject).issuer_name(subject).public_key(key.public_key())
            .serial_number(x509.random_serial_number()).not_valid_before(now - dt.timedelta(minutes=5))
            .not_valid_after(now + dt.timedelta(days=days))
            .add_extension(x509.SubjectAlternativeName(names), critical=False)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.KeyUsage(digital_signature=True, content_commitment=True, key_encipherment=True,
                                         data_encipherment=True, key_agreement=False, key_cert_sign=False,
                                         crl_sign=False, encipher_only=False, decipher_only=False), critical=True)
            .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]),
                           critical=False)
            .sign(key, hashes.SHA256()))
    cert_path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(key_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.TraditionalOpenSSL,
                                  serialization.NoEncryption()))
    cert_path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
