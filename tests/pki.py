"""Certificates for the Modbus/TCP Security tests and bench, made with the openssl command
as README's worked example makes them: a CA, a server certificate (its subjectAltName
chosen), client certificates with a role in the extension 1.3.6.1.4.1.50316.802.1
(UTF8String).  EC P-256 keys (the Secure SunSpec profile's, so the CCM suites apply, and a
handshake costs little).  `openssl ca` signs, for its -startdate/-enddate (expired and
not-yet-valid certificates), revokes, and writes CRLs (crl())."""
import subprocess
from pathlib import Path

ROLE_OID = "1.3.6.1.4.1.50316.802.1"

_CA_CONFIG = """\
[ca]
default_ca = authority
[authority]
dir = {dir}
database = {dir}/index.txt
new_certs_dir = {dir}
serial = {dir}/serial
default_md = sha256
default_days = 30
policy = any
unique_subject = no
copy_extensions = none
crl_extensions = crl_ext
[any]
commonName = supplied
[crl_ext]
authorityKeyIdentifier = keyid:always
"""


def openssl(*args: str, cwd: Path) -> None:
    subprocess.run(["openssl", *args], cwd=cwd, check=True, capture_output=True)


class Authority:
    """A CA in directory/name: ca.pem, ca.key; issue() signs certificates with it."""

    def __init__(self, directory: Path, name: str = "ca") -> None:
        self.dir = directory / name
        self.dir.mkdir(parents=True)
        self.cert = self.dir / "ca.pem"
        self.key = self.dir / "ca.key"
        (self.dir / "index.txt").write_text("")
        (self.dir / "serial").write_text("1000\n")
        self.config = self.dir / "ca.cnf"
        self.config.write_text(_CA_CONFIG.format(dir=self.dir))
        openssl("req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256",
                "-nodes", "-keyout", str(self.key), "-out", str(self.cert), "-days", "30",
                "-subj", f"/CN=mbgw test {name}", cwd=self.dir)

    def issue(self, name: str, role: str | None = None, server: bool = False,
              start: str | None = None, end: str | None = None,
              names: str = "IP:127.0.0.1, DNS:localhost",
              role_der: str | None = None) -> tuple[Path, Path]:
        """(certificate, key) for CN=name; role in the role extension (role_der: the
        extension's value as openssl's ASN1 text, e.g. "ASN1:SEQUENCE:..." or
        "DER:0c00"); server: with names as its subjectAltName; start/end: YYYYMMDDHHMMSSZ,
        else from now for 30 days."""
        key, csr, cert = (self.dir / f"{name}.{ext}" for ext in ("key", "csr", "pem"))
        openssl("req", "-new", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256",
                "-nodes", "-keyout", str(key), "-out", str(csr), "-subj", f"/CN={name}",
                cwd=self.dir)
        lines = ["basicConstraints = CA:FALSE"]
        if server:
            lines += [f"subjectAltName = {names}", "extendedKeyUsage = serverAuth"]
        else:
            lines += ["extendedKeyUsage = clientAuth"]
        if role is not None:
            lines.append(f"{ROLE_OID} = ASN1:UTF8String:{role}")
        if role_der is not None:
            lines.append(f"{ROLE_OID} = {role_der}")
        extensions = self.dir / f"{name}.ext"
        extensions.write_text("\n".join(lines) + "\n")
        dates = (["-startdate", start] if start else []) + (["-enddate", end] if end else [])
        openssl("ca", "-batch", "-notext", "-config", str(self.config), "-cert",
                str(self.cert), "-keyfile", str(self.key), "-in", str(csr), "-out", str(cert),
                "-extfile", str(extensions), *dates, cwd=self.dir)
        return cert, key

    def revoke(self, cert: Path) -> None:
        openssl("ca", "-config", str(self.config), "-cert", str(self.cert), "-keyfile",
                str(self.key), "-revoke", str(cert), cwd=self.dir)

    def crl(self, path: Path, hours: int = 24 * 7) -> Path:
        """The CA's CRL (PEM) into path, its next update `hours` from now (negative: in the
        past, a CRL that is out of date)."""
        if hours >= 0:
            openssl("ca", "-gencrl", "-config", str(self.config), "-cert", str(self.cert),
                    "-keyfile", str(self.key), "-crlhours", str(hours), "-out", str(path),
                    cwd=self.dir)
            return path
        return self._stale_crl(path, hours)

    def _stale_crl(self, path: Path, hours: int) -> Path:
        """A CRL whose next update has passed: openssl ca cannot date one in the past, so
        python3-cryptography signs it with the CA's key."""
        import datetime

        from cryptography import x509
        from cryptography.hazmat.primitives import hashes, serialization
        ca = x509.load_pem_x509_certificate(self.cert.read_bytes())
        key = serialization.load_pem_private_key(self.key.read_bytes(), password=None)
        now = datetime.datetime.utcnow()
        crl = (x509.CertificateRevocationListBuilder().issuer_name(ca.subject)
               .last_update(now + datetime.timedelta(hours=hours - 24))
               .next_update(now + datetime.timedelta(hours=hours))
               .sign(key, hashes.SHA256()))  # type: ignore[arg-type]
        path.write_bytes(crl.public_bytes(serialization.Encoding.PEM))
        return path
