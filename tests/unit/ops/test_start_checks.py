"""check-config is the single truth (issue 22, point 3): every file `mbgw run` refuses,
check-config refuses first, both with exit status 78 (EX_CONFIG: the units do not restart on
it) and a message naming the file and the key; `config set` refuses to write a value that is
wrong in itself.  Certificates are made by openssl (tests/pki.py).  The device is /dev/null:
were a file accepted, `run` would fail on it with status 1, never start."""
import socket
from pathlib import Path

import pytest
from click.testing import CliRunner

from mbgw.cli import main
from mbgw.ops import preflight
from tests.pki import Authority

EX_CONFIG = 78
DEVICE = '[serial]\ndevice = "/dev/null"\n'
HASH = "scrypt$16384$8$1$pKL9+dRwx2sQz/yn7xDC/g==$T4ZURuw73qU91t9QEBvgE6nngsqtMOhEM9zzTmqdeYw="


@pytest.fixture(scope="module")
def pki(tmp_path_factory):
    """The CA, a server certificate and its key, another key, a file that is no PEM."""
    directory = tmp_path_factory.mktemp("pki")
    ca = Authority(directory)
    cert, key = ca.issue("server", server=True)
    _, other_key = ca.issue("other", server=True)
    junk = directory / "junk.pem"
    junk.write_text("not a certificate\n")
    foreign_crl = Authority(directory, "other").crl(directory / "other.crl")
    return {"ca": ca.cert, "cert": cert, "key": key, "other_key": other_key, "junk": junk,
            "dir": directory, "foreign_crl": foreign_crl}


def _tls(cert, key, ca) -> str:
    return f'[tls]\ncert = "{cert}"\nkey = "{key}"\nca = "{ca}"\n'


def _taken_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


