"""Certificates and keys for the throw-away control plane, made with the openssl CLI.

Why openssl and not a Python library: it is already on every machine here and
keeps the test bed free of another dependency. ECDSA P-256 keys keep per-user
certificates fast to mint (tests create tenant users on demand).
"""

from __future__ import annotations

import subprocess
from dataclasses import dataclass
from pathlib import Path

from armnet_testbed.procs import require_tool

_DAYS = "3650"


def _openssl(*args: str, cwd: Path) -> None:
    result = subprocess.run(
        [require_tool("openssl"), *args], cwd=cwd, capture_output=True, text=True, check=False
    )
    if result.returncode != 0:
        raise RuntimeError(f"openssl {' '.join(args)} failed:\n{result.stderr}")


def _ec_key(path: Path, cwd: Path) -> None:
    _openssl("genpkey", "-algorithm", "EC", "-pkeyopt", "ec_paramgen_curve:P-256",
             "-out", str(path), cwd=cwd)


@dataclass(frozen=True)
class Pki:
    """Paths of the control plane's CA, serving certificate and service-account keys."""

    dir: Path
    ca_cert: Path
    ca_key: Path
    server_cert: Path
    server_key: Path
    sa_key: Path
    sa_pub: Path

    def client_cert(self, name: str, groups: tuple[str, ...]) -> tuple[Path, Path]:
        """A client certificate for user ``name`` (CN) in ``groups`` (O=, one per group)."""
        safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in name)
        key, csr, crt = (self.dir / f"user-{safe}.{ext}" for ext in ("key", "csr", "crt"))
        subject = f"/CN={name}" + "".join(f"/O={g}" for g in groups)
        _ec_key(key, self.dir)
        _openssl("req", "-new", "-key", str(key), "-subj", subject, "-out", str(csr), cwd=self.dir)
        ext = self.dir / "client.ext"
        ext.write_text("extendedKeyUsage=clientAuth\n")
        _openssl("x509", "-req", "-in", str(csr), "-CA", str(self.ca_cert), "-CAkey",
                 str(self.ca_key), "-CAcreateserial", "-days", _DAYS, "-extfile", str(ext),
                 "-out", str(crt), cwd=self.dir)
        return crt, key

    def serving_cert(self, name: str, ips: tuple[str, ...],
                     dns: tuple[str, ...] = ()) -> tuple[Path, Path]:
        """A TLS serving certificate for ``name`` valid for ``ips`` and ``dns`` names.

        Used for a test-bed kubelet: the apiserver checks it against this CA.
        """
        safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in name)
        key, csr, crt = (self.dir / f"serving-{safe}.{ext}" for ext in ("key", "csr", "crt"))
        _ec_key(key, self.dir)
        _openssl("req", "-new", "-key", str(key), "-subj", f"/CN={name}", "-out", str(csr),
                 cwd=self.dir)
        ext = self.dir / f"serving-{safe}.ext"
        sans = ",".join([f"IP:{ip}" for ip in ips] + [f"DNS:{d}" for d in dns])
        ext.write_text(f"subjectAltName={sans}\nextendedKeyUsage=serverAuth\n")
        _openssl("x509", "-req", "-in", str(csr), "-CA", str(self.ca_cert), "-CAkey",
                 str(self.ca_key), "-CAcreateserial", "-days", _DAYS, "-extfile", str(ext),
                 "-out", str(crt), cwd=self.dir)
        return crt, key


def create_pki(directory: Path) -> Pki:
    """CA, a serving cert for 127.0.0.1/localhost/kubernetes.default.svc, and the SA key pair."""
    directory.mkdir(parents=True, exist_ok=True)
    d = directory
    _ec_key(d / "ca.key", d)
    _openssl("req", "-x509", "-new", "-key", "ca.key", "-subj", "/CN=armnet-testbed-ca",
             "-days", _DAYS, "-out", "ca.crt", cwd=d)
    _ec_key(d / "apiserver.key", d)
    _openssl("req", "-new", "-key", "apiserver.key", "-subj", "/CN=kube-apiserver",
             "-out", "apiserver.csr", cwd=d)
    (d / "server.ext").write_text(
        "subjectAltName=IP:127.0.0.1,IP:10.0.0.1,DNS:localhost,DNS:kubernetes,"
        "DNS:kubernetes.default,DNS:kubernetes.default.svc\nextendedKeyUsage=serverAuth\n"
    )
    _openssl("x509", "-req", "-in", "apiserver.csr", "-CA", "ca.crt", "-CAkey", "ca.key",
             "-CAcreateserial", "-days", _DAYS, "-extfile", "server.ext",
             "-out", "apiserver.crt", cwd=d)
    # Service-account tokens are signed RS256 by default; keep RSA here.
    _openssl("genpkey", "-algorithm", "RSA", "-pkeyopt", "rsa_keygen_bits:2048",
             "-out", "sa.key", cwd=d)
    _openssl("pkey", "-in", "sa.key", "-pubout", "-out", "sa.pub", cwd=d)
    return Pki(dir=d, ca_cert=d / "ca.crt", ca_key=d / "ca.key", server_cert=d / "apiserver.crt",
               server_key=d / "apiserver.key", sa_key=d / "sa.key", sa_pub=d / "sa.pub")
