"""Mutual TLS with real certificates: a CA, a server (the runtime) and client certificates are
generated here (`cryptography`); LiteVLoc's publisher listens on a `tls/` endpoint with
`enable_mtls`, and only a subscriber with a certificate signed by that CA receives poses."""

from __future__ import annotations

import datetime
import ipaddress
import time
from pathlib import Path

import numpy as np
import pytest

from litevloc.config.schema import ZenohConfig
from litevloc.runtime.transport.bus import Bus, BusError, LiteVLocPublisher
from litevloc.runtime.transport.security import tls_config
from tests.runtime.zenoh_helpers import free_port

x509 = pytest.importorskip("cryptography.x509", reason="the `cryptography` package (dev extra) makes the certificates")
from cryptography.hazmat.primitives import hashes, serialization  # noqa: E402
from cryptography.hazmat.primitives.asymmetric import ec  # noqa: E402
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID  # noqa: E402


def _name(cn: str) -> x509.Name:
    return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn)])


def _builder(subject: str, issuer: x509.Name, key: ec.EllipticCurvePrivateKey) -> x509.CertificateBuilder:
    now = datetime.datetime.now(datetime.timezone.utc)
    return (x509.CertificateBuilder().subject_name(_name(subject)).issuer_name(issuer).public_key(key.public_key())
            .serial_number(x509.random_serial_number()).not_valid_before(now - datetime.timedelta(minutes=5))
            .not_valid_after(now + datetime.timedelta(days=1)))


def _write(folder: Path, stem: str, key: ec.EllipticCurvePrivateKey, cert: x509.Certificate) -> None:
    (folder / f"{stem}.key").write_bytes(key.private_bytes(
        serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()))
    (folder / f"{stem}.pem").write_bytes(cert.public_bytes(serialization.Encoding.PEM))


def make_pki(folder: Path, ca_name: str, leaves: list[str]) -> None:
    """`<ca_name>.pem/.key` (a self-signed CA) and `<leaf>.pem/.key` signed by it, valid for
    localhost / 127.0.0.1 as server and client (EC P-256, SHA-256)."""
    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca = (_builder(ca_name, _name(ca_name), ca_key)
          .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
          .add_extension(x509.KeyUsage(digital_signature=True, content_commitment=False, key_encipherment=False,
                                       data_encipherment=False, key_agreement=False, key_cert_sign=True,
                                       crl_sign=True, encipher_only=False, decipher_only=False), critical=True)
          .sign(ca_key, hashes.SHA256()))
    _write(folder, ca_name, ca_key, ca)
    for leaf in leaves:
        key = ec.generate_private_key(ec.SECP256R1())
        cert = (_builder(leaf, ca.subject, key)
                .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
                .add_extension(x509.SubjectAlternativeName(
                    [x509.DNSName("localhost"), x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]), critical=False)
                .add_extension(x509.ExtendedKeyUsage(
                    [ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False)
                .sign(ca_key, hashes.SHA256()))
        _write(folder, leaf, key, cert)


def test_tls_config_block() -> None:
    b = tls_config("/ca.pem", "/me.pem", "/me.key")
    assert b["enable_mtls"] and b["listen_certificate"] == "/me.pem" and b["connect_private_key"] == "/me.key"
    c = tls_config("/ca.pem", mtls=False, listen=False)
    assert c == {"root_ca_certificate": "/ca.pem", "enable_mtls": False, "verify_name_on_connect": True}
    with pytest.raises(ValueError, match="mutual TLS"):
        tls_config("/ca.pem")
    with pytest.raises(ValueError, match="both"):
        tls_config("/ca.pem", "/me.pem")


@pytest.mark.timeout(90)
def test_mutual_tls_only_clients_with_a_valid_certificate_receive(tmp_path: Path) -> None:
    make_pki(tmp_path, "ca", ["litevloc", "planner"])
    make_pki(tmp_path, "rogue_ca", ["rogue"])  # a second CA: its certificates are not trusted by the runtime
    p = {name: str(tmp_path / name) for name in ("ca.pem", "litevloc.pem", "litevloc.key", "planner.pem",
                                                   "planner.key", "rogue_ca.pem", "rogue.pem", "rogue.key")}
    ep = f"tls/127.0.0.1:{free_port()}"
    runtime = ZenohConfig(listen=(ep,), tls=tls_config(p["ca.pem"], p["litevloc.pem"], p["litevloc.key"]))

    def client(ca: str, cert: str | None, key: str | None, require: bool = False) -> ZenohConfig:
        return ZenohConfig(listen=(), connect=(ep,), require_connect=require, connect_timeout_s=1.0,
                           tls=tls_config(ca, cert, key, mtls=cert is not None, listen=False))

    cases = {  # name -> (config, poses expected)
        "no client certificate": client(p["ca.pem"], None, None),
        "certificate from another CA": client(p["ca.pem"], p["rogue.pem"], p["rogue.key"]),
        "valid certificate, but trusts another CA": client(p["rogue_ca.pem"], p["planner.pem"], p["planner.key"]),
        "valid certificate": client(p["ca.pem"], p["planner.pem"], p["planner.key"]),
    }
    received: dict[str, int] = {}
    with Bus(runtime) as bus:
        pub = LiteVLocPublisher(bus)
        for name, cfg in cases.items():
            got: list[bytes] = []
            with Bus(cfg) as cb:
                sub = cb.subscribe("litevloc/pose", lambda s, got=got: got.append(bytes(s.payload.to_bytes())))
                t_end = time.monotonic() + 2.0  # the valid client is matched within this; the others never are
                while time.monotonic() < t_end and not pub.pubs["pose"]._pub.matching_status.matching:
                    time.sleep(0.02)
                for i in range(20):
                    pub.publish_pose(1_000_000 * (i + 1), np.eye(4), None)
                    time.sleep(0.01)
                time.sleep(0.4)
                received[name] = len(got)
                connected = cb.connectivity()["connected"]
                sub.undeclare()
            assert connected == (name == "valid certificate"), (name, connected)
        # a client without a certificate that requires the connection fails to start, naming the endpoint
        with pytest.raises(BusError, match=ep.split("/")[1]):
            Bus(client(p["ca.pem"], None, None, require=True))
    assert received == {"no client certificate": 0, "certificate from another CA": 0,
                        "valid certificate, but trusts another CA": 0, "valid certificate": 20}, received