# (id, the file's text from the pki paths, the key the message names first, words of the why)
BAD_FILES = [
    ("web listen without an admin password",
     lambda p: DEVICE + '[web]\nlisten = "127.0.0.1:8080"\n',
     "web.listen", "no admin password set"),
    ("a tls key that does not match the certificate",
     lambda p: DEVICE + _tls(p["cert"], p["other_key"], p["ca"]),
     "tls.key", "does not match tls.cert"),
    ("an unreadable tls certificate",
     lambda p: DEVICE + _tls(p["dir"] / "none.pem", p["key"], p["ca"]),
     "tls.cert", "cannot be read"),
    ("a tls certificate that is no PEM",
     lambda p: DEVICE + _tls(p["junk"], p["key"], p["ca"]),
     "tls.cert", "not a PEM certificate"),
    ("a tls key that is no key",
     lambda p: DEVICE + _tls(p["cert"], p["junk"], p["ca"]),
     "tls.key", "not an unencrypted PEM private key"),
    ("a CA file that is no certificate",
     lambda p: DEVICE + _tls(p["cert"], p["key"], p["junk"]),
     "tls.ca", "not a PEM certificate"),
    ("a CRL another CA signed",
     lambda p: DEVICE + _tls(p["cert"], p["key"], p["ca"]) + f'crl = "{p["foreign_crl"]}"\n',
     "tls.crl", "not signed by a CA of tls-ca"),
    ("a tls certificate without its key and CA",
     lambda p: DEVICE + f'[tls]\ncert = "{p["cert"]}"\n',
     "tls.cert", "without tls-key and tls-ca"),
    ("mdbport 0 without TLS",
     lambda p: DEVICE + "[net]\nmdbport = 0\n",
     "net.mdbport", "needs TLS"),
    ("a bind address that is no IP address",
     lambda p: DEVICE + '[net]\nbind = "999.0.0.1"\n',
     "net.bind", "'999.0.0.1' is not an IP address"),
    ("a metrics host that does not resolve",
     lambda p: DEVICE + '[general]\nmetrics = "nohost.invalid:9502"\n',
     "general.metrics", "'nohost.invalid'"),
    ("a web host that does not resolve",
     lambda p: DEVICE + f'[web]\nlisten = "nohost.invalid:8080"\nadmin-password = "{HASH}"\n',
     "web.listen", "'nohost.invalid'"),
    ("metrics on the Modbus port",
     lambda p: DEVICE + '[net]\nmdbport = 1502\n[general]\nmetrics = "127.0.0.1:1502"\n',
     "general.metrics", "port 1502 is net.mdbport's already"),
    ("the web console on the TLS port",
     lambda p: DEVICE + _tls(p["cert"], p["key"], p["ca"]) + "port = 1802\n"
     + f'[web]\nlisten = ":1802"\nadmin-password = "{HASH}"\n',
     "web.listen", "port 1802 is tls.port's already"),
    ("web certificate and key that do not go together",
     lambda p: DEVICE + f'[web]\nlisten = "127.0.0.1:8080"\nadmin-password = "{HASH}"\n'
     f'cert = "{p["cert"]}"\nkey = "{p["other_key"]}"\n',
     "web.key", "does not match web.cert"),
    ("the table's file a directory",
     lambda p: DEVICE + f'[table]\nenabled = true\npersist = "{p["dir"]}"\n',
     "table.persist", "is a directory"),
    ("a TLS scenario without the client certificate",
     lambda p: DEVICE + '[[scenario]]\nname = "remote"\nserver = "10.0.0.5"\nfunction = 3\n'
     "address = 0\nquantity = 2\ntable = 0\ncycle = 1000\ntls = true\n",
     "scenario remote", "tls needs tls-client-cert"),
    ("master: a client key that does not match its certificate",
     lambda p: DEVICE + 'mode = "master"\n'
     f'[tls]\nclient-cert = "{p["cert"]}"\nclient-key = "{p["other_key"]}"\n'
     f'server-ca = "{p["ca"]}"\n',
     "tls.client-key", "does not match tls.client-cert"),
    ("master: the table's address in a slaveid range",
     lambda p: DEVICE + 'mode = "master"\n[net]\nslaveid = ["1 8 1 0 192.168.0.30"]\n'
     "[table]\nenabled = true\naddress = 3\n",
     "table.address", "slaveid range 1..8"),
    ("master: the table's port the metrics'",
     lambda p: DEVICE + 'mode = "master"\n[general]\nmetrics = ":1502"\n'
     "[table]\nenabled = true\nport = 1502\n",
     "general.metrics", "port 1502 is table.port's already"),
    ("the RTU-over-TCP port the Modbus port",
     lambda p: DEVICE + "[net]\nmdbport = 1502\nrtu-port = 1502\n",
     "net.rtu-port", "port 1502 is net.mdbport's already"),
    ("the RTU-over-TCP port the web console's",
     lambda p: DEVICE + f'[net]\nrtu-port = 4001\n[web]\nlisten = ":4001"\n'
     f'admin-password = "{HASH}"\n',
     "web.listen", "port 4001 is net.rtu-port's already"),
    ("master: the RTU-over-TCP port the table's",
     lambda p: DEVICE + 'mode = "master"\n[net]\nrtu-port = 1502\n'
     '[table]\nenabled = true\nport = 1502\n[[route]]\nunits = "200"\ntable = true\n',
     "net.rtu-port", "port 1502 is table.port's already"),
    ("master: a udp-port without the TCP face",
     lambda p: DEVICE + 'mode = "master"\n[net]\nudp-port = 1502\n',
     "net.udp-port", "only with a Modbus TCP face"),
    ("a udp-port out of range",
     lambda p: DEVICE + "[net]\nudp-port = 70000\n",
     "net.udp-port", "70000"),
    ("a firewall rule for a listener there is not",
     lambda p: DEVICE + '[[rule]]\nlistener = "serial"\n',
     "rule 1.listener", "'udp' or 'rtu'"),
    ("transparent: the raw port the Modbus port",
     lambda p: DEVICE + 'mode = "transparent"\n[net]\nmdbport = 1502\n'
     "[transparent]\nraw-port = 1502\n",
     "transparent.raw-port", "port 1502 is net.mdbport's already"),
]


