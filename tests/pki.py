"""Certificates for the Modbus/TCP Security tests and bench, made with the openssl command
as README's worked example makes them: a CA, a server certificate, client certificates with
a role in the extension 1.3.6.1.4.1.50316.802.1 (UTF8String).  EC P-256 keys, so that a
handshake costs little.  `openssl ca` signs, for its -startdate/-enddate (expired and
not-yet-valid certificates)."""
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
[any]
commonName = supplied
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
              start: str | None = None, end: str | None = None) -> tuple[Path, Path]:
        """(certificate, key) for CN=name; role in the role extension; server: for
        127.0.0.1; start/end: YYYYMMDDHHMMSSZ, else from now for 30 days."""
        key, csr, cert = (self.dir / f"{name}.{ext}" for ext in ("key", "csr", "pem"))
        openssl("req", "-new", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256",
                "-nodes", "-keyout", str(key), "-out", str(csr), "-subj", f"/CN={name}",
                cwd=self.dir)
        lines = ["basicConstraints = CA:FALSE"]
        if server:
            lines += ["subjectAltName = IP:127.0.0.1, DNS:localhost",
                      "extendedKeyUsage = serverAuth"]
        else:
            lines += ["extendedKeyUsage = clientAuth"]
        if role is not None:
            lines.append(f"{ROLE_OID} = ASN1:UTF8String:{role}")
        extensions = self.dir / f"{name}.ext"
        extensions.write_text("\n".join(lines) + "\n")
        dates = (["-startdate", start] if start else []) + (["-enddate", end] if end else [])
        openssl("ca", "-batch", "-notext", "-config", str(self.config), "-cert",
                str(self.cert), "-keyfile", str(self.key), "-in", str(csr), "-out", str(cert),
                "-extfile", str(extensions), *dates, cwd=self.dir)
        return cert, key