def mbgw(*args):
    return CliRunner().invoke(main, [str(a) for a in args], prog_name="mbgw")


@pytest.fixture
def bad_file(tmp_path, pki, request):
    _, text, key, why = request.param
    path = tmp_path / "mbgw.toml"
    path.write_text(text(pki))
    return path, key, why


@pytest.mark.parametrize("bad_file", BAD_FILES, ids=[case[0] for case in BAD_FILES],
                         indirect=True)
def test_what_run_refuses_check_config_refuses_first_naming_the_key(bad_file):
    path, key, why = bad_file
    for command in (("check-config", path), ("run", "--config", path),
                    ("slave" if "mode =" not in path.read_text() else "run", "--config", path)):
        result = mbgw(*command)
        assert result.exit_code == EX_CONFIG, (command, result.output)
        assert f"mbgw: {path}: {key}: " in result.output, (command, result.output)
        assert why in result.output.split(f"{key}: ", 1)[1].splitlines()[0], result.output


def test_a_good_file_passes_with_its_files_and_addresses(tmp_path, pki, monkeypatch):
    monkeypatch.setenv("STATE_DIRECTORY", str(tmp_path))    # where the table's file may be
    path = tmp_path / "mbgw.toml"
    path.write_text(DEVICE + _tls(pki["cert"], pki["key"], pki["ca"])
                    + f'[web]\nlisten = "localhost:8080"\nadmin-password = "{HASH}"\n'
                    f'cert = "{pki["cert"]}"\nkey = "{pki["key"]}"\n'
                    f'[table]\nenabled = true\npersist = "{tmp_path}/table"\n'
                    '[net]\nbind = "127.0.0.1"\n[general]\nmetrics = "127.0.0.1:9502"\n')
    result = mbgw("check-config", path)
    assert result.exit_code == 0, result.output
    assert result.output == f"{path}: ok (slave mode)\n"


def test_a_table_file_whose_directory_is_not_there_yet_is_no_refusal(tmp_path, monkeypatch):
    """The daemon runs on, reports the failing saves and saves once the directory is there
    (tests/integration/table/test_table_slave.py)."""
    monkeypatch.setenv("STATE_DIRECTORY", str(tmp_path))
    path = tmp_path / "mbgw.toml"
    path.write_text(DEVICE + f'[table]\nenabled = true\npersist = "{tmp_path}/none/t"\n')
    assert mbgw("check-config", path).exit_code == 0


def test_one_port_on_two_addresses_is_two_listeners(tmp_path):
    path = tmp_path / "mbgw.toml"
    path.write_text(DEVICE + '[net]\nbind = "127.0.0.1"\nmdbport = 1502\n'
                    '[general]\nmetrics = "127.0.0.2:1502"\n')
    assert mbgw("check-config", path).exit_code == 0



def test_the_udp_port_may_be_the_modbus_tcp_port(tmp_path):
    """UDP and TCP ports do not clash: udp-port = mdbport is the usual choice (502)."""
    path = tmp_path / "mbgw.toml"
    path.write_text(DEVICE + "[net]\nmdbport = 1502\nudp-port = 1502\nrtu-port = 1503\n")
    assert mbgw("check-config", path).exit_code == 0


def test_master_modes_table_port_on_its_bind_and_the_metrics_elsewhere_are_two(tmp_path):
    """net.bind is the table server's address in master mode: the metrics may take the
    port on another address, not on every one."""
    path = tmp_path / "mbgw.toml"
    text = DEVICE + 'mode = "master"\n[net]\nbind = "127.0.0.1"\n[table]\nenabled = true\n' \
        'port = 1502\n[general]\nmetrics = "{}:1502"\n'
    path.write_text(text.format("127.0.0.2"))
    assert mbgw("check-config", path).exit_code == 0
    path.write_text(text.format("0.0.0.0"))
    result = mbgw("check-config", path)
    assert result.exit_code == 78 and "port 1502 is table.port's already" in result.output


def test_a_port_another_program_holds_is_no_configuration_problem(tmp_path):
    """A port in use is a fact of the moment: check-config passes it, the start fails with
    status 1 (systemd tries again), naming the port."""
    port = _taken_port()
    with socket.socket() as holder:
        holder.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        holder.bind(("0.0.0.0", port))
        holder.listen()
        path = tmp_path / "mbgw.toml"
        path.write_text(DEVICE + f'[net]\nmdbport = {port}\n[general]\ncontrol = '
                        f'"{tmp_path}/c.sock"\n')
        assert mbgw("check-config", path).exit_code == 0


def test_all_the_problems_are_listed(tmp_path, pki):
    path = tmp_path / "mbgw.toml"
    path.write_text(DEVICE + _tls(pki["cert"], pki["other_key"], pki["ca"])
                    + '[general]\nmetrics = "nohost.invalid:9502"\n')
    result = mbgw("check-config", path)
    assert result.exit_code == EX_CONFIG
    assert f"{path}: tls.key: " in result.output and f"{path}: general.metrics: " in \
        result.output


def test_a_command_line_option_that_does_not_go_with_another_stays_a_usage_error():
    result = CliRunner().invoke(main, ["slave", "--device", "/dev/null", "--mdbport", "0"])
    assert result.exit_code == 2 and "'--mdbport'" in result.output


def test_config_set_refuses_a_value_run_would_refuse_and_writes_nothing(tmp_path, pki):
    path = tmp_path / "mbgw.toml"
    path.write_text(DEVICE + _tls(pki["cert"], pki["key"], pki["ca"]) + "[table]\nenabled = true\n")
    before = path.read_text()
    for words, key in ((("tls", "key", pki["other_key"]), "tls.key"),
                       (("net", "bind", "999.0.0.1"), "net.bind"),
                       (("table", "persist", tmp_path), "table.persist"),
                       (("general", "metrics", ":802"), "general.metrics")):
        result = mbgw("config", "set", *words, "--config", path)
        assert result.exit_code == 1, result.output
        assert f"{path}: {key}: " in result.output
        assert path.read_text() == before


def test_config_set_writes_a_key_that_waits_for_its_partner_and_says_so(tmp_path, pki):
    """Keys that go together are set one after the other: the first is written, with a
    warning that run and reload refuse the file until the other is set."""
    path = tmp_path / "mbgw.toml"
    path.write_text(DEVICE)
    result = mbgw("config", "set", "web", "listen", "127.0.0.1:8080", "--config", path)
    assert result.exit_code == 0, result.output
    assert 'listen = "127.0.0.1:8080"' in path.read_text()
    assert f"mbgw: warning: {path}: web.listen: no admin password set" in result.output
    assert "apply it with" not in result.output
    assert mbgw("check-config", path).exit_code == EX_CONFIG


def test_each_check_is_listed_once():
    names = [check.__name__ for check in preflight.CHECKS]
    assert len(set(names)) == len(names)
    assert all(callable(getattr(preflight, name)) for name in names)


def test_a_file_changed_after_the_checks_still_fails_the_start_with_78(tmp_path, pki):
    """The files are read again at start: a key replaced between check and start."""
    path = tmp_path / "mbgw.toml"
    key = tmp_path / "server.key"
    key.write_bytes(Path(pki["key"]).read_bytes())
    path.write_text(DEVICE + _tls(pki["cert"], key, pki["ca"]))
    assert mbgw("check-config", path).exit_code == 0
    key.write_bytes(Path(pki["other_key"]).read_bytes())
    result = mbgw("run", "--config", path)
    assert result.exit_code == EX_CONFIG and "tls.key: " in result.output
